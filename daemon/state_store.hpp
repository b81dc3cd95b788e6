// Crash-safe state file (architecture.md: "persisted atomically").
//
// Format: "NCCOMPST", u32 format version, u32 CRC-32 (IEEE) of everything after it, u64 payload
// size, u64 sequence number, payload (the engine's export_state() bytes). A truncated file, a
// flipped bit or a wrong size is detected; the daemon then starts safe (offsets held, alarm).
//
// Writing: temp file in the same directory, write, fsync, rename over the old file, fsync the
// directory: after a crash at any point the file is either the old state or the new one.
//
// Threads: the loop thread exports the engine into a pre-allocated blob (acquire / submit are
// wait-free SPSC operations); the persister thread writes it. Nothing here runs I/O on the loop.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "core/rt/spsc_ring.hpp"

namespace nccomp::daemon {

/// CRC-32 (IEEE 802.3). Chains: crc32(b, crc32(a)) == crc32(a followed by b).
[[nodiscard]] std::uint32_t crc32(std::span<const std::byte> bytes,
                                  std::uint32_t previous = 0) noexcept;

enum class StateFileStatus : std::uint8_t { kAbsent = 0, kOk = 1, kCorrupt = 2 };

struct StateFile {
  StateFileStatus status{StateFileStatus::kAbsent};
  std::vector<std::byte> payload;
  std::uint64_t sequence{0};
  /// Why the file is corrupt (for the log and `nccomp status`).
  std::string reason;
};

/// Reads and verifies path. Never throws for bad content (kCorrupt with a reason); an unreadable
/// existing file is kCorrupt too (it must not be mistaken for a fresh start).
[[nodiscard]] StateFile read_state_file(const std::string& path);

/// Writes atomically (see above). Throws std::system_error naming the path and the step.
void write_state_file(const std::string& path, std::span<const std::byte> payload,
                      std::uint64_t sequence);

/// The persister thread and its pool of pre-allocated blobs.
class StatePersister {
 public:
  struct Blob {
    std::vector<std::byte> data;
    std::size_t size{0};
  };

  /// blob_bytes: capacity of each blob; allocates `blobs` of them. Not real-time.
  StatePersister(std::string path, std::size_t blob_bytes, std::size_t blobs = 4);
  ~StatePersister();

  void start(std::uint64_t first_sequence);
  /// Writes whatever is queued, then stops. Idempotent.
  void stop();

  /// Loop thread: a free blob, or nullptr if every blob is queued (the persister is behind).
  Blob* acquire() noexcept;
  /// Loop thread: hands a filled blob to the persister. Never fails (pool size = ring size).
  void submit(Blob* blob) noexcept;
  /// Loop thread: gives back an acquired blob unused.
  void release(Blob* blob) noexcept;

  [[nodiscard]] std::size_t blob_bytes() const noexcept { return blob_bytes_; }
  [[nodiscard]] const std::string& path() const noexcept { return path_; }
  /// Main thread, with the loop stopped: writes payload synchronously (shutdown).
  void write_now(std::span<const std::byte> payload);

  struct Stats {
    std::uint64_t writes{0};
    std::uint64_t failures{0};
    std::uint64_t sequence{0};
    std::string last_error;
  };
  [[nodiscard]] Stats stats() const;

 private:
  void run();
  void write_one(std::span<const std::byte> payload);

  std::string path_;
  std::size_t blob_bytes_;
  std::vector<std::unique_ptr<Blob>> pool_;
  core::rt::SpscRing<Blob*> free_;  // persister → loop
  core::rt::SpscRing<Blob*> full_;  // loop → persister
  std::atomic<bool> stop_{false};
  std::thread thread_;
  mutable std::mutex mu_;  // guards stats_ and serialises writes (thread vs write_now)
  Stats stats_;
};

}  // namespace nccomp::daemon
