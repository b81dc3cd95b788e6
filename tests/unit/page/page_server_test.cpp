// nccomp-page's HTTP server (tools/page/page_server.hpp) on 127.0.0.1 with a fake daemon: bad
// bytes and unknown methods answered and counted without harm, server-sent events delivered,
// watchers beyond the limit turned away, and an action's user found from the real connection.
#include "tools/page/page_server.hpp"

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <httplib.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <string>
#include <thread>

namespace {

using nccomp::page::Endpoint;
using nccomp::page::PageDeps;
using nccomp::page::PageOptions;
using nccomp::page::PageServer;
using nccomp::page::PageService;
using nccomp::page::Permission;

struct Running {
  explicit Running(int max_watchers = 2) : server(max_watchers) {
    port = server.bind("127.0.0.1", 0);
    PageOptions o;
    o.poll_interval_s = 0.05;
    o.allowed_hosts = {"127.0.0.1:" + std::to_string(port)};
    PageDeps d;
    d.query = [](std::string_view r) {
      return r == "json" ? std::string(R"({"loop":{"cycles":1}})") : std::string("ok done\n");
    };
    d.client_uid = nccomp::page::loopback_client_uid;  // the real /proc/net/tcp
    d.permission = [this](uid_t u) {
      asked_uid = static_cast<long>(u);
      Permission p;
      p.allowed = true;
      p.user = "u" + std::to_string(u);
      return p;
    };
    d.log = [](std::string_view, const std::string&) {};
    service = std::make_unique<PageService>(o, d);
    service->start();
    thread = std::thread([this] { server.serve(*service); });
    httplib::Client c("127.0.0.1", port);
    for (int i = 0; i < 200 && !c.Get("/page.css"); ++i) {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
  }
  ~Running() {
    service->stop();
    server.stop();
    thread.join();
  }
  // Sends raw bytes, returns the answer's first line.
  std::string raw(const std::string& bytes) const {
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(static_cast<std::uint16_t>(port));
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) return "no connection";
    (void)!::write(fd, bytes.data(), bytes.size());
    std::string got;
    char buf[512];
    ssize_t n = 0;
    while (got.find("\r\n") == std::string::npos && (n = ::read(fd, buf, sizeof buf)) > 0) {
      got.append(buf, static_cast<std::size_t>(n));
    }
    ::close(fd);
    return got.substr(0, got.find("\r\n"));
  }

  PageServer server;
  int port{0};
  std::unique_ptr<PageService> service;
  std::thread thread;
  std::atomic<long> asked_uid{-1};
};

TEST(PageServer, BadBytesAndUnknownMethodsAreAnsweredCountedAndHarmless) {
  Running r;
  const auto before = r.service->bad_requests();
  EXPECT_EQ(r.raw("\x01\x02garbage\r\n\r\n"), "HTTP/1.1 400 Bad Request");
  EXPECT_EQ(r.raw("BREW /pot HTTP/1.1\r\nHost: x\r\n\r\n"), "HTTP/1.1 400 Bad Request");
  httplib::Client c("127.0.0.1", r.port);
  const auto big = c.Post("/api/action", std::string(100000, 'x'), "application/json");
  ASSERT_TRUE(big);
  EXPECT_EQ(big->status, 413);
  EXPECT_EQ(big->body, "{\"error\":\"bad request (HTTP 413)\"}\n");
  const auto missing = c.Get("/nope");
  ASSERT_TRUE(missing);
  EXPECT_EQ(missing->status, 404);
  EXPECT_EQ(missing->get_header_value("X-Content-Type-Options"), "nosniff");
  EXPECT_EQ(r.service->bad_requests(), before + 4);
  const auto ok = c.Get("/api/status");
  ASSERT_TRUE(ok);
  EXPECT_EQ(ok->status, 200);
}

TEST(PageServer, EventsStreamSnapshotsAndTurnAwayWatchersBeyondTheLimit) {
  Running r(1);
  std::atomic<int> events{0};
  std::atomic<bool> done{false};
  std::thread watcher([&] {
    httplib::Client c("127.0.0.1", r.port);
    c.Get("/events", [&](const char* data, std::size_t n) {
      if (std::string(data, n).rfind("data: {", 0) == 0) ++events;
      return !done.load();
    });
  });
  for (int i = 0; i < 500 && events < 2; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  EXPECT_GE(events.load(), 2);
  httplib::Client c("127.0.0.1", r.port);
  const auto second = c.Get("/events");
  ASSERT_TRUE(second);
  EXPECT_EQ(second->status, 503);
  EXPECT_EQ(second->body, "{\"error\":\"busy: 1 pages are watching (--max-watchers)\"}\n");
  done = true;
  watcher.join();
  // Under another site's name (DNS rebinding): no stream.
  httplib::Client evil("127.0.0.1", r.port);
  evil.set_default_headers({{"Host", "evil.example:" + std::to_string(r.port)}});
  const auto rebound = evil.Get("/events", [](const char* data, std::size_t n) {
    return std::string(data, n).find("data:") == std::string::npos;  // a stream: cancelled
  });
  ASSERT_TRUE(rebound);
  EXPECT_EQ(rebound->status, 403);
}

TEST(PageServer, AnActionsUserIsTheUidOfTheConnectingProcess) {
  Running r;
  httplib::Client c("127.0.0.1", r.port);
  const auto res =
      c.Post("/api/action", R"({"action":"acknowledge","confirmed":true})", "application/json");
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 200) << res->body;
  EXPECT_EQ(r.asked_uid.load(), static_cast<long>(::geteuid()));
}

}  // namespace
