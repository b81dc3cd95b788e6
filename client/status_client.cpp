#include "client/status_client.hpp"

#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <stdexcept>

namespace nccomp::client {

namespace {

// Closes the socket on every way out.
class Fd {
 public:
  explicit Fd(int fd) : fd_(fd) {}
  ~Fd() {
    if (fd_ >= 0) ::close(fd_);
  }
  Fd(const Fd&) = delete;
  Fd& operator=(const Fd&) = delete;
  [[nodiscard]] int get() const noexcept { return fd_; }

 private:
  int fd_;
};

std::string seconds_text(double s) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", s);
  return buf;
}

}  // namespace

std::string query(const std::string& socket_path, std::string_view request, double timeout_s) {
  using Clock = std::chrono::steady_clock;
  const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                           std::chrono::duration<double>(timeout_s));
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  if (socket_path.empty() || socket_path.size() >= sizeof(addr.sun_path)) {
    throw std::runtime_error("socket path '" + socket_path + "' is empty or too long");
  }
  std::memcpy(addr.sun_path, socket_path.c_str(), socket_path.size() + 1);
  const Fd fd(::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0));
  if (fd.get() < 0) {
    throw std::runtime_error(std::string("socket: ") + std::strerror(errno));
  }
  if (::connect(fd.get(), reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
    throw std::runtime_error("cannot connect to '" + socket_path + "': " + std::strerror(errno) +
                             " (is nccompd running?)");
  }
  // A request line is far smaller than the socket's buffer: send() does not block.
  const std::string line = std::string(request) + "\n";
  std::size_t off = 0;
  // A server that turns a client away (busy) answers and closes at once, maybe before the request
  // is sent: its answer is still to be read, so a closed peer ends the sending, not the query.
  int send_error = 0;
  while (off < line.size()) {
    const ssize_t n = ::send(fd.get(), line.data() + off, line.size() - off, MSG_NOSIGNAL);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0 && (errno == EPIPE || errno == ECONNRESET)) {
      send_error = errno;
      break;
    }
    if (n <= 0) {
      throw std::runtime_error("cannot send to '" + socket_path + "': " + std::strerror(errno));
    }
    off += static_cast<std::size_t>(n);
  }
  if (send_error == 0) ::shutdown(fd.get(), SHUT_WR);
  std::string out;
  char buf[4096];
  for (;;) {
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
    pollfd p{fd.get(), POLLIN, 0};
    const int r = left.count() > 0 ? ::poll(&p, 1, static_cast<int>(left.count())) : 0;
    if (r < 0 && errno == EINTR) continue;
    if (r == 0) {
      throw std::runtime_error("no answer from '" + socket_path + "' within " +
                               seconds_text(timeout_s) + " s");
    }
    const ssize_t n = ::recv(fd.get(), buf, sizeof buf, 0);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    out.append(buf, static_cast<std::size_t>(n));
  }
  if (out.empty()) {
    if (send_error != 0) {
      throw std::runtime_error("cannot send to '" + socket_path +
                               "': " + std::strerror(send_error));
    }
    throw std::runtime_error("'" + socket_path + "' closed without an answer");
  }
  return out;
}

}  // namespace nccomp::client
