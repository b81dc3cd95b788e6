#include "daemon/lockstep.hpp"

#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>

namespace nccomp::daemon {
namespace {

void put_u32(std::uint8_t* p, std::uint32_t v) noexcept {
  for (int i = 0; i < 4; ++i) {
    p[i] = static_cast<std::uint8_t>(v >> (8 * i));
  }
}
void put_u64(std::uint8_t* p, std::uint64_t v) noexcept {
  for (int i = 0; i < 8; ++i) {
    p[i] = static_cast<std::uint8_t>(v >> (8 * i));
  }
}
std::uint32_t get_u32(const std::uint8_t* p) noexcept {
  std::uint32_t v = 0;
  for (int i = 3; i >= 0; --i) {
    v = (v << 8) | p[i];
  }
  return v;
}
std::uint64_t get_u64(const std::uint8_t* p) noexcept {
  std::uint64_t v = 0;
  for (int i = 7; i >= 0; --i) {
    v = (v << 8) | p[i];
  }
  return v;
}

}  // namespace

std::array<std::uint8_t, kLockstepMessageBytes> encode_lockstep(const LockstepMessage& m) noexcept {
  std::array<std::uint8_t, kLockstepMessageBytes> b{};
  put_u32(b.data(), kLockstepMagic);
  put_u32(b.data() + 4, static_cast<std::uint32_t>(m.type));
  put_u64(b.data() + 8, m.cycle);
  put_u64(b.data() + 16, static_cast<std::uint64_t>(m.time_ns));
  return b;
}

LockstepDecode decode_lockstep(std::span<const std::uint8_t> bytes, LockstepMessage& out) noexcept {
  if (bytes.size() != kLockstepMessageBytes) {
    return LockstepDecode::kWrongSize;
  }
  if (get_u32(bytes.data()) != kLockstepMagic) {
    return LockstepDecode::kWrongMagic;
  }
  const std::uint32_t type = get_u32(bytes.data() + 4);
  if (type < 1 || type > 3) {
    return LockstepDecode::kUnknownType;
  }
  out.type = static_cast<LockstepType>(type);
  out.cycle = get_u64(bytes.data() + 8);
  out.time_ns = static_cast<core::TimeNs>(get_u64(bytes.data() + 16));
  return LockstepDecode::kOk;
}

const char* to_string(LockstepDecode d) noexcept {
  switch (d) {
    case LockstepDecode::kOk:
      return "ok";
    case LockstepDecode::kWrongSize:
      return "wrong size (not 24 bytes)";
    case LockstepDecode::kWrongMagic:
      return "wrong magic (not 0x4E43534D)";
    case LockstepDecode::kUnknownType:
      return "unknown type (not 1..3)";
  }
  return "?";
}

const char* to_string(LockstepEnd e) noexcept {
  switch (e) {
    case LockstepEnd::kRunning:
      return "running";
    case LockstepEnd::kBye:
      return "the peer said BYE";
    case LockstepEnd::kClosed:
      return "the peer closed the socket";
    case LockstepEnd::kBadMessage:
      return "malformed message from the peer";
    case LockstepEnd::kBadSequence:
      return "TICK out of sequence (cycle not increasing or time going backwards)";
    case LockstepEnd::kSocketError:
      return "socket error";
    case LockstepEnd::kStopped:
      return "stopped by signal";
  }
  return "?";
}

LockstepPeer::~LockstepPeer() {
  if (fd_ >= 0) {
    ::close(fd_);
  }
}

void LockstepPeer::connect(const std::string& path, double timeout_s) {
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  if (path.empty() || path.size() >= sizeof addr.sun_path) {
    throw std::runtime_error("lockstep socket path '" + path + "' is empty or longer than " +
                             std::to_string(sizeof addr.sun_path - 1) + " bytes");
  }
  std::memcpy(addr.sun_path, path.c_str(), path.size() + 1);
  timespec start{};
  clock_gettime(CLOCK_MONOTONIC, &start);
  int last_errno = 0;
  for (;;) {
    const int fd = ::socket(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0);
    if (fd < 0) {
      throw std::runtime_error(std::string("lockstep: socket(AF_UNIX, SOCK_SEQPACKET): ") +
                               std::strerror(errno));
    }
    if (::connect(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) == 0) {
      fd_ = fd;
      end_ = LockstepEnd::kRunning;
      return;
    }
    last_errno = errno;
    ::close(fd);
    timespec now{};
    clock_gettime(CLOCK_MONOTONIC, &now);
    const double waited_s = static_cast<double>(now.tv_sec - start.tv_sec) +
                            static_cast<double>(now.tv_nsec - start.tv_nsec) * 1e-9;
    if (waited_s >= timeout_s) {
      break;
    }
    const timespec pause{0, 20'000'000};
    nanosleep(&pause, nullptr);
  }
  throw std::runtime_error("lockstep: cannot connect to " + path + " within " +
                           std::to_string(timeout_s) + " s: " + std::strerror(last_errno) +
                           " (is ncsim running with --lockstep " + path + "?)");
}

void LockstepPeer::adopt(int fd) noexcept {
  if (fd_ >= 0) {
    ::close(fd_);
  }
  fd_ = fd;
  end_ = LockstepEnd::kRunning;
  end_detail_ = 0;
  ticks_ = 0;
}

void LockstepPeer::finish(LockstepEnd why, int detail) noexcept {
  if (end_ == LockstepEnd::kRunning) {
    end_ = why;
    end_detail_ = detail;
  }
}

LockstepPeer::Wait LockstepPeer::wait_tick(LockstepMessage& tick,
                                           core::TimeNs timeout_ns) noexcept {
  if (fd_ < 0 || end_ != LockstepEnd::kRunning) {
    return Wait::kEnd;
  }
  pollfd p{fd_, POLLIN, 0};
  const timespec ts{static_cast<time_t>(timeout_ns / 1'000'000'000),
                    static_cast<long>(timeout_ns % 1'000'000'000)};
  const int n = ::ppoll(&p, 1, &ts, nullptr);
  if (n == 0 || (n < 0 && errno == EINTR)) {
    return Wait::kTimeout;
  }
  if (n < 0) {
    finish(LockstepEnd::kSocketError, errno);
    return Wait::kEnd;
  }
  // One byte more than a message: a longer datagram is then seen as wrong-sized (MSG_TRUNC
  // would report it too, but this keeps the decode path the same).
  std::array<std::uint8_t, kLockstepMessageBytes + 1> buf{};
  const ssize_t got = ::recv(fd_, buf.data(), buf.size(), MSG_DONTWAIT);
  if (got == 0) {
    finish(LockstepEnd::kClosed, 0);
    return Wait::kEnd;
  }
  if (got < 0) {
    if (errno == EAGAIN || errno == EINTR) {
      return Wait::kTimeout;
    }
    // ECONNRESET: the peer exited without BYE; the same as a close.
    finish(errno == ECONNRESET ? LockstepEnd::kClosed : LockstepEnd::kSocketError, errno);
    return Wait::kEnd;
  }
  LockstepMessage m;
  const LockstepDecode d =
      decode_lockstep(std::span<const std::uint8_t>(buf.data(), static_cast<std::size_t>(got)), m);
  if (d != LockstepDecode::kOk) {
    finish(LockstepEnd::kBadMessage, static_cast<int>(d));
    return Wait::kEnd;
  }
  if (m.type == LockstepType::kBye) {
    finish(LockstepEnd::kBye, 0);
    return Wait::kEnd;
  }
  if (m.type != LockstepType::kTick) {
    finish(LockstepEnd::kBadMessage, static_cast<int>(LockstepDecode::kUnknownType));
    return Wait::kEnd;
  }
  // The engine needs time that never runs backwards; a repeated cycle would step it twice.
  if (ticks_ > 0 && (m.cycle <= last_cycle_ || m.time_ns < last_time_ns_)) {
    finish(LockstepEnd::kBadSequence, 0);
    return Wait::kEnd;
  }
  ++ticks_;
  last_cycle_ = m.cycle;
  last_time_ns_ = m.time_ns;
  tick = m;
  return Wait::kTick;
}

bool LockstepPeer::send(const LockstepMessage& m) noexcept {
  if (fd_ < 0) {
    return false;
  }
  const auto b = encode_lockstep(m);
  const ssize_t put = ::send(fd_, b.data(), b.size(), MSG_NOSIGNAL);
  if (put != static_cast<ssize_t>(b.size())) {
    finish(errno == EPIPE || errno == ECONNRESET ? LockstepEnd::kClosed : LockstepEnd::kSocketError,
           errno);
    return false;
  }
  return true;
}

bool LockstepPeer::send_done(std::uint64_t cycle, core::TimeNs time_ns) noexcept {
  return send(LockstepMessage{LockstepType::kDone, cycle, time_ns});
}

void LockstepPeer::send_bye() noexcept {
  if (fd_ >= 0) {
    (void)send(LockstepMessage{LockstepType::kBye, last_cycle_, last_time_ns_});
    ::close(fd_);
    fd_ = -1;
  }
}

}  // namespace nccomp::daemon
