#include "tools/page/page_service.hpp"

#include <algorithm>
#include <cctype>
#include <chrono>
#include <ctime>
#include <exception>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <vector>

#include "client/protocol.hpp"
#include "tools/page/page_assets.hpp"

namespace nccomp::page {

namespace {

namespace fs = std::filesystem;
using nlohmann::json;

std::string utc_now() {
  const auto now = std::chrono::system_clock::now();
  const std::time_t t = std::chrono::system_clock::to_time_t(now);
  const auto ms =
      std::chrono::duration_cast<std::chrono::milliseconds>(now.time_since_epoch()).count() % 1000;
  std::tm tm{};
  ::gmtime_r(&t, &tm);
  char stamp[32];
  std::strftime(stamp, sizeof stamp, "%Y-%m-%dT%H:%M:%S", &tm);
  char millis[8];
  std::snprintf(millis, sizeof millis, ".%03dZ", static_cast<int>(ms));
  return std::string(stamp) + millis;
}

std::string peer(const Endpoint& e) { return e.address + ":" + std::to_string(e.port); }

bool starts_with_nocase(std::string_view s, std::string_view prefix) {
  if (s.size() < prefix.size()) return false;
  for (std::size_t i = 0; i < prefix.size(); ++i) {
    if (std::tolower(static_cast<unsigned char>(s[i])) != prefix[i]) return false;
  }
  return true;
}

// A plot's file name: letters, digits, '_', '-', '.', ending in ".svg", no leading dot; so it
// can only name a file directly in the plots directory.
bool valid_plot_name(std::string_view name) {
  if (name.size() < 5 || name.size() > 128 || name.front() == '.') return false;
  if (name.substr(name.size() - 4) != ".svg") return false;
  for (char c : name) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '_' || c == '-' || c == '.';
    if (!ok) return false;
  }
  return true;
}

std::optional<std::string> read_file(const fs::path& p, std::size_t max_bytes) {
  std::error_code ec;
  const auto size = fs::file_size(p, ec);
  if (ec || size > max_bytes) return std::nullopt;
  std::ifstream f(p, std::ios::binary);
  if (!f) return std::nullopt;
  std::ostringstream s;
  s << f.rdbuf();
  return s.str();
}

// The actions the page may send: each maps to one request of the status socket, whose own
// permission check (the admin group) applies again in nccompd.
struct KnownAction {
  std::string_view name;
  std::string (*request)();
};
constexpr KnownAction kActions[] = {{"acknowledge", client::acknowledge_request},
                                    {"model_promote", client::model_promote_request},
                                    {"model_rollback", client::model_rollback_request}};

std::string known_actions() {
  std::string s;
  for (const auto& k : kActions) s += (s.empty() ? "" : ", ") + std::string(k.name);
  return s;
}

constexpr std::size_t kMaxReportFileBytes = 8U << 20U;
constexpr std::string_view kPlotPrefix = "/report/plots/";

}  // namespace

PageService::PageService(PageOptions options, PageDeps deps)
    : options_(std::move(options)), deps_(std::move(deps)) {}

PageService::~PageService() { stop(); }

HttpReply PageService::error(int status, const std::string& message) {
  ++bad_requests_;
  HttpReply r;
  r.status = status;
  r.body = json{{"error", message}}.dump() + "\n";
  return r;
}

HttpReply PageService::handle(const HttpRequest& request) {
  struct Route {
    std::string_view path;
    std::string_view method;
  };
  static constexpr Route kRoutes[] = {{"/", "GET"},
                                      {"/page.js", "GET"},
                                      {"/page.css", "GET"},
                                      {"/api/status", "GET"},
                                      {"/api/report", "GET"},
                                      {"/api/action", "POST"},
                                      {"/favicon.ico", "GET"},
                                      {"/events", "GET"}};
  std::string_view path = request.path;
  std::string_view method_wanted;
  for (const auto& r : kRoutes) {
    if (path == r.path) method_wanted = r.method;
  }
  if (method_wanted.empty() && path.substr(0, kPlotPrefix.size()) == kPlotPrefix) {
    method_wanted = "GET";
  }
  // Another site's name resolved to this host (DNS rebinding) reads and acts as nobody.
  if (!options_.allowed_hosts.empty() &&
      std::find(options_.allowed_hosts.begin(), options_.allowed_hosts.end(), request.host) ==
          options_.allowed_hosts.end()) {
    return error(403, "Host '" + request.host + "' is not this page's address (open the page as " +
                          "http://" + options_.allowed_hosts.front() + "/)");
  }
  if (method_wanted.empty()) return error(404, "no such page: " + request.path);
  if (request.method != method_wanted && !(method_wanted == "GET" && request.method == "HEAD")) {
    HttpReply r = error(405, "method " + request.method + " not allowed on " + request.path +
                                 " (use " + std::string(method_wanted) + ")");
    r.allow = std::string(method_wanted);
    return r;
  }
  if (path == "/api/action") return action(request);
  if (path == "/api/status") {
    HttpReply r;
    r.body = snapshot();
    return r;
  }
  if (path == "/events") return HttpReply{};  // allowed: the server streams it (page_server)
  if (path == "/api/report") return report();
  if (path == "/favicon.ico") {
    HttpReply r;  // no icon: answered, so that browsers asking for one are not bad requests
    r.status = 204;
    r.content_type = "image/x-icon";
    return r;
  }
  if (path.substr(0, kPlotPrefix.size()) == kPlotPrefix) {
    HttpReply r = plot(path.substr(kPlotPrefix.size()));
    if (r.status != 200) ++bad_requests_;
    return r;
  }
  HttpReply r;
  if (path == "/") {
    r.content_type = "text/html; charset=utf-8";
    r.body = std::string(kIndexHtml);
  } else if (path == "/page.js") {
    r.content_type = "text/javascript; charset=utf-8";
    r.body = std::string(kPageJs);
  } else {
    r.content_type = "text/css; charset=utf-8";
    r.body = std::string(kPageCss);
  }
  return r;
}

HttpReply PageService::action(const HttpRequest& request) {
  // Cross-site requests: a form of another site cannot send application/json without a CORS
  // preflight, which this server never grants; a script that could is refused by Origin.
  if (!starts_with_nocase(request.content_type, "application/json")) {
    return error(415, "an action is a JSON body: Content-Type must be application/json, not '" +
                          request.content_type + "'");
  }
  if (!request.origin.empty() && request.origin != "http://" + request.host) {
    return error(403, "cross-origin request refused: Origin '" + request.origin +
                          "' is not this page (http://" + request.host + ")");
  }
  if (request.body.size() > options_.max_body_bytes) {
    return error(413, "an action's body is at most " + std::to_string(options_.max_body_bytes) +
                          " bytes, got " + std::to_string(request.body.size()));
  }
  json body;
  try {
    body = json::parse(request.body);
  } catch (const json::exception& e) {
    return error(400, std::string("bad JSON: ") + e.what());
  }
  if (!body.is_object()) return error(400, "an action is a JSON object, e.g. {\"action\": ...}");
  for (const auto& [key, value] : body.items()) {
    if (key != "action" && key != "confirmed") {
      return error(400, "unknown key '" + key + "' (known: action, confirmed)");
    }
  }
  const auto a = body.find("action");
  if (a == body.end() || !a->is_string()) {
    return error(400, "\"action\" (a string) is missing");
  }
  const std::string name = a->get<std::string>();
  const auto known = std::find_if(std::begin(kActions), std::end(kActions),
                                  [&](const KnownAction& k) { return k.name == name; });
  if (known == std::end(kActions)) {
    return error(400, "unknown action '" + name + "' (known: " + known_actions() + ")");
  }
  const auto c = body.find("confirmed");
  if (c == body.end() || !c->is_boolean() || !c->get<bool>()) {
    return error(400, "the action is not confirmed: \"confirmed\": true is required");
  }

  // Who asks: a refusal past this point is a valid request from someone not allowed.
  const auto refuse = [&](int status, const std::string& who, const std::string& why) {
    ++actions_refused_;
    deps_.log("warning", "action refused: " + name + " by " + who + " from " +
                             peer(request.client) + ": " + why);
    HttpReply r;
    r.status = status;
    r.body = json{{"error", why}}.dump() + "\n";
    return r;
  };
  if (!options_.actions) {
    return refuse(403, "?",
                  "actions are off: the page listens beyond this host and was not started with "
                  "--remote-actions");
  }
  std::string who;
  if (is_loopback_ipv4(request.client.address)) {
    const auto uid = deps_.client_uid(request.client, request.server);
    if (!uid) {
      return refuse(403, "?",
                    "cannot tell which user opened the connection (no socket " +
                        peer(request.client) + " -> " + peer(request.server) +
                        " in /proc/net/tcp)");
    }
    const Permission p = deps_.permission(*uid);
    if (!p.allowed) return refuse(403, p.user, "permission denied: " + p.why);
    who = p.user;
  } else if (options_.remote_actions) {
    who = "remote client " + request.client.address;  // no user to check: --remote-actions
  } else {
    return refuse(403, "remote client " + request.client.address,
                  "actions come only from this host (--remote-actions allows others)");
  }

  const std::lock_guard lock(action_mutex_);
  deps_.log("info", "action: " + name + " by " + who + " from " + peer(request.client) +
                        ", sent to nccompd as the page's own user");
  std::string answer;
  try {
    answer = deps_.query(known->request());
  } catch (const std::exception& e) {
    ++actions_refused_;
    deps_.log("warning", "action " + name + " by " + who + " failed: " + e.what());
    HttpReply r;
    r.status = 502;
    r.body = json{{"error", std::string("nccompd cannot be reached: ") + e.what()}}.dump() + "\n";
    return r;
  }
  if (client::is_error(answer)) {
    ++actions_refused_;
    const std::string why = client::error_reason(answer);
    deps_.log("warning", "action " + name + " by " + who + " refused by nccompd: " + why);
    HttpReply r;
    r.status = 409;
    r.body = json{{"error", "nccompd refused: " + why}}.dump() + "\n";
    return r;
  }
  ++actions_done_;
  deps_.log("info", "action " + name + " by " + who + ": " + answer.substr(0, answer.find('\n')));
  HttpReply r;
  r.body = json{{"ok", true}, {"by", who}, {"answer", answer}}.dump() + "\n";
  return r;
}

nlohmann::json PageService::page_json() const {
  std::string report_mtime;
  if (!options_.report_dir.empty()) {
    std::error_code ec;
    const auto t = fs::last_write_time(fs::path(options_.report_dir) / "summary.json", ec);
    if (!ec) report_mtime = std::to_string(t.time_since_epoch().count());
  }
  return json{{"bad_requests", bad_requests_.load()},
              {"actions_done", actions_done_.load()},
              {"actions_refused", actions_refused_.load()},
              {"actions", options_.actions},
              {"admin_group", options_.admin_group},
              {"report", !options_.report_dir.empty()},
              {"report_version", report_mtime}};
}

std::string PageService::snapshot() {
  json s;
  s["time_utc"] = utc_now();
  try {
    const std::string answer = deps_.query(client::kStatusJson);
    try {
      s["status"] = json::parse(answer);
      s["ok"] = true;
    } catch (const json::exception& e) {
      s["ok"] = false;
      s["error"] = std::string("nccompd's status is not JSON: ") + e.what();
    }
  } catch (const std::exception& e) {
    s["ok"] = false;
    s["error"] = e.what();
  }
  s["page"] = page_json();
  return s.dump();
}

HttpReply PageService::report() const {
  HttpReply r;
  json out;
  out["configured"] = !options_.report_dir.empty();
  if (options_.report_dir.empty()) {
    r.body = out.dump();
    return r;
  }
  const fs::path dir(options_.report_dir);
  out["dir"] = options_.report_dir;
  const auto summary = read_file(dir / "summary.json", kMaxReportFileBytes);
  if (!summary) {
    out["error"] = "no readable summary.json in " + options_.report_dir;
  } else {
    try {
      out["summary"] = json::parse(*summary);
    } catch (const json::exception& e) {
      out["error"] = (dir / "summary.json").string() + " is not JSON: " + e.what();
    }
    std::error_code ec;
    const auto t = fs::last_write_time(dir / "summary.json", ec);
    if (!ec) {
      const auto sys = std::chrono::file_clock::to_sys(t);
      const std::time_t tt = std::chrono::system_clock::to_time_t(sys);
      std::tm tm{};
      ::gmtime_r(&tt, &tm);
      char buf[32];
      std::strftime(buf, sizeof buf, "%Y-%m-%d %H:%M:%S UTC", &tm);
      out["written_utc"] = buf;
    }
  }
  std::vector<std::string> plots;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir / "plots", ec)) {
    const std::string name = e.path().filename().string();
    if (e.is_regular_file() && valid_plot_name(name)) plots.push_back(name);
  }
  std::sort(plots.begin(), plots.end());
  out["plots"] = plots;
  r.body = out.dump();
  return r;
}

HttpReply PageService::plot(std::string_view name) const {
  HttpReply r;
  if (options_.report_dir.empty()) {
    r.status = 404;
    r.body = json{{"error", "no report is configured (--report-dir)"}}.dump() + "\n";
    return r;
  }
  if (!valid_plot_name(name)) {
    r.status = 400;
    r.body = json{{"error", "not a plot's name: '" + std::string(name) +
                                "' (letters, digits, '_', '-', '.', ending in .svg)"}}
                 .dump() +
             "\n";
    return r;
  }
  const auto svg =
      read_file(fs::path(options_.report_dir) / "plots" / std::string(name), kMaxReportFileBytes);
  if (!svg) {
    r.status = 404;
    r.body = json{{"error", "no plot " + std::string(name) + " in the report"}}.dump() + "\n";
    return r;
  }
  r.content_type = "image/svg+xml";
  r.body = *svg;
  return r;
}

void PageService::start() {
  const std::lock_guard lock(mutex_);
  if (poller_.joinable()) return;
  stopping_ = false;
  poller_ = std::thread([this] { poll_loop(); });
}

void PageService::stop() {
  {
    const std::lock_guard lock(mutex_);
    stopping_ = true;
  }
  changed_.notify_all();
  if (poller_.joinable()) poller_.join();
}

void PageService::poll_loop() {
  const auto period = std::chrono::duration<double>(options_.poll_interval_s);
  std::unique_lock lock(mutex_);
  while (!stopping_) {
    // Nobody watching: no requests to the daemon.
    changed_.wait(lock, [&] { return stopping_ || watchers_ > 0; });
    if (stopping_) break;
    lock.unlock();
    std::string s = snapshot();
    lock.lock();
    latest_ = std::move(s);
    ++number_;
    changed_.notify_all();
    changed_.wait_for(lock, period, [&] { return stopping_; });
  }
}

std::optional<PageService::Numbered> PageService::next_snapshot(std::uint64_t after,
                                                                double timeout_s) {
  std::unique_lock lock(mutex_);
  ++watchers_;
  changed_.notify_all();
  const bool got = changed_.wait_for(lock, std::chrono::duration<double>(timeout_s),
                                     [&] { return stopping_ || number_ > after; });
  --watchers_;
  if (!got || stopping_) return std::nullopt;
  return Numbered{number_, latest_};
}

}  // namespace nccomp::page
