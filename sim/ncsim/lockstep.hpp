// Lock-step clock master (contract C2): ncsim listens on a Unix SOCK_SEQPACKET socket, the daemon
// connects; per cycle ncsim sends TICK(cycle, time_ns) and waits for DONE(cycle); BYE from either
// side ends the run. Messages are fixed 24-byte little-endian structs.
#pragma once

#include <cstdint>
#include <string>

namespace nccomp::sim::ncsim {

inline constexpr std::uint32_t kLockstepMagic = 0x4E43534D;  // "NCSM"
enum class LockstepType : std::uint32_t { kTick = 1, kDone = 2, kBye = 3 };

struct LockstepMessage {
  std::uint32_t magic{kLockstepMagic};
  std::uint32_t type{0};
  std::uint64_t cycle{0};
  std::int64_t time_ns{0};
};
static_assert(sizeof(LockstepMessage) == 24);

/// Checks a received datagram: size, magic, type. Returns false (and why) for anything else.
bool parse_lockstep_message(const void* data, std::size_t size, LockstepMessage& out,
                            std::string& why);

class LockstepServer {
 public:
  /// Binds and listens at path (an existing socket file there is replaced). Throws on error.
  explicit LockstepServer(std::string path);
  ~LockstepServer();
  LockstepServer(const LockstepServer&) = delete;
  LockstepServer& operator=(const LockstepServer&) = delete;

  /// Waits for the daemon to connect. Throws std::runtime_error after timeout_s.
  void accept(double timeout_s);
  /// Waits for the connected daemon to close its end (without a BYE: it was killed), then
  /// forgets it, so that accept() takes the next one. Throws after timeout_s or on a message.
  void wait_closed(double timeout_s);
  void tick(std::uint64_t cycle, std::int64_t time_ns);
  enum class Reply : std::uint8_t { kDone, kBye, kClosed, kTimeout };
  /// Waits for DONE of this cycle (a DONE of another cycle or a malformed message throws).
  Reply wait_done(std::uint64_t cycle, double timeout_s);
  /// Sends BYE (ignored if the peer is gone).
  void bye() noexcept;
  [[nodiscard]] const std::string& path() const noexcept { return path_; }

 private:
  std::string path_;
  int listen_fd_{-1};
  int fd_{-1};
};

}  // namespace nccomp::sim::ncsim
