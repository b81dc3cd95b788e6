// Helpers of the Modbus HIL tests: a pseudo-terminal pair with a byte relay (a serial "null
// modem" without socat), a child process for the python peer, a raw TCP server with scripted
// answers, and polling waits. Everything binds to 127.0.0.1 and is torn down by destructors.
#pragma once

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <stdlib.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "tests/support/wait.hpp"

namespace nccomp::test::modbus {

/// tests/support/wait.hpp's wait_until with the limit in seconds, as these tests give it.
inline bool wait_until(const std::function<bool()>& pred, double timeout_s = 5.0) {
  return test::wait_until(pred,
                          std::chrono::milliseconds(static_cast<std::int64_t>(timeout_s * 1e3)));
}

/// One read of the relay: bytes travelling from a() to b() (from_a) or back, time-stamped with
/// CLOCK_MONOTONIC (the drivers' clock) when the relay read them.
struct WireChunk {
  std::int64_t t_ns{0};
  bool from_a{true};
  std::vector<std::uint8_t> bytes;
};

/// Two pseudo-terminals whose master sides are relayed to each other: a() and b() are serial
/// device paths connected like a null-modem cable. With record(true) the relay keeps every chunk
/// it passes on (a wire tap for frame-timing checks).
class PtyPair {
 public:
  PtyPair() {
    for (int i = 0; i < 2; ++i) {
      master_[i] = posix_openpt(O_RDWR | O_NOCTTY);
      if (master_[i] < 0 || grantpt(master_[i]) != 0 || unlockpt(master_[i]) != 0) {
        throw std::runtime_error("posix_openpt failed");
      }
      path_[i] = ptsname(master_[i]);
      termios t{};
      tcgetattr(master_[i], &t);
      cfmakeraw(&t);
      tcsetattr(master_[i], TCSANOW, &t);
      // Keep the slave open so the master never sees EIO while a side reopens the device.
      keep_[i] = open(path_[i].c_str(), O_RDWR | O_NOCTTY);
      tcgetattr(keep_[i], &t);
      cfmakeraw(&t);
      tcsetattr(keep_[i], TCSANOW, &t);
    }
    if (pipe(stop_) != 0) {
      throw std::runtime_error("pipe failed");
    }
    relay_ = std::thread([this] { run(); });
  }
  ~PtyPair() {
    const char c = 'x';
    (void)!write(stop_[1], &c, 1);
    relay_.join();
    for (int fd : {master_[0], master_[1], keep_[0], keep_[1], stop_[0], stop_[1]}) {
      close(fd);
    }
  }
  PtyPair(const PtyPair&) = delete;
  PtyPair& operator=(const PtyPair&) = delete;
  [[nodiscard]] const std::string& a() const { return path_[0]; }
  [[nodiscard]] const std::string& b() const { return path_[1]; }
  /// Line noise: flips one bit in each of the next n chunks travelling from b() to a().
  void corrupt_next(int n) { corrupt_.store(n); }
  /// Starts (true) or stops keeping the chunks the relay passes on.
  void record(bool on) {
    const std::lock_guard<std::mutex> lock(tap_mutex_);
    recording_ = on;
  }
  /// The chunks kept so far, oldest first.
  [[nodiscard]] std::vector<WireChunk> recorded() {
    const std::lock_guard<std::mutex> lock(tap_mutex_);
    return tap_;
  }

 private:
  static std::int64_t now_ns() {
    timespec ts{};
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return std::int64_t{ts.tv_sec} * 1'000'000'000 + ts.tv_nsec;
  }
  void run() {
    char buf[512];
    for (;;) {
      pollfd p[3] = {{master_[0], POLLIN, 0}, {master_[1], POLLIN, 0}, {stop_[0], POLLIN, 0}};
      if (::poll(p, 3, -1) < 0) {
        continue;
      }
      if (p[2].revents != 0) {
        return;
      }
      for (int i = 0; i < 2; ++i) {
        if ((p[i].revents & POLLIN) != 0) {
          const ssize_t n = read(master_[i], buf, sizeof(buf));
          const std::int64_t t = now_ns();
          if (n > 0) {
            {
              const std::lock_guard<std::mutex> lock(tap_mutex_);
              if (recording_) {
                tap_.push_back({t, i == 0, std::vector<std::uint8_t>(buf, buf + n)});
              }
            }
            if (i == 1 && corrupt_.load() > 0) {
              corrupt_.fetch_sub(1);
              buf[n - 1] = static_cast<char>(buf[n - 1] ^ 0x10);  // inside the CRC or data
            }
            (void)!write(master_[1 - i], buf, static_cast<std::size_t>(n));
          }
        }
      }
    }
  }
  std::atomic<int> corrupt_{0};
  std::mutex tap_mutex_;
  bool recording_{false};
  std::vector<WireChunk> tap_;
  int master_[2]{-1, -1};
  int keep_[2]{-1, -1};
  int stop_[2]{-1, -1};
  std::string path_[2];
  std::thread relay_;
};

/// A child process (the python peer); its first stdout line is returned by start().
class PeerProcess {
 public:
  PeerProcess() = default;
  ~PeerProcess() { kill_now(); }
  PeerProcess(const PeerProcess&) = delete;
  PeerProcess& operator=(const PeerProcess&) = delete;

  std::string start(const std::vector<std::string>& argv, double timeout_s = 15.0) {
    int out[2];
    if (pipe(out) != 0) {
      throw std::runtime_error("pipe failed");
    }
    pid_ = fork();
    if (pid_ == 0) {
      dup2(out[1], 1);
      close(out[0]);
      close(out[1]);
      std::vector<char*> args;
      for (const auto& a : argv) {
        args.push_back(const_cast<char*>(a.c_str()));
      }
      args.push_back(nullptr);
      execv(args[0], args.data());
      _exit(127);
    }
    close(out[1]);
    std::string line;
    pollfd p{out[0], POLLIN, 0};
    const auto end = std::chrono::steady_clock::now() +
                     std::chrono::milliseconds(static_cast<int>(timeout_s * 1000));
    char c = 0;
    while (std::chrono::steady_clock::now() < end) {
      if (::poll(&p, 1, 50) > 0) {
        if (read(out[0], &c, 1) != 1 || c == '\n') {
          break;
        }
        line += c;
      }
    }
    close(out[0]);
    return line;
  }
  /// Sends sig to the child (e.g. SIGUSR1 for the peer's register dump).
  void signal(int sig) const {
    if (pid_ > 0) {
      ::kill(pid_, sig);
    }
  }
  void kill_now() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      waitpid(pid_, nullptr, 0);
      pid_ = -1;
    }
  }

 private:
  pid_t pid_{-1};
};

/// A raw TCP server on 127.0.0.1 (ephemeral port): each received request (bytes as read) is
/// passed to `respond`, whose returned bytes are sent back (empty = no answer). With
/// hang_up_on_request(true) it closes the connection on every request instead (a peer that
/// accepts and hangs up); a `hang_up` predicate does so for the requests it returns true for.
/// Responders and predicates get the request and, in their two-argument form, how many requests
/// its connection received before it.
class RawTcpServer {
 public:
  using Responder = std::function<std::vector<std::uint8_t>(const std::vector<std::uint8_t>&)>;
  using ConnectionResponder =
      std::function<std::vector<std::uint8_t>(const std::vector<std::uint8_t>&, int)>;
  using HangUp = std::function<bool(const std::vector<std::uint8_t>&, int)>;
  explicit RawTcpServer(Responder respond, HangUp hang_up = nullptr)
      : RawTcpServer(
            ConnectionResponder([r = std::move(respond)](const std::vector<std::uint8_t>& req,
                                                         int) { return r(req); }),
            std::move(hang_up)) {}
  RawTcpServer(ConnectionResponder respond, HangUp hang_up)
      : respond_(std::move(respond)), hang_up_if_(std::move(hang_up)) {
    listen_ = socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    a.sin_port = 0;
    if (bind(listen_, reinterpret_cast<sockaddr*>(&a), sizeof(a)) != 0 || listen(listen_, 4) != 0) {
      throw std::runtime_error("raw server: bind/listen failed");
    }
    socklen_t len = sizeof(a);
    getsockname(listen_, reinterpret_cast<sockaddr*>(&a), &len);
    port_ = ntohs(a.sin_port);
    if (pipe(stop_) != 0) {
      throw std::runtime_error("pipe failed");
    }
    thread_ = std::thread([this] { run(); });
  }
  ~RawTcpServer() {
    const char c = 'x';
    (void)!write(stop_[1], &c, 1);
    thread_.join();
    for (int fd : {listen_, stop_[0], stop_[1]}) {
      close(fd);
    }
  }
  RawTcpServer(const RawTcpServer&) = delete;
  RawTcpServer& operator=(const RawTcpServer&) = delete;
  [[nodiscard]] std::uint16_t port() const { return port_; }
  [[nodiscard]] int requests() const { return requests_.load(); }
  [[nodiscard]] int connections() const { return connections_.load(); }
  void hang_up_on_request(bool on) { hang_up_.store(on); }

 private:
  void run() {
    std::vector<int> clients;
    std::vector<int> served;  // requests per client, same order
    const auto drop = [&](int fd) {
      close(fd);
      const auto it = std::find(clients.begin(), clients.end(), fd);
      served.erase(served.begin() + (it - clients.begin()));
      clients.erase(it);
    };
    for (;;) {
      std::vector<pollfd> p{{stop_[0], POLLIN, 0}, {listen_, POLLIN, 0}};
      for (int c : clients) {
        p.push_back({c, POLLIN, 0});
      }
      if (::poll(p.data(), p.size(), -1) < 0) {
        continue;
      }
      if (p[0].revents != 0) {
        break;
      }
      if (p[1].revents != 0) {
        clients.push_back(accept(listen_, nullptr, nullptr));
        served.push_back(0);
        ++connections_;
      }
      for (std::size_t i = 2; i < p.size(); ++i) {
        if (p[i].revents == 0) {
          continue;
        }
        std::vector<std::uint8_t> req(260);
        const ssize_t n = recv(p[i].fd, req.data(), req.size(), 0);
        if (n <= 0) {
          drop(p[i].fd);
          break;
        }
        req.resize(static_cast<std::size_t>(n));
        ++requests_;
        const int before = served[i - 2]++;
        if (hang_up_.load() || (hang_up_if_ && hang_up_if_(req, before))) {
          drop(p[i].fd);
          break;
        }
        const std::vector<std::uint8_t> rsp = respond_(req, before);
        if (!rsp.empty()) {
          (void)!send(p[i].fd, rsp.data(), rsp.size(), MSG_NOSIGNAL);
        }
      }
    }
    for (int c : clients) {
      close(c);
    }
  }
  ConnectionResponder respond_;
  HangUp hang_up_if_;
  int listen_{-1};
  int stop_[2]{-1, -1};
  std::uint16_t port_{0};
  std::atomic<int> requests_{0};
  std::atomic<int> connections_{0};
  std::atomic<bool> hang_up_{false};
  std::thread thread_;
};

}  // namespace nccomp::test::modbus
