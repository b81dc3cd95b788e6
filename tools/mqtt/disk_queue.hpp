// The publisher's bounded on-disk store-and-forward queue (docs/mqtt.md, "The queue").
//
// Messages are lines in segment files (<dir>/seg-<first id>.q, one line per message:
// id, kind, sequence, source cursor, JSON payload, tab-separated), appended whole with one
// write(2) per flush and fdatasync'ed at least every fsync_interval_s. Every message has a queue
// id (global order) and a sequence number of its kind (measurements, alarms, model: the number
// the collector drops duplicates by). Messages leave in id order; an acknowledged prefix is
// forgotten (its segments deleted). When more than max_messages are queued, the oldest segment
// is dropped and its unacknowledged messages are counted per kind: the producer never waits.
//
// <dir>/state.json (written atomically) keeps the first unacknowledged id, the next sequence of
// each kind, the drop counts, the source cursor and the publisher's own state. It is written
// at most every second, before a segment is deleted, and on close; a crash in between is rolled
// forward from the segment lines (their ids, sequences and cursors), so a sequence number is
// never given twice and a source row never queued twice. Acknowledgements since the last save
// are lost in a crash: those messages are sent again (the collector drops them by sequence).
//
// One thread (the publisher's main loop) uses it. Not real-time.
#pragma once

#include <cstdint>
#include <map>
#include <set>
#include <string>
#include <string_view>
#include <vector>

#include <nlohmann/json.hpp>

namespace nccomp::tools::mqtt {

struct QueuedMessage {
  std::uint64_t id{0};
  std::string kind;
  std::uint64_t seq{0};
  std::string payload;
};

class DiskQueue {
 public:
  struct Options {
    std::string directory;
    std::uint64_t max_messages{3'600'000};
    double fsync_interval_s{1.0};
  };

  explicit DiskQueue(Options options);
  ~DiskQueue();
  DiskQueue(const DiskQueue&) = delete;
  DiskQueue& operator=(const DiskQueue&) = delete;

  /// Creates the directory, reads the state and the segments (cutting a partial last line).
  /// Throws std::runtime_error naming the file for a state it cannot trust.
  void open();
  /// Writes what is buffered and the state.
  void close();

  /// The sequence number the next message of `kind` gets (1, 2, …).
  [[nodiscard]] std::uint64_t next_seq(const std::string& kind) const;
  /// Queues a message with the next sequence of its kind (buffered until flush()); `cursor` is
  /// the source position after it (no tabs or newlines). Returns its id.
  std::uint64_t append(const std::string& kind, std::uint64_t seq, const std::string& cursor,
                       std::string_view payload);
  /// Writes the buffered lines (whole lines), syncs per fsync_interval_s (force: now), drops
  /// the oldest segments beyond max_messages, saves the state if due.
  void flush(bool force_sync = false);

  /// The next message to send after the read position (only flushed ones), skipping
  /// acknowledged ones; false if there is none.
  bool next(QueuedMessage& out);
  /// Read position back to the first unacknowledged message (after a lost connection).
  void rewind();
  /// The broker took message `id`.
  void ack(std::uint64_t id);

  /// The source cursor after the last queued message (or set_cursor()'s).
  [[nodiscard]] const std::string& cursor() const noexcept { return cursor_; }
  /// A source position with no message (rows skipped): saved with the state.
  void set_cursor(const std::string& cursor);
  /// The publisher's own state (alarm keys, …), saved with the queue's.
  nlohmann::json& app_state() noexcept { return app_; }
  /// Writes state.json now (atomically).
  void save_state();

  /// Messages queued and not acknowledged.
  [[nodiscard]] std::uint64_t queued() const noexcept { return next_id_ - head_; }
  [[nodiscard]] std::uint64_t acknowledged() const noexcept { return acked_total_; }
  /// Messages dropped because the queue was full, per kind (counted over the queue's life).
  [[nodiscard]] std::uint64_t dropped(const std::string& kind) const;
  [[nodiscard]] std::uint64_t dropped_total() const;
  [[nodiscard]] std::size_t segments() const noexcept { return segments_.size(); }

 private:
  struct Segment {
    std::uint64_t first{0};
    std::uint64_t count{0};
    std::string path;
  };
  void start_segment();
  void drop_oldest();
  void delete_acked_segments();
  [[nodiscard]] std::string segment_path(std::uint64_t first) const;

  Options options_;
  std::uint64_t segment_limit_{1};
  std::vector<Segment> segments_;
  int fd_{-1};  // the newest segment, for appending
  std::string buffer_;
  std::uint64_t buffered_{0};
  std::uint64_t head_{1};     // first unacknowledged id
  std::uint64_t next_id_{1};  // id of the next message
  std::uint64_t flushed_id_{1};
  std::set<std::uint64_t> acked_;  // acknowledged ids ≥ head_
  std::uint64_t acked_total_{0};
  std::map<std::string, std::uint64_t> next_seq_;
  std::map<std::string, std::uint64_t> dropped_;
  std::string cursor_;
  nlohmann::json app_ = nlohmann::json::object();
  // Reading.
  std::size_t read_segment_{0};
  std::uint64_t read_offset_{0};
  std::uint64_t read_id_{1};
  std::string read_buffer_;
  // Timing.
  std::int64_t last_sync_ns_{0};
  std::int64_t last_save_ns_{0};
  bool unsynced_{false};
  bool dirty_{false};
};

}  // namespace nccomp::tools::mqtt
