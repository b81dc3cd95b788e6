// GIVEN Debian's mosquitto on 127.0.0.1 (a free port, a password file made with
// mosquitto_passwd, an ACL that lets machine <m> write only nccomp/s1/<m>/#, persistence on),
// `nccomp collect` and `nccomp publish` as processes, and this test writing nccompd's
// measurement log with the daemon's own writer (rotation included), WHEN the broker restarts,
// goes away for a while, the publisher's queue overflows, the password is wrong or the ACL
// refuses the topic, THEN every row arrives once and in order where it must, the oldest rows are
// dropped and counted where the queue is full, and the errors are reported clearly with the
// rows kept queued.
//
// "An hour without a broker": nothing is lost as long as the queue holds every row measured
// while the publisher is not connected, max_messages >= (outage + reconnect back-off) × row rate
// (3 600 000 for an hour at 1000 rows/s, plus the back-off's rows). The tests keep that condition
// and compress time by the rate: a 2 s outage at 400 rows/s plus at most 1 s of back-off
// (reconnect_max_s = 1) is at most 1200 rows, with a queue of 2000 — the hour with a queue of
// 3 600 000 at 1000 rows/s is the same condition; what an hour adds is only disk space
// (bench/results/mqtt.md measures the real rates).
#include <arpa/inet.h>
#include <fcntl.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <functional>
#include <mutex>
#include <random>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "daemon/measurement_log.hpp"

extern char** environ;

namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

constexpr const char* kMosquitto = "/usr/sbin/mosquitto";

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

std::vector<std::string> lines_of(const fs::path& p) {
  std::ifstream in(p);
  std::vector<std::string> v;
  for (std::string l; std::getline(in, l);) v.push_back(l);
  return v;
}

bool wait_for(const std::function<bool()>& ok, std::chrono::milliseconds timeout) {
  const auto until = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < until) {
    if (ok()) return true;
    std::this_thread::sleep_for(20ms);
  }
  return ok();
}

// A new TCP socket bound (::bind) or connected (::connect) to 127.0.0.1:port, then closed:
// whether that succeeded.
bool on_loopback(int port, int (*op)(int, const sockaddr*, socklen_t)) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  const bool ok = op(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
  ::close(fd);
  return ok;
}

// A TCP port nobody listens on now, for a broker started (and restarted) on it later. Drawn
// below the kernel's ephemeral range (net.ipv4.ip_local_port_range), where a client's source
// port (the daemon's reconnects while the broker is down, another test's) can never take it
// between this call and the broker's bind.
int free_port() {
  int top = 32768;
  std::ifstream range("/proc/sys/net/ipv4/ip_local_port_range");
  if (int low = 0; range >> low) top = std::max(low, 20001);
  std::random_device seed;
  std::mt19937 rng(seed());
  std::uniform_int_distribution<int> pick(std::max(1024, top - 12000), top - 1);
  for (int attempt = 0; attempt < 200; ++attempt) {
    const int port = pick(rng);
    if (on_loopback(port, ::bind)) return port;
  }
  ADD_FAILURE() << "no free TCP port below " << top << " after 200 draws";
  return 0;
}

bool port_open(int port) { return on_loopback(port, ::connect); }

/// A child process with stdout and stderr in `log` (appended).
class Process {
 public:
  Process() = default;
  Process(const std::vector<std::string>& args, const fs::path& log) { start(args, log); }
  ~Process() { stop(); }
  Process(const Process&) = delete;
  Process& operator=(const Process&) = delete;

  void start(const std::vector<std::string>& args, const fs::path& log) {
    std::vector<char*> argv;
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    const std::string l = log.string();
    posix_spawn_file_actions_addopen(&fa, 1, l.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
    posix_spawn_file_actions_adddup2(&fa, 1, 2);
    // Paho's leak at a reconnect (lsan.supp) is not the processes' own.
    std::vector<std::string> env_text;
    for (char** e = environ; *e != nullptr; ++e) {
      if (std::string(*e).rfind("LSAN_OPTIONS=", 0) != 0) env_text.emplace_back(*e);
    }
    env_text.push_back(std::string("LSAN_OPTIONS=suppressions=") + NCCOMP_LSAN_SUPP +
                       ":print_suppressions=0");
    std::vector<char*> env;
    for (auto& e : env_text) env.push_back(e.data());
    env.push_back(nullptr);
    ASSERT_EQ(posix_spawn(&pid_, argv[0], &fa, nullptr, argv.data(), env.data()), 0) << args[0];
    posix_spawn_file_actions_destroy(&fa);
  }
  /// SIGTERM, then SIGKILL after 10 s. Returns the exit status (-1 if killed).
  int stop() {
    if (pid_ <= 0) return -1;
    ::kill(pid_, SIGTERM);
    int status = 0;
    for (int i = 0; i < 1000; ++i) {
      if (::waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
      }
      std::this_thread::sleep_for(10ms);
    }
    ::kill(pid_, SIGKILL);
    ::waitpid(pid_, &status, 0);
    pid_ = -1;
    return -1;
  }
  [[nodiscard]] bool running() const { return pid_ > 0 && ::kill(pid_, 0) == 0; }

 private:
  pid_t pid_{-1};
};

/// A stand-in for nccompd's status socket: answers every request with the JSON it is given
/// (the daemon's status format: daemon, loop, modules, alarms), as nccompd does (one request
/// line, one answer, close).
class FakeStatusSocket {
 public:
  explicit FakeStatusSocket(const std::string& path) : path_(path) {
    fd_ = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_un a{};
    a.sun_family = AF_UNIX;
    std::snprintf(a.sun_path, sizeof a.sun_path, "%s", path.c_str());
    ::unlink(path.c_str());
    EXPECT_EQ(::bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
    EXPECT_EQ(::listen(fd_, 8), 0);
    thread_ = std::thread([this] {
      while (!stop_.load()) {
        const int c = ::accept(fd_, nullptr, nullptr);
        if (c < 0) continue;
        char buf[64];
        (void)::recv(c, buf, sizeof buf, 0);
        std::string answer;
        {
          std::lock_guard<std::mutex> lock(mu_);
          answer = answer_;
          ++requests_;
        }
        (void)::send(c, answer.data(), answer.size(), MSG_NOSIGNAL);
        ::close(c);
      }
    });
  }
  ~FakeStatusSocket() {
    stop_.store(true);
    ::shutdown(fd_, SHUT_RDWR);
    ::close(fd_);
    thread_.join();
    ::unlink(path_.c_str());
  }
  void set(const nlohmann::json& j) {
    std::lock_guard<std::mutex> lock(mu_);
    answer_ = j.dump() + "\n";
  }
  int requests() {
    std::lock_guard<std::mutex> lock(mu_);
    return requests_;
  }

 private:
  std::string path_;
  int fd_{-1};
  std::atomic<bool> stop_{false};
  std::mutex mu_;
  std::string answer_{"{}\n"};
  int requests_{0};
  std::thread thread_;
};

class MqttHil : public ::testing::Test {
 protected:
  void SetUp() override {
    if (::access(kMosquitto, X_OK) != 0) GTEST_SKIP() << kMosquitto << " is not installed";
    dir_ = fs::temp_directory_path() /
           ("nccomp_mqtt_hil_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "log");
    fs::create_directories(dir_ / "broker");
    port_ = free_port();
    // Users: two machines and the collector; mosquitto_passwd hashes the passwords.
    std::ofstream(dir_ / "broker" / "passwd") << "";
    ::chmod((dir_ / "broker" / "passwd").c_str(), 0600);
    for (const auto& [user, pw] : {std::pair{"m1", "pw-m1"}, {"m2", "pw-m2"}, {"coll", "pw-c"}}) {
      const std::string cmd =
          "mosquitto_passwd -b " + (dir_ / "broker" / "passwd").string() + " " + user + " " + pw;
      ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
    }
    std::ofstream(dir_ / "broker" / "acl") << "user coll\ntopic read nccomp/#\n"
                                           << "pattern write nccomp/s1/%u/#\n";
    std::ofstream conf(dir_ / "broker" / "mosquitto.conf");
    conf << "listener " << port_ << " 127.0.0.1\n"
         << "allow_anonymous false\n"
         << "password_file " << (dir_ / "broker" / "passwd").string() << "\n"
         << "acl_file " << (dir_ / "broker" / "acl").string() << "\n"
         << "persistence true\n"
         << "persistence_location " << (dir_ / "broker").string() << "/\n"
         << "max_queued_messages 100000\n"
         << "log_dest stderr\nlog_type all\n";
    // As root mosquitto drops to the user `mosquitto`, who cannot read the test's files.
    if (::geteuid() == 0) conf << "user root\n";
    conf.close();
    write_secret("coll.pw", "pw-c");
  }

  void TearDown() override {
    publisher_.stop();
    collector_.stop();
    broker_.stop();
    if (!HasFailure()) fs::remove_all(dir_);
  }

  void write_secret(const std::string& name, const std::string& pw) {
    std::ofstream(dir_ / name) << pw << "\n";
    ::chmod((dir_ / name).c_str(), 0600);
  }

  void start_broker() {
    broker_.start({kMosquitto, "-c", (dir_ / "broker" / "mosquitto.conf").string()},
                  dir_ / "broker.log");
    ASSERT_TRUE(wait_for([&] { return port_open(port_); }, 10s)) << slurp(dir_ / "broker.log");
  }

  std::string broker_uri() const { return "tcp://127.0.0.1:" + std::to_string(port_); }

  /// Starts the collector and waits until its subscription stands (its session then keeps rows
  /// for it while it is away).
  void start_collector() {
    collector_.start({NCCOMP_BIN, "collect", "--broker", broker_uri(), "--out",
                      (dir_ / "out").string(), "--username", "coll", "--password-file",
                      (dir_ / "coll.pw").string(), "--client-id", "hil-collector"},
                     dir_ / "collect.log");
    ASSERT_TRUE(wait_for(
        [&] { return slurp(dir_ / "collect.log").find("subscribed") != std::string::npos; }, 20s))
        << slurp(dir_ / "collect.log");
  }

  void write_publisher_config(const std::string& machine, const std::string& user,
                              std::int64_t max_messages, const std::string& status_socket = "") {
    std::ofstream(dir_ / "pub.toml")
        << "[publish]\nsite = \"s1\"\nmachine = \"" << machine << "\"\nheartbeat_s = 1\n"
        << "[source]\nlog_directory = \"log\"\npoll_s = 0.05\nstatus_socket = \"" << status_socket
        << "\"\nstatus_poll_s = 0.1\n"
        << "[broker]\nuri = \"" << broker_uri() << "\"\nusername = \"" << user
        << "\"\npassword_file = \"" << user << ".pw\"\nreconnect_max_s = 1\n"
        << "[queue]\ndirectory = \"queue\"\nmax_messages = " << max_messages << "\n";
  }

  void start_publisher() {
    publisher_.start({NCCOMP_BIN, "publish", "--config", (dir_ / "pub.toml").string()},
                     dir_ / "publish.log");
  }

  /// The log writer as nccompd runs it, with small files so that the test sees rotations.
  std::unique_ptr<nccomp::daemon::MeasurementLogWriter> make_writer(const std::string& machine) {
    nccomp::daemon::MeasurementLogOptions o;
    o.directory = (dir_ / "log").string();
    o.machine_id = machine;
    o.context_columns = {{"spindle_rpm", 3}};
    o.max_file_bytes = 64 * 1024;
    o.keep_files = 50;
    auto w = std::make_unique<nccomp::daemon::MeasurementLogWriter>(o);
    w->start();
    return w;
  }

  /// Writes rows point = next_point_ … at `rate_hz` for `seconds`.
  void write_rows(nccomp::daemon::MeasurementLogWriter& w, double rate_hz, double seconds) {
    const auto n = static_cast<int>(rate_hz * seconds);
    const auto start = std::chrono::steady_clock::now();
    for (int i = 0; i < n; ++i) {
      nccomp::core::MeasurementRecord r;
      r.time_ns = 1'000'000'000LL + next_point_ * 1'000'000LL;
      r.kind = nccomp::core::MeasurementKind::kContour;
      r.point = next_point_++;
      r.measured_um = 0.5 * r.point;
      r.session = 7;
      r.context[0] = 8000.0 + r.point;
      while (!w.ring().try_push(r)) std::this_thread::sleep_for(1ms);
      std::this_thread::sleep_until(
          start + std::chrono::microseconds(static_cast<std::int64_t>((i + 1) * 1e6 / rate_hz)));
    }
  }

  /// The collector's rows for a machine: the `point` of each, in file order.
  std::vector<int> collected_points(const std::string& machine) {
    std::vector<int> points;
    const auto lines = lines_of(dir_ / "out" / "s1" / (machine + ".csv"));
    for (std::size_t i = 1; i < lines.size(); ++i) {
      std::vector<std::string> cells;
      std::stringstream ss(lines[i]);
      for (std::string c; std::getline(ss, c, ',');) cells.push_back(c);
      points.push_back(std::stoi(cells.at(4)));
    }
    return points;
  }

  /// The retained heartbeat of a machine, read with mosquitto_sub.
  nlohmann::json heartbeat(const std::string& machine) {
    const fs::path out = dir_ / "status.json";
    const std::string cmd = "mosquitto_sub -p " + std::to_string(port_) +
                            " -u coll -P pw-c -t nccomp/s1/" + machine + "/status -C 1 -W 5 > " +
                            out.string();
    if (std::system(cmd.c_str()) != 0) return nullptr;
    return nlohmann::json::parse(slurp(out), nullptr, false);
  }

  static std::vector<int> range(int from, int to) {
    std::vector<int> v;
    for (int i = from; i < to; ++i) v.push_back(i);
    return v;
  }

  fs::path dir_;
  int port_{0};
  int next_point_{0};
  Process broker_;
  Process collector_;
  Process publisher_;
};

TEST_F(MqttHil, BrokerRestartsAndANetworkCutLoseNothingAndDeliverInOrderOnce) {
  start_broker();
  start_collector();
  write_secret("m1.pw", "pw-m1");
  write_publisher_config("m1", "m1", 2000);
  auto w = make_writer("m1");
  start_publisher();
  write_rows(*w, 400, 1.0);
  // A broker restart (stopped and started at once); both clients come back.
  broker_.stop();
  start_broker();
  const auto count = [&](const std::string& file, const std::string& what) {
    const std::string text = slurp(dir_ / file);
    std::size_t n = 0;
    for (std::size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) {
      ++n;
    }
    return n;
  };
  write_rows(*w, 400, 1.0);
  ASSERT_TRUE(wait_for(
      [&] {
        return count("publish.log", "] connected") >= 2 && count("collect.log", "subscribed") >= 2;
      },
      10s))
      << slurp(dir_ / "publish.log") << slurp(dir_ / "collect.log");
  // The network cut: the broker is away for 2 s while 800 rows are measured (queued on disk).
  broker_.stop();
  write_rows(*w, 400, 2.0);
  ASSERT_TRUE(
      wait_for([&] { return slurp(dir_ / "publish.log").find("lost") != std::string::npos; }, 5s))
      << slurp(dir_ / "publish.log");
  start_broker();
  write_rows(*w, 400, 1.0);
  w->stop();
  const int total = next_point_;
  ASSERT_TRUE(wait_for(
      [&] { return collected_points("m1").size() >= static_cast<std::size_t>(total); }, 60s))
      << collected_points("m1").size() << " of " << total << "\n"
      << slurp(dir_ / "publish.log") << slurp(dir_ / "collect.log");
  std::this_thread::sleep_for(500ms);  // anything late would be a duplicate or out of order
  EXPECT_EQ(collected_points("m1"), range(0, total));
  // The sequence numbers are 1…total, the collector's log is a v2 log with the context column.
  const auto lines = lines_of(dir_ / "out" / "s1" / "m1.csv");
  EXPECT_EQ(lines.front(),
            nccomp::formats::measurement_log::csv_header({{"spindle_rpm", 3}}) + ",seq");
  EXPECT_EQ(lines.back().substr(lines.back().rfind(',') + 1), std::to_string(total));
  const auto hb = heartbeat("m1");
  ASSERT_TRUE(hb.is_object());
  EXPECT_EQ(hb.at("publisher").at("dropped").at("measurements"), 0);
  EXPECT_EQ(publisher_.stop(), 0);
  EXPECT_EQ(collector_.stop(), 0);
  // The collector's own count of the duplicates it dropped (at-least-once after reconnects).
  std::cout << "[          ] collector: " << lines_of(dir_ / "collect.log").back().substr(0, 200)
            << "\n";
}

TEST_F(MqttHil, AFullQueueDropsTheOldestRowsAndCountsThem) {
  start_broker();
  start_collector();
  broker_.stop();  // the publisher finds no broker
  write_secret("m1.pw", "pw-m1");
  write_publisher_config("m1", "m1", 64);  // segments of 4 rows
  auto w = make_writer("m1");
  start_publisher();
  write_rows(*w, 500, 0.4);
  w->stop();
  const int total = next_point_;  // 200
  ASSERT_TRUE(wait_for(
      [&] { return slurp(dir_ / "publish.log").find("queue full") != std::string::npos; }, 10s))
      << slurp(dir_ / "publish.log");
  // Everything read from the log: the state on disk says so.
  ASSERT_TRUE(wait_for(
      [&] {
        const auto s = nlohmann::json::parse(slurp(dir_ / "queue" / "state.json"), nullptr, false);
        return s.is_object() && s.at("next_seq").value("measurements", 0) == total + 1;
      },
      10s));
  start_broker();
  ASSERT_TRUE(wait_for([&] { return collected_points("m1").size() >= 64; }, 30s))
      << slurp(dir_ / "publish.log");
  std::this_thread::sleep_for(1s);
  // The newest rows, in order, once; the oldest were dropped, and counted.
  const auto got = collected_points("m1");
  ASSERT_GE(got.size(), 60U);
  ASSERT_LE(got.size(), 64U);
  EXPECT_EQ(got, range(total - static_cast<int>(got.size()), total));
  const auto hb = heartbeat("m1");
  ASSERT_TRUE(hb.is_object()) << slurp(dir_ / "publish.log");
  EXPECT_EQ(
      hb.at("publisher").at("dropped").at("measurements").get<int>() + static_cast<int>(got.size()),
      total);
  const std::string log = slurp(dir_ / "publish.log");
  EXPECT_NE(log.find("measurement row(s)"), std::string::npos) << log;
}

TEST_F(MqttHil, AWrongPasswordIsAClearErrorAndTheRowsStayQueued) {
  start_broker();
  start_collector();
  write_secret("m1.pw", "not-the-password");
  write_publisher_config("m1", "m1", 1000);
  auto w = make_writer("m1");
  start_publisher();
  write_rows(*w, 200, 0.5);
  ASSERT_TRUE(wait_for(
      [&] { return slurp(dir_ / "publish.log").find("cannot connect") != std::string::npos; },
      10s));
  const std::string log = slurp(dir_ / "publish.log");
  EXPECT_NE(log.find("as m1: 135 Not authorized"), std::string::npos) << log;
  EXPECT_NE(log.find("message(s) stay queued"), std::string::npos) << log;
  EXPECT_EQ(log.find("not-the-password"), std::string::npos) << "the password is in the log";
  EXPECT_EQ(publisher_.stop(), 0);
  EXPECT_TRUE(collected_points("m1").empty());
  // The operator fixes the password: every row measured meanwhile arrives, in order.
  write_secret("m1.pw", "pw-m1");
  start_publisher();
  write_rows(*w, 200, 0.5);
  w->stop();
  ASSERT_TRUE(wait_for(
      [&] { return collected_points("m1").size() >= static_cast<std::size_t>(next_point_); }, 30s))
      << slurp(dir_ / "publish.log");
  EXPECT_EQ(collected_points("m1"), range(0, next_point_));
}

TEST_F(MqttHil, TheBrokerRefusesAnotherMachinesTopicAndThePublisherReportsIt) {
  start_broker();
  start_collector();
  // Logged in as m1, publishing as machine m2: the ACL lets m1 write only nccomp/s1/m1/#.
  write_secret("m1.pw", "pw-m1");
  write_publisher_config("m2", "m1", 1000);
  auto w = make_writer("m2");
  start_publisher();
  write_rows(*w, 200, 0.25);
  w->stop();
  ASSERT_TRUE(wait_for(
      [&] { return slurp(dir_ / "publish.log").find("refused") != std::string::npos; }, 20s))
      << slurp(dir_ / "publish.log");
  // Every row read from the log into the queue (the state is saved every second).
  ASSERT_TRUE(wait_for(
      [&] {
        const auto s = nlohmann::json::parse(slurp(dir_ / "queue" / "state.json"), nullptr, false);
        return s.is_object() && s.at("next_seq").value("measurements", 0) == next_point_ + 1;
      },
      10s));
  const std::string log = slurp(dir_ / "publish.log");
  EXPECT_NE(log.find("135 Not authorized"), std::string::npos) << log;
  EXPECT_NE(log.find("check the broker's ACL for user 'm1'"), std::string::npos) << log;
  EXPECT_EQ(publisher_.stop(), 0);
  EXPECT_TRUE(collected_points("m2").empty());
  // Nothing was acknowledged: every row is still queued.
  const auto s = nlohmann::json::parse(slurp(dir_ / "queue" / "state.json"));
  EXPECT_EQ(s.at("next_id").get<int>() - s.at("head").get<int>(), next_point_);
}

TEST_F(MqttHil, AlarmsAcknowledgementsAndTheModelArePublishedOnceAlsoAcrossARestart) {
  start_broker();
  write_secret("m1.pw", "pw-m1");
  const std::string sock = (dir_ / "status.sock").string();
  FakeStatusSocket status(sock);
  const auto alarm = [](double t_s, int code, int subject) {
    return nlohmann::json{{"time_s", t_s},      {"severity", "alarm"},
                          {"code", code},       {"name", "tool_broken_or_mismeasured"},
                          {"subject", subject}, {"value", 12.5}};
  };
  const auto answer = [&](nlohmann::json alarms, int acknowledged) {
    return nlohmann::json{
        {"daemon", {{"pid", 4242}, {"config_generation", 1}, {"hold", false}}},
        {"loop", {{"cycles", 1000}, {"overruns", 0}, {"latency_us", {{"p99_9", 20.0}}}}},
        {"modules",
         {{{"name", "creep"},
           {"status", {{"acknowledged", acknowledged}, {"last_acknowledge", "halt released"}}}}}},
        {"measurement_log", {{"rows", 0}, {"errors", 0}}},
        {"alarms", std::move(alarms)}};
  };
  status.set(answer({alarm(100.0, 23, 4)}, 0));
  const fs::path seen = dir_ / "alarms.txt";
  Process sub({"/usr/bin/mosquitto_sub", "-p", std::to_string(port_), "-u", "coll", "-P", "pw-c",
               "-t", "nccomp/s1/m1/alarms", "-t", "nccomp/s1/m1/model", "-v", "-q", "1"},
              seen);
  std::this_thread::sleep_for(300ms);
  write_publisher_config("m1", "m1", 1000, sock);
  start_publisher();
  const auto count = [&](const std::string& what) {
    const std::string text = slurp(seen);
    std::size_t n = 0;
    for (std::size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) {
      ++n;
    }
    return n;
  };
  ASSERT_TRUE(wait_for([&] { return count("\"event\":\"alarm\"") == 1; }, 20s))
      << slurp(seen) << slurp(dir_ / "publish.log");
  // Polled again and again (every 0.1 s): still one. Then a second alarm and an acknowledgement.
  ASSERT_TRUE(wait_for([&] { return status.requests() >= 10; }, 10s));
  status.set(answer({alarm(100.0, 23, 4), alarm(101.5, 23, 5)}, 1));
  ASSERT_TRUE(wait_for([&] { return count("\"event\":\"acknowledge\"") == 1; }, 10s))
      << slurp(seen);
  // A restart of the publisher sees the same list: nothing new.
  EXPECT_EQ(publisher_.stop(), 0);
  start_publisher();
  const int before = status.requests();
  ASSERT_TRUE(wait_for([&] { return status.requests() >= before + 10; }, 10s));
  std::this_thread::sleep_for(500ms);
  EXPECT_EQ(count("\"event\":\"alarm\""), 2U) << slurp(seen);
  EXPECT_EQ(count("\"event\":\"acknowledge\""), 1U) << slurp(seen);
  EXPECT_EQ(count("nccomp/s1/m1/model "), 1U) << slurp(seen);
  // Sequence numbers of the alarms topic: 1, 2, 3 in the order sent.
  EXPECT_NE(slurp(seen).find("{\"seq\":3,\"machine\":\"m1\""), std::string::npos) << slurp(seen);
  const auto hb = heartbeat("m1");
  ASSERT_TRUE(hb.is_object());
  EXPECT_EQ(hb.at("daemon").at("pid"), 4242);
  EXPECT_EQ(hb.at("daemon").at("latency_us_p99_9"), 20.0);
}

}  // namespace
