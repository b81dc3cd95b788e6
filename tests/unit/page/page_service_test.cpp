// nccomp-page's request handling (tools/page/page_service.hpp) with a fake daemon, a fake
// identity and a fake user database: every route, every bad input (a 4xx with the reason,
// counted, the daemon never asked), the actions' rules and what is logged, the snapshots.
#include "tools/page/page_service.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace {

namespace fs = std::filesystem;
using nccomp::page::Endpoint;
using nccomp::page::HttpReply;
using nccomp::page::HttpRequest;
using nccomp::page::PageDeps;
using nccomp::page::PageOptions;
using nccomp::page::PageService;
using nccomp::page::Permission;
using nlohmann::json;
using namespace std::chrono_literals;

constexpr const char* kStatus =
    R"({"daemon":{"pid":7},"registers":[{"index":0,"name":"T1","output_um":1.5}],"alarms":[]})";

struct Fake {
  std::mutex m;
  std::vector<std::string> requests;  // what the daemon was asked
  std::vector<std::string> log;       // "level line"
  std::string answer_ack = "ok acknowledged: creep: nothing latched\n";
  std::string answer_model = "ok model rollback: /srv/a.toml (hash 00000000000000aa)\n";
  bool daemon_down = false;
  std::optional<uid_t> uid = 1000;
  std::vector<uid_t> asked_uids;

  PageDeps deps() {
    PageDeps d;
    d.query = [this](std::string_view r) {
      const std::lock_guard l(m);
      requests.emplace_back(r);
      if (daemon_down) throw std::runtime_error("cannot connect to status.sock: No such file");
      if (r == "json") return std::string(kStatus) + "\n";
      return r.starts_with("model ") ? answer_model : answer_ack;
    };
    d.client_uid = [this](const Endpoint&, const Endpoint&) { return uid; };
    d.permission = [this](uid_t u) {
      asked_uids.push_back(u);
      Permission p;
      p.user = (u == 1000 ? "alice" : "bob") + std::string(" (uid ") + std::to_string(u) + ")";
      p.allowed = u == 1000;
      if (!p.allowed) p.why = p.user + " is not root and not in group 'adm' (--admin-group)";
      return p;
    };
    d.log = [this](std::string_view level, const std::string& line) {
      const std::lock_guard l(m);
      log.push_back(std::string(level) + " " + line);
    };
    return d;
  }
  int asked(const std::string& request) {
    const std::lock_guard l(m);
    return static_cast<int>(std::count(requests.begin(), requests.end(), request));
  }
  int acks() { return asked("acknowledge"); }
};

HttpRequest action(std::string body) {
  HttpRequest r;
  r.method = "POST";
  r.path = "/api/action";
  r.content_type = "application/json";
  r.host = "127.0.0.1:8470";
  r.origin = "http://127.0.0.1:8470";
  r.body = std::move(body);
  r.client = Endpoint{"127.0.0.1", 54312};
  r.server = Endpoint{"127.0.0.1", 8470};
  return r;
}

HttpRequest get(std::string path) {
  HttpRequest r;
  r.method = "GET";
  r.path = std::move(path);
  r.host = "127.0.0.1:8470";
  r.client = Endpoint{"127.0.0.1", 54312};
  r.server = Endpoint{"127.0.0.1", 8470};
  return r;
}

std::string error_of(const HttpReply& r) { return json::parse(r.body).at("error"); }

PageOptions loopback_options() {
  PageOptions o;
  o.admin_group = "adm";
  o.allowed_hosts = {"127.0.0.1:8470", "localhost:8470"};
  return o;
}

constexpr const char* kAck = R"({"action":"acknowledge","confirmed":true})";

TEST(PageService, ServesThePageItsScriptAndStyle) {
  Fake f;
  PageService s(loopback_options(), f.deps());
  const auto html = s.handle(get("/"));
  EXPECT_EQ(html.status, 200);
  EXPECT_EQ(html.content_type, "text/html; charset=utf-8");
  EXPECT_NE(html.body.find("<title>nccomp — operator page</title>"), std::string::npos);
  EXPECT_NE(html.body.find("<dialog id=\"ack-dialog\">"), std::string::npos);
  EXPECT_EQ(s.handle(get("/page.js")).content_type, "text/javascript; charset=utf-8");
  EXPECT_NE(s.handle(get("/page.js")).body.find("new EventSource('/events')"), std::string::npos);
  EXPECT_EQ(s.handle(get("/page.css")).content_type, "text/css; charset=utf-8");
  auto head = get("/");
  head.method = "HEAD";
  EXPECT_EQ(s.handle(head).status, 200);
  EXPECT_EQ(s.bad_requests(), 0U);
}

TEST(PageService, UnknownPathsAndWrongMethodsAreRefusedAndCounted) {
  Fake f;
  PageService s(loopback_options(), f.deps());
  const auto missing = s.handle(get("/etc/passwd"));
  EXPECT_EQ(missing.status, 404);
  EXPECT_EQ(error_of(missing), "no such page: /etc/passwd");
  auto del = action(kAck);
  del.method = "DELETE";
  const auto r = s.handle(del);
  EXPECT_EQ(r.status, 405);
  EXPECT_EQ(r.allow, "POST");
  EXPECT_EQ(error_of(r), "method DELETE not allowed on /api/action (use POST)");
  auto get_action = get("/api/action");
  EXPECT_EQ(s.handle(get_action).status, 405);
  auto post_status = action("");
  post_status.path = "/api/status";
  EXPECT_EQ(s.handle(post_status).allow, "GET");
  EXPECT_EQ(s.bad_requests(), 4U);
  EXPECT_EQ(f.acks(), 0);
}

TEST(PageService, EveryBadActionIsA4xxWithItsReasonAndTheDaemonIsNeverAsked) {
  Fake f;
  PageService s(loopback_options(), f.deps());
  struct Case {
    HttpRequest request;
    int status;
    std::string error;
  };
  auto wrong_type = action(kAck);
  wrong_type.content_type = "application/x-www-form-urlencoded";
  auto cross = action(kAck);
  cross.origin = "http://evil.example";
  auto rebound = action(kAck);
  rebound.host = "evil.example:8470";
  rebound.origin = "http://evil.example:8470";
  const std::vector<Case> cases = {
      {action("{\"action\":"), 400,
       "bad JSON: [json.exception.parse_error.101] parse error at line 1, column 11: syntax "
       "error while parsing value - unexpected end of input; expected '[', '{', or a literal"},
      {action("[1]"), 400, "an action is a JSON object, e.g. {\"action\": ...}"},
      {action(R"({"action":"acknowledge","confirmed":true,"as":"root"})"), 400,
       "unknown key 'as' (known: action, confirmed)"},
      {action(R"({"confirmed":true})"), 400, "\"action\" (a string) is missing"},
      {action(R"({"action":7,"confirmed":true})"), 400, "\"action\" (a string) is missing"},
      {action(R"({"action":"release","confirmed":true})"), 400,
       "unknown action 'release' (known: acknowledge, model_promote, model_rollback)"},
      {action(R"({"action":"acknowledge"})"), 400,
       "the action is not confirmed: \"confirmed\": true is required"},
      {action(R"({"action":"acknowledge","confirmed":"yes"})"), 400,
       "the action is not confirmed: \"confirmed\": true is required"},
      {action(std::string(2000, ' ')), 413, "an action's body is at most 1024 bytes, got 2000"},
      {wrong_type, 415,
       "an action is a JSON body: Content-Type must be application/json, not "
       "'application/x-www-form-urlencoded'"},
      {cross, 403,
       "cross-origin request refused: Origin 'http://evil.example' is not this page "
       "(http://127.0.0.1:8470)"},
      {rebound, 403,
       "Host 'evil.example:8470' is not this page's address (open the page as "
       "http://127.0.0.1:8470/)"},
  };
  std::uint64_t n = 0;
  for (const auto& c : cases) {
    const auto r = s.handle(c.request);
    EXPECT_EQ(r.status, c.status) << c.request.body;
    EXPECT_EQ(error_of(r), c.error) << c.request.body;
    EXPECT_EQ(s.bad_requests(), ++n);
  }
  EXPECT_EQ(f.acks(), 0);
  EXPECT_TRUE(f.asked_uids.empty());
  EXPECT_EQ(s.actions_refused(), 0U);
  // Nor is the status read under another site's name.
  auto rebound_get = get("/api/status");
  rebound_get.host = "evil.example:8470";
  EXPECT_EQ(s.handle(rebound_get).status, 403);
  EXPECT_TRUE(f.requests.empty());
}

TEST(PageService, AnAllowedUserAcknowledgesAndTheLogNamesThem) {
  Fake f;
  PageService s(loopback_options(), f.deps());
  auto no_origin = action(kAck);
  no_origin.origin.clear();  // curl sends none
  for (const auto& req : {action(kAck), no_origin}) {
    const auto r = s.handle(req);
    ASSERT_EQ(r.status, 200) << r.body;
    const json body = json::parse(r.body);
    EXPECT_EQ(body.at("answer"), f.answer_ack);
    EXPECT_EQ(body.at("by"), "alice (uid 1000)");
  }
  EXPECT_EQ(f.acks(), 2);
  EXPECT_EQ(s.actions_done(), 2U);
  ASSERT_EQ(f.log.size(), 4U);
  EXPECT_EQ(f.log[0],
            "info action: acknowledge by alice (uid 1000) from 127.0.0.1:54312, sent to nccompd "
            "as the page's own user");
  EXPECT_EQ(f.log[1],
            "info action acknowledge by alice (uid 1000): ok acknowledged: creep: nothing latched");
}

TEST(PageService, AUserOutsideTheGroupOrUnknownIsRefusedAndLogged) {
  Fake f;
  PageService s(loopback_options(), f.deps());
  f.uid = 1001;
  auto r = s.handle(action(kAck));
  EXPECT_EQ(r.status, 403);
  EXPECT_EQ(error_of(r),
            "permission denied: bob (uid 1001) is not root and not in group 'adm' (--admin-group)");
  ASSERT_EQ(f.log.size(), 1U);
  EXPECT_EQ(f.log[0],
            "warning action refused: acknowledge by bob (uid 1001) from 127.0.0.1:54312: "
            "permission denied: bob (uid 1001) is not root and not in group 'adm' "
            "(--admin-group)");
  f.uid = std::nullopt;
  r = s.handle(action(kAck));
  EXPECT_EQ(r.status, 403);
  EXPECT_EQ(error_of(r),
            "cannot tell which user opened the connection (no socket 127.0.0.1:54312 -> "
            "127.0.0.1:8470 in /proc/net/tcp)");
  EXPECT_EQ(f.acks(), 0);
  EXPECT_EQ(s.actions_refused(), 2U);
  EXPECT_EQ(s.actions_done(), 0U);
}

TEST(PageService, RemoteClientsActOnlyWhenConfigured) {
  Fake f;
  PageOptions o;  // a listener beyond this host: no Host list
  o.actions = false;
  {
    PageService s(o, f.deps());
    auto r = s.handle(action(kAck));
    EXPECT_EQ(r.status, 403);
    EXPECT_EQ(error_of(r),
              "actions are off: the page listens beyond this host and was not started with "
              "--remote-actions");
  }
  o.actions = true;
  auto remote = action(kAck);
  remote.client = Endpoint{"10.0.0.5", 40000};
  remote.host = "10.0.0.2:8470";
  remote.origin.clear();
  {
    PageService s(o, f.deps());
    const auto r = s.handle(remote);
    EXPECT_EQ(r.status, 403);
    EXPECT_EQ(error_of(r), "actions come only from this host (--remote-actions allows others)");
  }
  EXPECT_EQ(f.acks(), 0);
  o.remote_actions = true;
  PageService s(o, f.deps());
  const auto r = s.handle(remote);
  EXPECT_EQ(r.status, 200);
  EXPECT_EQ(json::parse(r.body).at("by"), "remote client 10.0.0.5");
  EXPECT_EQ(f.acks(), 1);
  EXPECT_TRUE(f.asked_uids.empty());  // no user to check
}

TEST(PageService, TheDaemonsRefusalOrAbsenceIsPassedOn) {
  Fake f;
  PageService s(loopback_options(), f.deps());
  f.answer_ack = "error: permission denied: 'acknowledge' changes the machine; uid 998\n";
  auto r = s.handle(action(kAck));
  EXPECT_EQ(r.status, 409);
  EXPECT_EQ(error_of(r),
            "nccompd refused: permission denied: 'acknowledge' changes the machine; uid 998");
  f.daemon_down = true;
  r = s.handle(action(kAck));
  EXPECT_EQ(r.status, 502);
  EXPECT_EQ(error_of(r), "nccompd cannot be reached: cannot connect to status.sock: No such file");
  EXPECT_EQ(s.actions_done(), 0U);
  EXPECT_EQ(s.actions_refused(), 2U);
}

// The model's buttons go through the acknowledge path: each action becomes its own request.
TEST(PageService, ModelPromoteAndRollbackAreCheckedLikeAcknowledge) {
  for (const std::string name : {"model_promote", "model_rollback"}) {
    SCOPED_TRACE(name);
    const std::string request = name == "model_promote" ? "model promote" : "model rollback";
    const std::string confirmed = R"({"action":")" + name + R"(","confirmed":true})";
    Fake f;
    PageService s(loopback_options(), f.deps());
    // Not confirmed: refused before anyone is asked.
    auto r = s.handle(action(R"({"action":")" + name + R"("})"));
    EXPECT_EQ(r.status, 400);
    EXPECT_EQ(error_of(r), "the action is not confirmed: \"confirmed\": true is required");
    EXPECT_TRUE(f.asked_uids.empty());
    // A user outside the admin group.
    f.uid = 1001;
    r = s.handle(action(confirmed));
    EXPECT_EQ(r.status, 403);
    EXPECT_EQ(error_of(r),
              "permission denied: bob (uid 1001) is not root and not in group 'adm' "
              "(--admin-group)");
    ASSERT_EQ(f.log.size(), 1U);
    EXPECT_EQ(f.log[0], "warning action refused: " + name +
                            " by bob (uid 1001) from 127.0.0.1:54312: permission denied: bob (uid "
                            "1001) is not root and not in group 'adm' (--admin-group)");
    EXPECT_EQ(f.asked(request), 0);
    // An allowed user: the daemon is sent the model request, its answer passed on.
    f.uid = 1000;
    r = s.handle(action(confirmed));
    ASSERT_EQ(r.status, 200) << r.body;
    EXPECT_EQ(json::parse(r.body).at("answer"), f.answer_model);
    EXPECT_EQ(json::parse(r.body).at("by"), "alice (uid 1000)");
    EXPECT_EQ(f.asked(request), 1);
    EXPECT_EQ(f.log[1], "info action: " + name +
                            " by alice (uid 1000) from 127.0.0.1:54312, sent to nccompd as the "
                            "page's own user");
    // The daemon refuses (no candidate announced, nothing kept for rollback): 409, counted.
    f.answer_model = "error: model " + request.substr(6) + ": nothing to do\n";
    r = s.handle(action(confirmed));
    EXPECT_EQ(r.status, 409);
    EXPECT_EQ(error_of(r), "nccompd refused: model " + request.substr(6) + ": nothing to do");
    EXPECT_EQ(f.asked(request), 2);
    EXPECT_EQ(f.acks(), 0);
    EXPECT_EQ(s.actions_done(), 1U);
    EXPECT_EQ(s.actions_refused(), 2U);
    EXPECT_EQ(s.bad_requests(), 1U);
  }
}

TEST(PageService, ASnapshotCarriesTheDaemonsStatusOrWhyNot) {
  Fake f;
  PageService s(loopback_options(), f.deps());
  json snap = json::parse(s.handle(get("/api/status")).body);
  EXPECT_TRUE(snap.at("ok").get<bool>());
  EXPECT_EQ(snap.at("status"), json::parse(kStatus));
  EXPECT_EQ(snap.at("page").at("admin_group"), "adm");
  EXPECT_TRUE(snap.at("page").at("actions").get<bool>());
  f.daemon_down = true;
  snap = json::parse(s.snapshot());
  EXPECT_FALSE(snap.at("ok").get<bool>());
  EXPECT_EQ(snap.at("error"), "cannot connect to status.sock: No such file");
  EXPECT_FALSE(snap.contains("status"));
}

TEST(PageService, SnapshotsAreTakenOnlyWhileSomeoneWatches) {
  Fake f;
  PageOptions o = loopback_options();
  o.poll_interval_s = 0.05;
  PageService s(o, f.deps());
  s.start();
  std::this_thread::sleep_for(300ms);
  {
    const std::lock_guard l(f.m);
    EXPECT_TRUE(f.requests.empty());
  }
  const auto first = s.next_snapshot(0, 5.0);
  ASSERT_TRUE(first);
  EXPECT_EQ(json::parse(first->json).at("status"), json::parse(kStatus));
  const auto second = s.next_snapshot(first->number, 5.0);
  ASSERT_TRUE(second);
  EXPECT_GT(second->number, first->number);
  s.stop();
  EXPECT_FALSE(s.next_snapshot(second->number, 5.0));
}

struct ReportDir {
  ReportDir() {
    path = fs::temp_directory_path() / ("page_report_" + std::to_string(::getpid()));
    fs::remove_all(path);
    fs::create_directories(path / "plots");
    std::ofstream(path / "summary.json") << R"({"declared_rms_um":1.9,"final_rms_um":0.49})";
    std::ofstream(path / "plots" / "residual_x_mm.svg") << "<svg/>";
    std::ofstream(path / "plots" / "notes.txt") << "x";
    std::ofstream(path / "secret.svg") << "<svg>secret</svg>";
  }
  ~ReportDir() { fs::remove_all(path); }
  fs::path path;
};

TEST(PageService, TheReportListsItsPlotsAndServesOnlyThem) {
  Fake f;
  ReportDir dir;
  PageOptions o = loopback_options();
  o.report_dir = dir.path.string();
  PageService s(o, f.deps());
  const json rep = json::parse(s.handle(get("/api/report")).body);
  EXPECT_TRUE(rep.at("configured").get<bool>());
  EXPECT_EQ(rep.at("summary").at("final_rms_um"), 0.49);
  EXPECT_EQ(rep.at("plots"), json::array({"residual_x_mm.svg"}));
  const auto svg = s.handle(get("/report/plots/residual_x_mm.svg"));
  EXPECT_EQ(svg.status, 200);
  EXPECT_EQ(svg.content_type, "image/svg+xml");
  EXPECT_EQ(svg.body, "<svg/>");
  for (const char* bad : {"/report/plots/../secret.svg", "/report/plots/..svg",
                          "/report/plots/notes.txt", "/report/plots/a%2fb.svg"}) {
    EXPECT_EQ(s.handle(get(bad)).status, 400) << bad;
  }
  EXPECT_EQ(s.handle(get("/report/plots/missing.svg")).status, 404);
  EXPECT_EQ(s.bad_requests(), 5U);

  PageService none(loopback_options(), f.deps());
  EXPECT_FALSE(json::parse(none.handle(get("/api/report")).body).at("configured").get<bool>());
  EXPECT_EQ(none.handle(get("/report/plots/residual_x_mm.svg")).status, 404);
}

}  // namespace
