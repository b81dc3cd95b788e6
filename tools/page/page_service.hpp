// nccomp-page's request handling, apart from the HTTP server (page_server.hpp) so that every
// route is tested without sockets (docs/operator-page.md). It reads nccompd only through the
// status socket (client::query): a snapshot of `status json` every poll interval while a page
// is watching, and the actions (acknowledge, model promote, model rollback) for an allowed user.
// Not real-time; every public member may be called from any thread.
#pragma once

#include <sys/types.h>

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "tools/page/peer_identity.hpp"

namespace nccomp::page {

struct PageOptions {
  std::string admin_group{"nccomp-admin"};  // who may act: root and this group (--admin-group)
  std::string report_dir;                   // nccomp analyze's --out DIR; empty: none
  bool actions{true};                       // false: every action is refused (remote listener)
  bool remote_actions{false};               // a client on another host may act (--remote-actions)
  double poll_interval_s{0.25};             // status requests while a page watches [s]
  std::size_t max_body_bytes{1024};         // an action's JSON body
  /// Host headers an action may carry (DNS rebinding: another site's name resolved to this
  /// host); empty: not checked (a listener beyond this host, whose names the page cannot know).
  std::vector<std::string> allowed_hosts;
};

/// What the page needs from the outside; the tests replace each.
struct PageDeps {
  /// One request to nccompd's status socket, its whole answer; throws when it cannot.
  std::function<std::string(std::string_view request)> query;
  /// The uid that opened the client's end of the connection (loopback_client_uid).
  std::function<std::optional<uid_t>(const Endpoint& client, const Endpoint& server)> client_uid;
  /// May this uid change the machine (may_change_machine with the admin group).
  std::function<Permission(uid_t uid)> permission;
  /// A line for the journal: level "info" or "warning".
  std::function<void(std::string_view level, const std::string& line)> log;
};

struct HttpRequest {
  std::string method;  // "GET", "POST", ...
  std::string path;    // without the query string
  std::string content_type;
  std::string origin;  // the Origin header, empty when absent
  std::string host;    // the Host header
  std::string body;
  Endpoint client;  // the peer
  Endpoint server;  // the page's end of the connection
};

struct HttpReply {
  int status{200};
  std::string content_type{"application/json"};
  std::string body;
  std::string allow;  // 405: the methods the path takes
};

class PageService {
 public:
  PageService(PageOptions options, PageDeps deps);
  ~PageService();
  PageService(const PageService&) = delete;
  PageService& operator=(const PageService&) = delete;

  /// Every route: the page, its script and style, /api/status, /api/report,
  /// /report/plots/NAME.svg and POST /api/action. Bad input gets a 4xx reply with
  /// {"error": "..."} and is counted; nothing throws. GET /events is only judged here (200 with
  /// no body: the server then streams next_snapshot()).
  [[nodiscard]] HttpReply handle(const HttpRequest& request);

  /// A snapshot now: {"time_utc", "ok", "status" (the daemon's JSON) or "error", "page"}.
  [[nodiscard]] std::string snapshot();

  /// Starts the thread that takes a snapshot every poll interval while someone waits in
  /// next_snapshot(); stop() ends it and wakes every waiter.
  void start();
  void stop();

  /// The first snapshot newer than `after` (its number), waiting at most timeout_s. Returns
  /// nullopt on timeout or after stop(). Marks the caller as watching while it waits.
  struct Numbered {
    std::uint64_t number{0};
    std::string json;
  };
  [[nodiscard]] std::optional<Numbered> next_snapshot(std::uint64_t after, double timeout_s);

  /// A bad request the server saw before handle() (an unknown method, too many watchers).
  void count_bad_request() { ++bad_requests_; }

  [[nodiscard]] std::uint64_t bad_requests() const { return bad_requests_.load(); }
  [[nodiscard]] std::uint64_t actions_done() const { return actions_done_.load(); }
  [[nodiscard]] std::uint64_t actions_refused() const { return actions_refused_.load(); }

 private:
  HttpReply action(const HttpRequest& request);
  HttpReply report() const;
  HttpReply plot(std::string_view name) const;
  HttpReply error(int status, const std::string& message);
  nlohmann::json page_json() const;
  void poll_loop();

  PageOptions options_;
  PageDeps deps_;
  std::atomic<std::uint64_t> bad_requests_{0};
  std::atomic<std::uint64_t> actions_done_{0};
  std::atomic<std::uint64_t> actions_refused_{0};
  std::mutex action_mutex_;  // one action at a time, as the daemon takes them

  std::mutex mutex_;
  std::condition_variable changed_;
  bool stopping_{false};
  int watchers_{0};
  std::uint64_t number_{0};
  std::string latest_;
  std::thread poller_;
};

}  // namespace nccomp::page
