#include "sim/ncsim/lockstep.hpp"

#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <bit>
#include <cerrno>
#include <cstring>
#include <stdexcept>

namespace nccomp::sim::ncsim {

static_assert(std::endian::native == std::endian::little,
              "the lock-step messages are little-endian structs sent as they are");

bool parse_lockstep_message(const void* data, std::size_t size, LockstepMessage& out,
                            std::string& why) {
  if (size != sizeof(LockstepMessage)) {
    why = "message of " + std::to_string(size) + " bytes, expected 24";
    return false;
  }
  std::memcpy(&out, data, sizeof(out));
  if (out.magic != kLockstepMagic) {
    why = "bad magic";
    return false;
  }
  if (out.type < 1 || out.type > 3) {
    why = "unknown type " + std::to_string(out.type);
    return false;
  }
  return true;
}

LockstepServer::LockstepServer(std::string path) : path_(std::move(path)) {
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  if (path_.empty() || path_.size() >= sizeof(addr.sun_path)) {
    throw std::runtime_error("lockstep: socket path empty or longer than " +
                             std::to_string(sizeof(addr.sun_path) - 1) + " bytes: " + path_);
  }
  std::memcpy(addr.sun_path, path_.c_str(), path_.size() + 1);
  listen_fd_ = socket(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0);
  if (listen_fd_ < 0) {
    throw std::runtime_error(std::string("lockstep: socket: ") + std::strerror(errno));
  }
  ::unlink(path_.c_str());
  if (bind(listen_fd_, reinterpret_cast<const sockaddr*>(&addr), sizeof(addr)) != 0 ||
      listen(listen_fd_, 1) != 0) {
    const std::string why = std::strerror(errno);
    ::close(listen_fd_);
    throw std::runtime_error("lockstep: cannot listen on " + path_ + ": " + why);
  }
}

LockstepServer::~LockstepServer() {
  if (fd_ >= 0) {
    ::close(fd_);
  }
  if (listen_fd_ >= 0) {
    ::close(listen_fd_);
    ::unlink(path_.c_str());
  }
}

void LockstepServer::accept(double timeout_s) {
  pollfd p{listen_fd_, POLLIN, 0};
  const int rc = ::poll(&p, 1, static_cast<int>(timeout_s * 1000.0));
  if (rc <= 0) {
    throw std::runtime_error("lockstep: no daemon connected to " + path_ + " within " +
                             std::to_string(timeout_s) + " s");
  }
  fd_ = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC);
  if (fd_ < 0) {
    throw std::runtime_error(std::string("lockstep: accept: ") + std::strerror(errno));
  }
}

void LockstepServer::wait_closed(double timeout_s) {
  pollfd p{fd_, POLLIN, 0};
  if (::poll(&p, 1, static_cast<int>(timeout_s * 1000.0)) <= 0) {
    throw std::runtime_error("lockstep: the daemon did not go away within " +
                             std::to_string(timeout_s) + " s");
  }
  unsigned char buf[64];
  if (::recv(fd_, buf, sizeof(buf), 0) > 0) {
    throw std::runtime_error("lockstep: a message from the daemon while waiting for it to go away");
  }
  ::close(fd_);
  fd_ = -1;
}

void LockstepServer::tick(std::uint64_t cycle, std::int64_t time_ns) {
  const LockstepMessage m{kLockstepMagic, static_cast<std::uint32_t>(LockstepType::kTick), cycle,
                          time_ns};
  if (::send(fd_, &m, sizeof(m), MSG_NOSIGNAL) != static_cast<ssize_t>(sizeof(m))) {
    throw std::runtime_error(std::string("lockstep: send TICK: ") + std::strerror(errno));
  }
}

LockstepServer::Reply LockstepServer::wait_done(std::uint64_t cycle, double timeout_s) {
  pollfd p{fd_, POLLIN, 0};
  const int rc = ::poll(&p, 1, static_cast<int>(timeout_s * 1000.0));
  if (rc == 0) {
    return Reply::kTimeout;
  }
  unsigned char buf[64];
  const ssize_t n = ::recv(fd_, buf, sizeof(buf), 0);
  if (n <= 0) {
    return Reply::kClosed;
  }
  LockstepMessage m{};
  std::string why;
  if (!parse_lockstep_message(buf, static_cast<std::size_t>(n), m, why)) {
    throw std::runtime_error("lockstep: from the daemon: " + why);
  }
  if (m.type == static_cast<std::uint32_t>(LockstepType::kBye)) {
    return Reply::kBye;
  }
  if (m.type != static_cast<std::uint32_t>(LockstepType::kDone) || m.cycle != cycle) {
    throw std::runtime_error("lockstep: expected DONE of cycle " + std::to_string(cycle) +
                             ", got type " + std::to_string(m.type) + " cycle " +
                             std::to_string(m.cycle));
  }
  return Reply::kDone;
}

void LockstepServer::bye() noexcept {
  if (fd_ < 0) {
    return;
  }
  const LockstepMessage m{kLockstepMagic, static_cast<std::uint32_t>(LockstepType::kBye), 0, 0};
  (void)::send(fd_, &m, sizeof(m), MSG_NOSIGNAL);
}

}  // namespace nccomp::sim::ncsim
