// `nccomp collect` (docs/mqtt.md): subscribes to the measurement rows of every machine (or of
// one site) and writes one v2 measurement log per machine, <out>/<site>/<machine>.csv, with the
// publisher's sequence number as the last column `seq`. A row whose sequence is not above the
// last one written for its machine is a duplicate and is not written again, also after a restart
// of the collector: it reads the last sequence back from each file. Not real-time.
#pragma once

#include <cstdint>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace nccomp::tools::mqtt {

class CollectorStore {
 public:
  explicit CollectorStore(std::string out_dir) : out_dir_(std::move(out_dir)) {}
  ~CollectorStore();
  CollectorStore(const CollectorStore&) = delete;
  CollectorStore& operator=(const CollectorStore&) = delete;

  enum class Result { kWritten, kDuplicate, kRefused };

  /// One message from `topic` (nccomp/<site>/<machine>/measurements). Validates it (a JSON
  /// object with a seq, the v2 columns, `machine` equal to the topic's machine, plain column
  /// names and cells), writes it as a row unless it is a duplicate. `error` says why a message is
  /// refused. Thread-safe. Throws std::system_error if a file cannot be written.
  Result add(const std::string& topic, const std::string& payload, std::string& error);

  /// fdatasync of every file written since the last call. Thread-safe.
  void sync();

  struct Stats {
    std::uint64_t written{0};
    std::uint64_t duplicates{0};
    std::uint64_t refused{0};
    /// Sequence numbers skipped (rows the publisher dropped from a full queue, or lost).
    std::uint64_t missing{0};
  };
  [[nodiscard]] Stats stats() const;
  /// The last sequence written for a machine (0 = none); reads the file back the first time.
  [[nodiscard]] std::uint64_t last_seq(const std::string& site, const std::string& machine);

 private:
  struct File {
    int fd{-1};
    std::vector<std::string> header;
    std::uint64_t last_seq{0};
    bool unsynced{false};
  };
  File& file(const std::string& site, const std::string& machine);
  [[nodiscard]] std::string path(const std::string& site, const std::string& machine) const;
  void start_file(File& f, const std::string& path, const std::vector<std::string>& header);

  std::string out_dir_;
  mutable std::mutex mu_;
  std::map<std::string, File> files_;  // "site/machine"
  Stats stats_;
};

}  // namespace nccomp::tools::mqtt
