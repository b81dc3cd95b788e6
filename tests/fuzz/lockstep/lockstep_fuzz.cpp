// Fuzz target: whatever a broken or hostile lock-step peer sends. The input is cut into
// datagrams (a length byte, then that many bytes) sent over a real SOCK_SEQPACKET pair to
// LockstepPeer::wait_tick(), which must end the run cleanly (BYE, bad message, bad sequence)
// or deliver TICKs whose cycles increase and whose time never goes backwards.
#include <sys/socket.h>
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdlib>

#include "daemon/lockstep.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  int sv[2];
  if (::socketpair(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0, sv) != 0) {
    return 0;
  }
  std::size_t sent = 0;
  for (std::size_t i = 0; i < size && sent < 64;) {
    const std::size_t len = data[i++];
    const std::size_t n = len < size - i ? len : size - i;
    // Mostly well-formed messages with fuzzed fields: a length byte of 0 means "24 bytes".
    const std::size_t take = (len == 0 && size - i >= 24) ? 24 : n;
    if (::send(sv[1], data + i, take, MSG_DONTWAIT | MSG_NOSIGNAL) < 0) {
      break;
    }
    i += take;
    ++sent;
  }
  ::close(sv[1]);  // after the datagrams: the daemon side then sees the close
  nccomp::daemon::LockstepPeer peer;
  peer.adopt(sv[0]);
  std::uint64_t last_cycle = 0;
  nccomp::core::TimeNs last_time = 0;
  bool first = true;
  for (std::size_t k = 0; k < sent + 2; ++k) {
    nccomp::daemon::LockstepMessage tick;
    const auto w = peer.wait_tick(tick, 1'000'000);
    if (w == nccomp::daemon::LockstepPeer::Wait::kEnd) {
      if (peer.end() == nccomp::daemon::LockstepEnd::kRunning) {
        std::abort();  // an end must have a reason
      }
      break;
    }
    if (w == nccomp::daemon::LockstepPeer::Wait::kTick) {
      if (!first && (tick.cycle <= last_cycle || tick.time_ns < last_time)) {
        std::abort();  // the sequence rule let a bad TICK through
      }
      first = false;
      last_cycle = tick.cycle;
      last_time = tick.time_ns;
    }
  }
  return 0;
}
