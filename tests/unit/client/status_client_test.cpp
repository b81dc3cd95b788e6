// GIVEN a Unix socket server in the test, WHEN client::query() sends a request, THEN the server
// reads exactly the request line, and the client returns the whole answer once the server closes
// (however it is cut into writes); a server that stays silent past the deadline, one that closes
// without answering and a socket nobody listens on are errors naming the socket.
#include "client/status_client.hpp"

#include <gtest/gtest.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <functional>
#include <stdexcept>
#include <string>
#include <thread>

namespace nccomp::client {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

/// Listens on a socket in a temporary directory; serve() runs one connection on a thread.
class Server {
 public:
  Server() {
    dir_ = fs::temp_directory_path() / ("nccomp_client_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
    path_ = (dir_ / "status.sock").string();
    ::unlink(path_.c_str());
    fd_ = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_un a{};
    a.sun_family = AF_UNIX;
    std::memcpy(a.sun_path, path_.c_str(), path_.size() + 1);
    EXPECT_EQ(::bind(fd_, reinterpret_cast<const sockaddr*>(&a), sizeof a), 0);
    EXPECT_EQ(::listen(fd_, 4), 0);
  }
  ~Server() {
    if (thread_.joinable()) thread_.join();
    ::close(fd_);
    fs::remove_all(dir_);
  }
  [[nodiscard]] const std::string& path() const { return path_; }
  /// Accepts one client, reads its request to the end (the client shuts its side down after the
  /// line), then runs answer(client fd) and closes the connection.
  void serve(std::function<void(int)> answer) {
    thread_ = std::thread([this, answer = std::move(answer)] {
      const int c = ::accept(fd_, nullptr, nullptr);
      if (c < 0) return;
      char buf[256];
      ssize_t n = 0;
      while ((n = ::recv(c, buf, sizeof buf, 0)) > 0) {
        request_.append(buf, static_cast<std::size_t>(n));
      }
      answer(c);
      ::close(c);
    });
  }
  /// What the client sent (after serve() finished).
  std::string request() {
    if (thread_.joinable()) thread_.join();
    return request_;
  }

 private:
  fs::path dir_;
  std::string path_;
  int fd_{-1};
  std::thread thread_;
  std::string request_;
};

void send_text(int fd, const std::string& s) {
  ASSERT_EQ(::send(fd, s.data(), s.size(), MSG_NOSIGNAL), static_cast<ssize_t>(s.size()));
}

TEST(StatusClient, SendsOneLineAndReturnsTheWholeAnswerAtTheClose) {
  Server server;
  server.serve([](int c) {
    send_text(c, "ok acknowledged: creep: halt lifted\n");
    std::this_thread::sleep_for(50ms);  // a second write, later
    send_text(c, "  creep: now halted 0\n");
  });
  const std::string answer = query(server.path(), "acknowledge");
  EXPECT_EQ(answer, "ok acknowledged: creep: halt lifted\n  creep: now halted 0\n");
  EXPECT_EQ(server.request(), "acknowledge\n");
}

TEST(StatusClient, ADaemonSilentPastTheDeadlineIsAnError) {
  Server server;
  server.serve([](int c) {
    send_text(c, "ok partial");  // an answer begun but never finished
    std::this_thread::sleep_for(1500ms);
  });
  try {
    (void)query(server.path(), "json", 0.2);
    FAIL() << "no error";
  } catch (const std::runtime_error& e) {
    EXPECT_EQ(std::string(e.what()), "no answer from '" + server.path() + "' within 0.2 s");
  }
}

TEST(StatusClient, ACloseWithoutAnAnswerIsAnError) {
  Server server;
  server.serve([](int) {});
  try {
    (void)query(server.path(), "text");
    FAIL() << "no error";
  } catch (const std::runtime_error& e) {
    EXPECT_EQ(std::string(e.what()), "'" + server.path() + "' closed without an answer");
  }
}

TEST(StatusClient, NoDaemonIsAnErrorNamingTheSocket) {
  const std::string path =
      (fs::temp_directory_path() / ("nccomp_client_none_" + std::to_string(::getpid()))).string();
  try {
    (void)query(path, "text");
    FAIL() << "no error";
  } catch (const std::runtime_error& e) {
    EXPECT_EQ(std::string(e.what()).rfind("cannot connect to '" + path + "': ", 0), 0U) << e.what();
  }
  EXPECT_THROW((void)query("", "text"), std::runtime_error);
}

}  // namespace
}  // namespace nccomp::client
