// GIVEN a running loop and the status server, WHEN clients ask over the Unix socket and the
// Prometheus port, THEN they get the loop's numbers; the socket is mode 0660.
// WHEN clients trickle bytes to both, THEN many others are answered meanwhile and the tricklers
// are cut off at their deadline; clients beyond max_clients are turned away, not queued.
// WHEN users switched to in forked children (root only) send commands, THEN only root and
// members of the admin group run those that change the machine, each logged with uid, user name
// and pid, refusals too; read-only verbs and status are for everyone who can open the socket.
#include "daemon/status.hpp"

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <spdlog/sinks/base_sink.h>
#include <spdlog/spdlog.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "client/status_client.hpp"
#include "core/engine/ramp_module.hpp"
#include "drivers/loopback/loopback_bus.hpp"
#include "tests/support/run_as.hpp"

namespace nccomp::daemon {
namespace {

using drivers::loopback::LoopbackBus;

namespace fs = std::filesystem;
using namespace std::chrono_literals;

std::string http_get(int port, const std::string& path) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::connect(fd, reinterpret_cast<const sockaddr*>(&a), sizeof a) != 0) {
    ::close(fd);
    return {};
  }
  const std::string req = "GET " + path + " HTTP/1.0\r\n\r\n";
  (void)::send(fd, req.data(), req.size(), 0);
  std::string out;
  char buf[4096];
  ssize_t n = 0;
  while ((n = ::recv(fd, buf, sizeof buf, 0)) > 0) {
    out.append(buf, static_cast<std::size_t>(n));
  }
  ::close(fd);
  return out;
}

/// A loopback bus that also reports driver-specific counters (as the CAN and Modbus drivers do).
class CountingBus final : public drivers::Bus {
 public:
  CountingBus() = default;
  explicit CountingBus(std::vector<drivers::BusCounterValue> values) : values_(std::move(values)) {}
  void start() override { inner_.start(); }
  void stop() override { inner_.stop(); }
  core::rt::SpscRing<core::Event>& rx() override { return inner_.rx(); }
  core::rt::SpscRing<core::OffsetWrite>& tx() override { return inner_.tx(); }
  [[nodiscard]] drivers::BusStatus status() const override { return inner_.status(); }
  [[nodiscard]] std::size_t extra_counters(std::span<drivers::BusCounterValue> out) const override {
    std::size_t n = 0;
    for (const auto& v : values_) {
      if (n < out.size()) out[n++] = v;
    }
    return n;
  }

 private:
  std::vector<drivers::BusCounterValue> values_{{"bus_off", 2}, {"rx_overflow", 0}};
  LoopbackBus inner_{64, 64};
};

std::unique_ptr<Runtime> ramp_runtime() {
  auto rt = std::make_unique<Runtime>();
  rt->engine = std::make_unique<core::engine::Engine>();
  std::vector<std::unique_ptr<core::engine::Module>> m;
  m.push_back(std::make_unique<core::engine::RampModule>(
      core::engine::RampConfig{"ramp", "T1", 0.0, 3.0, 1000.0}));
  rt->engine->configure({{"T1", core::engine::RegisterKind::kToolLengthWear, {200.0, 5.0, 5000.0}}},
                        std::move(m));
  rt->register_bus = {0};
  return rt;
}

// A loop ramping register T1 to 3 µm on a counting loopback bus, and what status needs of it.
struct Rig {
  Rig() {
    fs::create_directories(dir);
    bus.start();
    logger.start();
    loop.start();
  }
  ~Rig() {
    loop.stop();
    logger.stop();
    bus.stop();
    fs::remove_all(dir);
  }
  StatusContext context() {
    StatusContext c;
    c.loop = &loop;
    c.buses = {{"loopback", &bus}};
    c.logger = &logger;
    c.register_names = [] { return std::vector<std::string>{"T1_length_wear"}; };
    c.register_specs = [] {
      return std::vector<core::engine::RegisterSpec>{
          {"T1_length_wear", core::engine::RegisterKind::kToolLengthWear, {200.0, 5.0, 5000.0}}};
    };
    c.config_path = "test.toml";
    c.state_path = "state.bin";
    return c;
  }
  std::string socket() const { return (dir / "s.sock").string(); }

  static inline int n = 0;
  fs::path dir = fs::temp_directory_path() /
                 ("nccomp_status_" + std::to_string(::getpid()) + "_" + std::to_string(n++));
  core::rt::ConfigSwap<Runtime> swap{ramp_runtime()};
  CountingBus bus;
  Loop loop{LoopOptions{}, swap, {&bus}, nullptr, nullptr};
  EventLogger logger{loop};
};

TEST(StatusServer, AnswersTextJsonAndPrometheus) {
  Rig rig;
  StatusServer server(rig.context());
  const std::string sock = rig.socket();
  StatusServerOptions o;
  o.socket_path = sock;
  o.prometheus_port = -1;  // any free port (tests)
  server.start(o);
  struct stat st {};
  ASSERT_EQ(::stat(sock.c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0660U);
  ASSERT_GT(server.prometheus_port(), 0);

  // Wait until the ramp has reached 3 µm and the register snapshot shows it.
  std::string json;
  for (int i = 0; i < 500; ++i) {
    json = client::query(sock, "json");
    if (json.find("\"output_um\":3,") != std::string::npos) {
      break;
    }
    std::this_thread::sleep_for(10ms);
  }
  EXPECT_NE(json.find("\"name\":\"T1_length_wear\",\"output_um\":3,"), std::string::npos) << json;
  // Each register's kind and limits (the operator page shows them).
  EXPECT_NE(json.find("\"awaiting_nc\":false,\"kind\":\"tool_length_wear\",\"max_abs_um\":200,"
                      "\"max_step_um\":5,\"max_rate_um_per_s\":5000,\"hold\":null}"),
            std::string::npos)
      << json;
  EXPECT_NE(json.find("\"buses\":[{\"name\":\"loopback\",\"state\":\"up\""), std::string::npos);
  EXPECT_NE(json.find("\"rate_hz\":1000,"), std::string::npos);
  // Driver-specific counters: all of them in JSON and metrics, only the non-zero ones in text.
  EXPECT_NE(json.find("\"counters\":{\"bus_off\":2,\"rx_overflow\":0}}"), std::string::npos)
      << json;
  const std::string text = client::query(sock, "text");
  EXPECT_NE(text.find("T1_length_wear                3.000 um"), std::string::npos) << text;
  EXPECT_NE(text.find("bus_off 2\n"), std::string::npos) << text;
  EXPECT_EQ(text.find("rx_overflow"), std::string::npos) << text;
  EXPECT_NE(client::query(sock, "bogus").find("error: unknown request 'bogus'"), std::string::npos);
  const std::string http = http_get(server.prometheus_port(), "/metrics");
  EXPECT_EQ(http.rfind("HTTP/1.0 200 OK", 0), 0U) << http;
  EXPECT_NE(http.find("nccompd_register_output_meters{register=\"T1_length_wear\"} 3e-06\n"),
            std::string::npos)
      << http;
  EXPECT_NE(http.find("nccompd_bus_up{bus=\"loopback\"} 1\n"), std::string::npos);
  EXPECT_NE(http.find("nccompd_bus_events_total{bus=\"loopback\",event=\"bus_off\"} 2\n"),
            std::string::npos)
      << http;
  EXPECT_EQ(http_get(server.prometheus_port(), "/other").rfind("HTTP/1.0 404", 0), 0U);
  // One unknown request, one 404: the server counts them.
  EXPECT_NE(client::query(sock, "json").find("\"bad_requests\":2}"), std::string::npos);

  server.stop();
  EXPECT_FALSE(fs::exists(sock));
}

TEST(StatusJson, NamesTheLiveModelTheRollbackModelAndThePromoteRule) {
  Rig rig;
  StatusContext c = rig.context();
  EXPECT_EQ(render_json(c).find("\"model\":"), std::string::npos);  // no provider: not shown
  ModelState m;
  m.has_section = true;
  m.live = {"/srv/b.toml", "00000000000000bb", "2026-11-27T10:00:00Z"};
  m.previous = {"/srv/a\"1.toml", "00000000000000aa", "2026-11-26T09:00:00Z"};
  m.chosen = true;
  m.generation = 3;
  c.model = [m] { return m; };
  sections::ShadowStatus shadow;
  shadow.phase = sections::ShadowPhase::kAnnounced;
  shadow.options.promote = sections::ShadowPromote::kOperator;
  c.shadow = [shadow] { return shadow; };
  const std::string json = render_json(c);
  EXPECT_NE(json.find("\"model\":{\"live\":{\"file\":\"/srv/b.toml\",\"hash\":\"00000000000000bb\","
                      "\"since_utc\":\"2026-11-27T10:00:00Z\"},\"previous\":{\"file\":"
                      "\"/srv/a\\\"1.toml\",\"hash\":\"00000000000000aa\",\"since_utc\":"
                      "\"2026-11-26T09:00:00Z\"},\"pending\":null,\"pending_generation\":0,"
                      "\"pending_cycles\":0,\"chosen\":true,\"generation\":3},"),
            std::string::npos)
      << json;
  // A model accepted that the loop has not swapped in: live is still the one in force.
  m.pending = true;
  m.pending_model = {"/srv/c.toml", "00000000000000cc", ""};
  m.pending_generation = 4;
  m.pending_cycles = 17;
  c.model = [m] { return m; };
  const std::string pending = render_json(c);
  EXPECT_NE(pending.find("\"pending\":{\"file\":\"/srv/c.toml\",\"hash\":\"00000000000000cc\","
                         "\"since_utc\":\"\"},\"pending_generation\":4,\"pending_cycles\":17,"),
            std::string::npos)
      << pending;
  EXPECT_NE(json.find("\"shadow\":{\"phase\":\"announced\",\"promote\":\"operator\","),
            std::string::npos)
      << json;
}

TEST(StatusMetrics, LatencyEdgesAreBucketEdges) {
  const auto edges = prometheus_latency_edges_us();
  ASSERT_FALSE(edges.empty());
  for (std::size_t i = 0; i < edges.size(); ++i) {
    EXPECT_TRUE(LatencyHistogram::is_edge_us(edges[i])) << edges[i];
    if (i > 0) {
      EXPECT_GT(edges[i], edges[i - 1]);
    }
  }
  // Not every value is an edge above 1024 µs: 5000 µs lies inside [4992, 5056).
  EXPECT_FALSE(LatencyHistogram::is_edge_us(5000));
  EXPECT_TRUE(LatencyHistogram::is_edge_us(4992));
}

// The metrics as Prometheus' own linter reads them: `promtool check metrics` (Debian's
// prometheus package) passes: base units spelled out, counters only for counts, the latency a
// histogram; a driver's gauges are gauges (in seconds where the driver counts milliseconds),
// one family across buses.
TEST(StatusMetrics, PromtoolCheckMetricsPasses) {
  if (::system("command -v promtool >/dev/null 2>&1") != 0) {
    GTEST_SKIP() << "promtool missing (Debian's prometheus package; scripts/setup installs it)";
  }
  Rig rig;
  CountingBus second(
      {{"bus_off", 0}, {"offsets_pending", 4, true}, {"reconnect_backoff_ms", 250, true}});
  CountingBus third({{"offsets_pending", 0, true}, {"reconnect_backoff_ms", 1500, true}});
  second.start();
  third.start();
  StatusContext c = rig.context();
  c.buses.push_back({"second", &second});
  c.buses.push_back({"third", &third});
  // A candidate in shadow: the live model scored on two parts, the candidate on none yet (NaN).
  sections::ShadowStatus shadow;
  shadow.phase = sections::ShadowPhase::kCandidate;
  shadow.live.add_part(4.0, 3);
  shadow.live.add_part(2.0, 1);
  shadow.other_file = "/srv/cand.toml";
  c.shadow = [shadow] { return shadow; };
  // Some latency samples first.
  for (int i = 0; i < 500 && rig.loop.latency().count() < 50; ++i) {
    std::this_thread::sleep_for(10ms);
  }
  const std::string metrics = render_prometheus(c);
  second.stop();
  third.stop();
  const fs::path file = rig.dir / "metrics.txt";
  {
    std::FILE* f = std::fopen(file.c_str(), "w");
    ASSERT_NE(f, nullptr);
    std::fwrite(metrics.data(), 1, metrics.size(), f);
    std::fclose(f);
  }
  const std::string cmd = "promtool check metrics <" + file.string() + " 2>&1";
  std::FILE* p = ::popen(cmd.c_str(), "r");
  ASSERT_NE(p, nullptr);
  std::string lint;
  char buf[512];
  std::size_t n = 0;
  while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) lint.append(buf, n);
  const int status = ::pclose(p);
  EXPECT_EQ(status, 0) << lint << "\n" << metrics;
  EXPECT_EQ(lint, "") << metrics;

  // The gauges: one family each, every bus in it, milliseconds as seconds.
  EXPECT_NE(metrics.find("# TYPE nccompd_bus_reconnect_backoff_seconds gauge\n"
                         "nccompd_bus_reconnect_backoff_seconds{bus=\"second\"} 0.25\n"
                         "nccompd_bus_reconnect_backoff_seconds{bus=\"third\"} 1.5\n"),
            std::string::npos)
      << metrics;
  EXPECT_NE(metrics.find("nccompd_bus_offsets_pending{bus=\"second\"} 4\n"), std::string::npos);
  EXPECT_NE(metrics.find("nccompd_shadow_mean_squared_error_square_meters{model=\"live\"} 3e-12\n"
                         "nccompd_shadow_mean_squared_error_square_meters{model=\"other\"} NaN\n"),
            std::string::npos)
      << metrics;
  EXPECT_EQ(metrics.find("counter=\"offsets_pending\""), std::string::npos) << metrics;
  EXPECT_EQ(metrics.find("_ms"), std::string::npos) << metrics;
  EXPECT_EQ(metrics.find("_us"), std::string::npos) << metrics;
  // The histogram: cumulative, +Inf = _count = the samples recorded.
  const std::string inf = "nccompd_loop_wake_latency_seconds_bucket{le=\"+Inf\"} ";
  const auto at = metrics.find(inf);
  ASSERT_NE(at, std::string::npos) << metrics;
  const std::uint64_t total = std::stoull(metrics.substr(at + inf.size()));
  EXPECT_GE(total, 1U);
  EXPECT_NE(metrics.find("nccompd_loop_wake_latency_seconds_count " + std::to_string(total) + "\n"),
            std::string::npos)
      << metrics;
  std::uint64_t prev = 0;
  for (const std::uint64_t e : prometheus_latency_edges_us()) {
    char le[64];
    std::snprintf(le, sizeof le, "{le=\"%.10g\"} ", static_cast<double>(e) / 1e6);
    const auto b = metrics.find(std::string("nccompd_loop_wake_latency_seconds_bucket") + le);
    ASSERT_NE(b, std::string::npos) << le << metrics;
    const std::uint64_t v = std::stoull(metrics.substr(
        b + std::strlen("nccompd_loop_wake_latency_seconds_bucket") + std::strlen(le)));
    EXPECT_GE(v, prev) << le;
    EXPECT_LE(v, total) << le;
    prev = v;
  }
}

int connect_unix(const std::string& path) {
  sockaddr_un a{};
  a.sun_family = AF_UNIX;
  std::strncpy(a.sun_path, path.c_str(), sizeof(a.sun_path) - 1);
  const int fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
  if (::connect(fd, reinterpret_cast<const sockaddr*>(&a), sizeof a) != 0) {
    ::close(fd);
    return -1;
  }
  return fd;
}

int connect_tcp(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::connect(fd, reinterpret_cast<const sockaddr*>(&a), sizeof a) != 0) {
    ::close(fd);
    return -1;
  }
  return fd;
}

// A client that sends one byte every 0.5 s and never completes its request, until the server
// answers or closes (or 30 s pass); then it reads what the server said last.
class Trickler {
 public:
  explicit Trickler(int fd) : fd_(fd), thread_([this] { run(); }) {}
  ~Trickler() { join(); }
  [[nodiscard]] bool cut_off() const { return cut_off_.load(); }
  /// Waits for the end; what the server sent.
  std::string join() {
    if (thread_.joinable()) thread_.join();
    return received_;
  }

 private:
  void run() {
    const auto end = std::chrono::steady_clock::now() + 30s;
    while (std::chrono::steady_clock::now() < end) {
      if (::send(fd_, "x", 1, MSG_NOSIGNAL) != 1) break;
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, 500) == 1) break;  // the server speaks or closes
    }
    char buf[512];
    ssize_t n = 0;
    while ((n = ::recv(fd_, buf, sizeof buf, 0)) > 0) {
      received_.append(buf, static_cast<std::size_t>(n));
    }
    cut_off_.store(true);
    ::close(fd_);
  }
  int fd_;
  std::atomic<bool> cut_off_{false};
  std::string received_;
  std::thread thread_;
};

TEST(StatusServer, TricklingClientsDelayNobodyAndAreCutOffAtTheirDeadline) {
  Rig rig;
  StatusServer server(rig.context());
  const std::string sock = rig.socket();
  StatusServerOptions o;
  o.socket_path = sock;
  o.prometheus_port = -1;
  o.client_timeout_s = 4.0;
  server.start(o);
  const int ufd = connect_unix(sock);
  const int tfd = connect_tcp(server.prometheus_port());
  ASSERT_GE(ufd, 0);
  ASSERT_GE(tfd, 0);
  Trickler on_socket(ufd);
  Trickler on_metrics(tfd);
  std::this_thread::sleep_for(600ms);  // both are in the middle of their requests

  // 24 clients at once, Unix socket and HTTP, while the tricklers hold their connections.
  std::vector<std::string> answers(24);
  std::vector<std::thread> clients;
  for (std::size_t i = 0; i < answers.size(); ++i) {
    clients.emplace_back([&, i] {
      try {
        answers[i] = i < 20 ? client::query(sock, i % 2 == 0 ? "text" : "json")
                            : http_get(server.prometheus_port(), "/metrics");
      } catch (const std::exception& e) {
        answers[i] = e.what();
      }
    });
  }
  for (auto& t : clients) t.join();
  const bool held = !on_socket.cut_off() && !on_metrics.cut_off();
  EXPECT_TRUE(held) << "the tricklers were cut off before the others were answered";
  for (std::size_t i = 0; i < answers.size(); ++i) {
    const char* want = i >= 20      ? "nccompd_loop_cycles_total"
                       : i % 2 == 0 ? "nccompd pid "
                                    : "{\"daemon\":";
    EXPECT_NE(answers[i].find(want), std::string::npos) << "client " << i << ": " << answers[i];
  }

  // At their deadline (4 s after connecting) the tricklers are told why and cut off.
  EXPECT_EQ(on_socket.join(), "error: no complete request within 4 s\n");
  EXPECT_EQ(on_metrics.join().rfind("HTTP/1.0 408 Request Timeout", 0), 0U);
  const std::string json = client::query(sock, "json");
  EXPECT_NE(json.find("\"status_server\":{\"clients\":27,\"timed_out\":2,\"turned_away\":0,"),
            std::string::npos)
      << json;
}

TEST(StatusServer, ClientsBeyondMaxClientsAreTurnedAwayNotQueued) {
  Rig rig;
  StatusServer server(rig.context());
  const std::string sock = rig.socket();
  StatusServerOptions o;
  o.socket_path = sock;
  o.max_clients = 3;
  o.client_timeout_s = 30.0;
  server.start(o);
  std::vector<int> idle;
  for (int i = 0; i < 3; ++i) idle.push_back(connect_unix(sock));
  EXPECT_EQ(client::query(sock, "text"),
            "error: busy: 3 clients are being served ([status] max_clients); try again\n");
  // One idle client goes away: its place is free again.
  ::close(idle.back());
  idle.pop_back();
  std::string text;
  for (int i = 0; i < 200 && text.rfind("nccompd pid ", 0) != 0; ++i) {
    std::this_thread::sleep_for(10ms);
    text = client::query(sock, "text");
  }
  EXPECT_EQ(text.rfind("nccompd pid ", 0), 0U) << text;
  for (const int fd : idle) ::close(fd);
}

// The log lines of the process, kept for a test to read.
class CaptureSink final : public spdlog::sinks::base_sink<std::mutex> {
 public:
  std::string text() {
    std::lock_guard<std::mutex> lock(mutex_);
    return text_;
  }

 protected:
  void sink_it_(const spdlog::details::log_msg& m) override {
    text_.append(m.payload.data(), m.payload.size());
    text_ += '\n';
  }
  void flush_() override {}

 private:
  std::string text_;
};

// Adds a CaptureSink to the default logger for its lifetime: a logger's sinks are not guarded
// against changes while it logs, so it must outlive the threads that log.
struct CapturedLog {
  CapturedLog() { spdlog::default_logger()->sinks().push_back(sink); }
  ~CapturedLog() {
    auto& sinks = spdlog::default_logger()->sinks();
    sinks.erase(std::remove(sinks.begin(), sinks.end(), sink), sinks.end());
  }
  std::shared_ptr<CaptureSink> sink = std::make_shared<CaptureSink>();
};

std::atomic<int> g_changes{0};
std::atomic<int> g_looks{0};
// A verb registered with the default access (it changes the machine), and a read-only one.
[[maybe_unused]] const int kChangeVerb =
    register_command_handler("test-change", [](std::string_view args, CommandContext&) {
      g_changes.fetch_add(1);
      return "ok changed " + std::string(args) + "\n";
    });
[[maybe_unused]] const int kLookVerb = register_command_handler(
    "test-look",
    [](std::string_view, CommandContext&) {
      g_looks.fetch_add(1);
      return std::string("ok looked\n");
    },
    &read_only);

TEST(StatusServer, OnlyRootAndTheAdminGroupChangeTheMachine) {
  if (::geteuid() != 0) {
    GTEST_SKIP() << "switching to other users and groups needs root (CI runs as root)";
  }
  // Two groups of every Debian host stand for nccomp (may open the socket) and nccomp-admin.
  const auto status_gid = nccomp::test::gid_of("users");
  const auto admin_gid = nccomp::test::gid_of("adm");
  const auto other_gid = nccomp::test::gid_of("nogroup");
  ASSERT_TRUE(status_gid && admin_gid && other_gid) << "groups users, adm, nogroup";
  const uid_t nobody = 65534;
  const std::string name = nccomp::test::user_name_of(nobody);
  CapturedLog captured;  // before the threads that log, removed after they stopped
  Rig rig;
  StatusServer server(rig.context());
  const std::string sock = rig.socket();
  StatusServerOptions o;
  o.socket_path = sock;
  o.policy = CommandPolicy{"adm", ::geteuid()};
  server.start(o);
  // As systemd's Group=: the socket belongs to the status group (mode 0660).
  ASSERT_EQ(::chown(sock.c_str(), static_cast<uid_t>(-1), *status_gid), 0);

  const nccomp::test::Identity op{nobody, *other_gid, {*status_gid}};
  const nccomp::test::Identity admin{nobody, *other_gid, {*status_gid, *admin_gid}};
  const nccomp::test::Identity admin_egid{nobody, *admin_gid, {*status_gid}};
  const nccomp::test::Identity outsider{nobody, *other_gid, {}};

  // A member of the status group only: status and read-only verbs yes, changes no.
  const auto refused = nccomp::test::request_as(op, sock, "test-change now");
  EXPECT_EQ(refused.exit_code, 0);
  EXPECT_EQ(refused.answer,
            "error: permission denied: 'test-change' changes the machine; uid 65534 (" + name +
                ") is not root and not in group 'adm' ([status] admin_group)\n"
                "  an administrator grants it with: usermod -aG adm " +
                name + " (effective at the user's next login)\n");
  EXPECT_EQ(g_changes.load(), 0);
  EXPECT_EQ(nccomp::test::request_as(op, sock, "test-look").answer, "ok looked\n");
  EXPECT_EQ(g_looks.load(), 1);
  EXPECT_EQ(nccomp::test::request_as(op, sock, "text").answer.rfind("nccompd pid ", 0), 0U);

  // A member of the admin group (supplementary, or as effective group), and root.
  const auto allowed = nccomp::test::request_as(admin, sock, "test-change now");
  EXPECT_EQ(allowed.answer, "ok changed now\n");
  const auto allowed_egid = nccomp::test::request_as(admin_egid, sock, "test-change again");
  EXPECT_EQ(allowed_egid.answer, "ok changed again\n");
  EXPECT_EQ(client::query(sock, "test-change as root"), "ok changed as root\n");
  EXPECT_EQ(g_changes.load(), 3);

  // Not in the status group: the socket's mode keeps it out (connect fails: exit 11).
  EXPECT_EQ(nccomp::test::request_as(outsider, sock, "text").exit_code, 11);

  const std::string log = captured.sink->text();
  EXPECT_NE(log.find("operator command refused: 'test-change now' from uid 65534 (" + name +
                     ") pid " + std::to_string(refused.pid) + ": permission denied: uid 65534 (" +
                     name + ") is not root and not in group 'adm' ([status] admin_group)\n"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("operator command from uid 65534 (" + name + ") pid " +
                     std::to_string(allowed.pid) + ": test-change now\n"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("operator command from uid 65534 (" + name + ") pid " +
                     std::to_string(allowed_egid.pid) + ": test-change again\n"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("operator command from uid 0 (root) pid " + std::to_string(::getpid()) +
                     ": test-change as root\n"),
            std::string::npos)
      << log;
  EXPECT_EQ(log.find("test-look"), std::string::npos) << "read-only commands are not logged";
}

}  // namespace
}  // namespace nccomp::daemon
