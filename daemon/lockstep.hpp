// Lock-step with a simulated NC (contract C2, docs/daemon.md "Lock-step with ncsim"): the peer
// (ncsim) is the clock master. It listens on a Unix SOCK_SEQPACKET socket; nccompd connects.
// Every message is one fixed 24-byte little-endian record:
//
//   uint32 magic = 0x4E43534D ("NCSM") | uint32 type | uint64 cycle | int64 time_ns
//
// type 1 = TICK (peer → daemon: the NC state of `cycle` at `time_ns` is published),
// 2 = DONE (daemon → peer: the cycle is stepped and its writes are on the wire),
// 3 = BYE (either side: the run is over).
//
// The codec is pure (unit-tested, fuzzed); LockstepPeer owns the socket. Its wait_tick() and
// send_*() are called from the loop thread: system calls, but no allocation and no locks.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>

#include "core/common/types.hpp"

namespace nccomp::daemon {

inline constexpr std::uint32_t kLockstepMagic = 0x4E43534D;  // "NCSM" read as LE uint32
inline constexpr std::size_t kLockstepMessageBytes = 24;

enum class LockstepType : std::uint32_t { kTick = 1, kDone = 2, kBye = 3 };

struct LockstepMessage {
  LockstepType type{LockstepType::kTick};
  std::uint64_t cycle{0};
  core::TimeNs time_ns{0};
};

enum class LockstepDecode : std::uint8_t { kOk = 0, kWrongSize, kWrongMagic, kUnknownType };

/// Little-endian wire form. Real-time safe.
[[nodiscard]] std::array<std::uint8_t, kLockstepMessageBytes> encode_lockstep(
    const LockstepMessage& m) noexcept;
/// Parses one datagram. Real-time safe.
[[nodiscard]] LockstepDecode decode_lockstep(std::span<const std::uint8_t> bytes,
                                             LockstepMessage& out) noexcept;
[[nodiscard]] const char* to_string(LockstepDecode d) noexcept;

/// Why the lock-step run ended (the loop publishes it; the daemon logs it and picks its exit
/// status: kBye and kClosed are a normal end, exit 0).
enum class LockstepEnd : std::uint8_t {
  kRunning = 0,
  kBye = 1,          // the peer said BYE
  kClosed = 2,       // the peer closed the socket
  kBadMessage = 3,   // wrong size / magic / type
  kBadSequence = 4,  // a TICK whose cycle did not increase or whose time went backwards
  kSocketError = 5,
  kStopped = 6,  // SIGTERM / SIGINT on the daemon side (BYE sent to the peer)
};
[[nodiscard]] const char* to_string(LockstepEnd e) noexcept;

class LockstepPeer {
 public:
  LockstepPeer() = default;
  ~LockstepPeer();
  LockstepPeer(const LockstepPeer&) = delete;
  LockstepPeer& operator=(const LockstepPeer&) = delete;

  /// Connects to the peer's socket, retrying every 20 ms for up to timeout_s (the peer may start
  /// after the daemon). Not real-time. Throws std::runtime_error naming the path and the error.
  void connect(const std::string& path, double timeout_s);
  /// Takes an already connected SOCK_SEQPACKET socket (tests, fuzzing, an inherited socket).
  void adopt(int fd) noexcept;

  enum class Wait : std::uint8_t { kTick, kTimeout, kEnd };
  /// Loop thread: waits at most timeout_ns for the next TICK. kEnd: the run is over, end() says
  /// why. No allocation.
  Wait wait_tick(LockstepMessage& tick, core::TimeNs timeout_ns) noexcept;
  /// Loop thread: DONE for a cycle. False if the socket failed (end() then says so).
  bool send_done(std::uint64_t cycle, core::TimeNs time_ns) noexcept;
  /// Best effort; then the socket is closed.
  void send_bye() noexcept;

  [[nodiscard]] LockstepEnd end() const noexcept { return end_; }
  /// Detail of a kBadMessage / kBadSequence / kSocketError end (decode result or errno).
  [[nodiscard]] int end_detail() const noexcept { return end_detail_; }
  [[nodiscard]] std::uint64_t ticks() const noexcept { return ticks_; }
  [[nodiscard]] bool connected() const noexcept { return fd_ >= 0; }

 private:
  bool send(const LockstepMessage& m) noexcept;
  void finish(LockstepEnd why, int detail) noexcept;

  int fd_{-1};
  LockstepEnd end_{LockstepEnd::kRunning};
  int end_detail_{0};
  std::uint64_t ticks_{0};
  std::uint64_t last_cycle_{0};
  core::TimeNs last_time_ns_{0};
};

}  // namespace nccomp::daemon
