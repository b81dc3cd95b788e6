// GIVEN the nccompd binary with a loopback bus and a commissioning ramp, WHEN it is killed with
// SIGKILL mid-ramp and restarted, THEN the ramp resumes from the persisted value (no restart from
// zero, nothing doubled); a corrupt state file holds the offsets with an alarm; a bad reload is
// refused while the old configuration keeps running; SIGTERM persists and exits 0.
#include <fcntl.h>
#include <grp.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "client/status_client.hpp"
#include "core/engine/engine.hpp"
#include "daemon/config/builtin_sections.hpp"
#include "daemon/config/config.hpp"
#include "daemon/state_store.hpp"
#include "tests/support/nccompd_process.hpp"
#include "tests/support/status_json.hpp"
#include "tests/support/temp_dir.hpp"

extern char** environ;

namespace {

using nccomp::test::number;
using nccomp::test::TempDir;

namespace fs = std::filesystem;
using namespace std::chrono_literals;

std::string config_text(double target_um, double rate_um_per_s, const std::string& extra = "") {
  std::ostringstream s;
  s << "[daemon]\nrate_hz = 1000\n"
    << "[state]\ndirectory = \"state\"\nmin_interval_s = 0.05\n"
    << "[measurement_log]\ndirectory = \"log\"\n"
    << "[status]\nsocket_path = \"status.sock\"\n"
    << "[loopback]\n"
    << "[[registers]]\nname = \"T1_length_wear\"\nkind = \"tool_length_wear\"\nbus = \"loopback\"\n"
    << "max_abs_um = 200\nmax_step_um = 5\nmax_rate_um_per_s = 50\n"
    << "[[ramp]]\nname = \"test\"\nregister = \"T1_length_wear\"\ntarget_um = " << target_um
    << "\nrate_um_per_s = " << rate_um_per_s << "\n"
    << extra;
  return s.str();
}

class Daemon : public nccomp::test::NccompdProcess {
 public:
  explicit Daemon(fs::path dir) : NccompdProcess(std::move(dir), NCCOMPD_BIN) {}
};

bool flag(const std::string& json, const std::string& key) {
  return json.find("\"" + key + "\":true") != std::string::npos;
}

// The value of register T1_length_wear in an engine state (read back through an engine with the
// same register, the way nccompd restores it).
double register_in_state(const std::vector<std::byte>& payload) {
  nccomp::core::engine::Engine e;
  e.configure(
      {{"T1_length_wear", nccomp::core::engine::RegisterKind::kToolLengthWear, {200.0, 5.0, 50.0}}},
      {});
  std::size_t skipped = 0;
  if (!e.import_state(payload, 0, &skipped)) {
    return -1e300;
  }
  return e.register_state(0).output_um;
}

TEST(NccompdProcess, KillNineMidRampResumesWithoutDoubling) {
  TempDir d;
  d.write("nccompd.toml", config_text(30.0, 10.0));
  double before_kill = 0.0;
  {
    Daemon p(d.path);
    p.start();
    const auto s =
        p.wait_status([](const std::string& j) { return number(j, "output_um") >= 8.0; });
    before_kill = number(s, "output_um");
    p.signal(SIGKILL);
    EXPECT_EQ(p.wait(), 128 + SIGKILL);
  }
  ASSERT_GE(before_kill, 8.0);
  ASSERT_LT(before_kill, 30.0);
  const auto f = nccomp::daemon::read_state_file((d.path / "state" / "state.bin").string());
  ASSERT_EQ(f.status, nccomp::daemon::StateFileStatus::kOk) << f.reason;

  Daemon p(d.path);
  p.start();
  const auto first = p.wait_status([](const std::string& j) { return number(j, "cycles") >= 1; });
  const double resumed = number(first, "output_um");
  // Persisted at most min_interval_s (0.05 s = 0.5 µm) plus the query-to-kill gap before the
  // kill; after the restart the ramp continues from there at 10 µm/s. Never from 0.
  EXPECT_GE(resumed, before_kill - 2.0) << p.log();
  EXPECT_LE(resumed, before_kill + 3.0) << p.log();
  const auto done =
      p.wait_status([](const std::string& j) { return number(j, "output_um") >= 30.0; });
  // Target reached exactly once: 30 µm, not 30 + what was done before the kill.
  EXPECT_DOUBLE_EQ(number(done, "output_um"), 30.0);
  std::this_thread::sleep_for(300ms);
  const auto later = p.try_status();
  ASSERT_TRUE(later);
  EXPECT_DOUBLE_EQ(number(*later, "output_um"), 30.0);
  EXPECT_NE(p.log().find("state resumed from"), std::string::npos) << p.log();
  p.signal(SIGTERM);
  EXPECT_EQ(p.wait(), 0) << p.log();
}

TEST(NccompdProcess, CorruptStateHoldsOffsetsWithAnAlarm) {
  TempDir d;
  d.write("nccompd.toml", config_text(30.0, 10.0));
  fs::create_directories(d.path / "state");
  d.write("state/state.bin", "NCCOMPST this is not a valid state file at all............");
  const auto before = fs::file_size(d.path / "state" / "state.bin");
  Daemon p(d.path);
  p.start();
  const auto s = p.wait_status([](const std::string& j) { return number(j, "cycles") >= 200; });
  EXPECT_TRUE(flag(s, "hold")) << s;
  EXPECT_NE(s.find("\"state_problem\":\"state file"), std::string::npos) << s;
  EXPECT_NE(s.find("\"name\":\"state_corrupt\""), std::string::npos) << s;
  EXPECT_EQ(number(s, "writes_sent"), 0.0);
  EXPECT_EQ(number(s, "output_um"), 0.0);
  const auto text = p.try_status("text");
  ASSERT_TRUE(text);
  EXPECT_NE(text->find("HOLD: offsets are held"), std::string::npos) << *text;
  p.signal(SIGTERM);
  EXPECT_EQ(p.wait(), 0);
  // The corrupt file is left for the operator, not overwritten.
  EXPECT_EQ(fs::file_size(d.path / "state" / "state.bin"), before);
}

TEST(NccompdProcess, BadReloadIsRefusedGoodReloadSwapsIn) {
  TempDir d;
  d.write("nccompd.toml", config_text(5.0, 50.0));
  Daemon p(d.path);
  p.start();
  p.wait_status([](const std::string& j) { return number(j, "output_um") >= 5.0; });
  d.write("nccompd.toml", config_text(5.0, 50.0, "[status2]\nx = 1\n"));
  p.signal(SIGHUP);
  std::this_thread::sleep_for(400ms);
  auto s = p.wait_status([](const std::string& j) { return number(j, "cycles") > 0; });
  EXPECT_EQ(number(s, "config_generation"), 1.0);
  EXPECT_NE(p.log().find("reload refused"), std::string::npos) << p.log();
  EXPECT_NE(p.log().find("status2: unknown section"), std::string::npos) << p.log();
  const double cycles = number(s, "cycles");
  s = p.wait_status([&](const std::string& j) { return number(j, "cycles") > cycles + 100; });

  d.write("nccompd.toml", config_text(-5.0, 50.0));
  p.signal(SIGHUP);
  s = p.wait_status([](const std::string& j) {
    return number(j, "config_generation") > 1.5 && number(j, "output_um") <= -5.0;
  });
  EXPECT_DOUBLE_EQ(number(s, "output_um"), -5.0);
  EXPECT_EQ(number(s, "reloads"), 1.0);
  p.signal(SIGTERM);
  EXPECT_EQ(p.wait(), 0) << p.log();
}

TEST(NccompdProcess, DryRunWritesNothing) {
  TempDir d;
  d.write("nccompd.toml", config_text(5.0, 50.0));
  Daemon p(d.path);
  p.start({"--dry-run"});
  const auto s =
      p.wait_status([](const std::string& j) { return number(j, "writes_dry_run") >= 10; });
  EXPECT_TRUE(flag(s, "dry_run"));
  EXPECT_EQ(number(s, "writes_sent"), 0.0);
  EXPECT_EQ(number(s, "offsets_written"), 0.0);
  p.signal(SIGTERM);
  EXPECT_EQ(p.wait(), 0);
}

// systemd's notify protocol, with the test as the service manager: READY=1 after start-up,
// WATCHDOG=1 while the loop runs (WATCHDOG_USEC=200 ms → fed every 100 ms), STOPPING=1 at SIGTERM.
TEST(NccompdProcess, NotifiesReadyWatchdogAndStopping) {
  TempDir d;
  d.write("nccompd.toml", config_text(5.0, 50.0));
  const std::string sock = (d.path / "notify.sock").string();
  const int fd = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  ASSERT_GE(fd, 0);
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  std::memcpy(addr.sun_path, sock.c_str(), sock.size() + 1);
  ASSERT_EQ(::bind(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr), 0);
  timeval tv{0, 200'000};
  ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  Daemon p(d.path);
  p.env = {"NOTIFY_SOCKET=" + sock, "WATCHDOG_USEC=200000"};
  p.start();
  std::string all;
  int watchdogs = 0;
  bool ready = false;
  const auto end = std::chrono::steady_clock::now() + 15s;
  while (std::chrono::steady_clock::now() < end && watchdogs < 5) {
    char buf[1024];
    const ssize_t n = ::recv(fd, buf, sizeof buf, 0);
    if (n > 0) {
      const std::string msg(buf, static_cast<std::size_t>(n));
      all += msg + "|";
      ready = ready || msg.find("READY=1") != std::string::npos;
      // The watchdog is only fed after READY=1.
      if (msg.find("WATCHDOG=1") != std::string::npos) {
        EXPECT_TRUE(ready) << all;
        ++watchdogs;
      }
    }
  }
  EXPECT_TRUE(ready) << all;
  EXPECT_GE(watchdogs, 5) << all;
  EXPECT_NE(all.find("STATUS=running: loop 1000 Hz"), std::string::npos) << all;
  p.signal(SIGTERM);
  bool stopping = false;
  for (int i = 0; i < 50 && !stopping; ++i) {
    char buf[1024];
    const ssize_t n = ::recv(fd, buf, sizeof buf, 0);
    stopping = n > 0 && std::string(buf, static_cast<std::size_t>(n)).find("STOPPING=1") !=
                            std::string::npos;
  }
  EXPECT_TRUE(stopping);
  EXPECT_EQ(p.wait(), 0);
  ::close(fd);
}

// systemd's notify socket, played by the test: a thread collects every datagram with its time.
class NotifySocket {
 public:
  explicit NotifySocket(std::string path) : path_(std::move(path)) {
    fd_ = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    EXPECT_GE(fd_, 0);
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    std::memcpy(addr.sun_path, path_.c_str(), path_.size() + 1);
    EXPECT_EQ(::bind(fd_, reinterpret_cast<const sockaddr*>(&addr), sizeof addr), 0);
    timeval tv{0, 50'000};
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    thread_ = std::thread([this] {
      while (!stop_.load()) {
        char buf[1024];
        const ssize_t n = ::recv(fd_, buf, sizeof buf, 0);
        if (n > 0) {
          std::lock_guard<std::mutex> lock(mu_);
          got_.emplace_back(std::chrono::steady_clock::now(),
                            std::string(buf, static_cast<std::size_t>(n)));
        }
      }
    });
  }
  ~NotifySocket() {
    stop_.store(true);
    thread_.join();
    ::close(fd_);
  }
  using Message = std::pair<std::chrono::steady_clock::time_point, std::string>;
  std::vector<Message> messages() {
    std::lock_guard<std::mutex> lock(mu_);
    return got_;
  }

 private:
  std::string path_;
  int fd_{-1};
  std::atomic<bool> stop_{false};
  std::mutex mu_;
  std::vector<Message> got_;
  std::thread thread_;
};

// A stalled loop stops the watchdog: with WATCHDOG_USEC = 200 ms the daemon feeds every 100 ms
// while the loop's heartbeat advances; when the loop thread stops cycling (test hook: it stalls
// after 800 cycles, the process and its other threads stay alive) no WATCHDOG=1 follows, so
// systemd would kill and restart the service after WatchdogSec.
TEST(NccompdProcess, StalledLoopStopsFeedingTheWatchdog) {
  TempDir d;
  d.write("nccompd.toml", config_text(5.0, 50.0));
  NotifySocket notify((d.path / "notify.sock").string());
  Daemon p(d.path);
  p.env = {"NOTIFY_SOCKET=" + (d.path / "notify.sock").string(), "WATCHDOG_USEC=200000",
           "NCCOMPD_TEST_STALL_AFTER_CYCLES=800"};
  p.start();
  // Wait until the loop has stalled: its cycle count stops at 800 while the status thread still
  // answers.
  const auto s = p.wait_status([](const std::string& j) { return number(j, "cycles") >= 800; });
  ASSERT_EQ(number(s, "cycles"), 800) << s;
  const auto stalled_seen = std::chrono::steady_clock::now();
  std::this_thread::sleep_for(1500ms);  // 15 feed periods
  const auto later = p.try_status();
  ASSERT_TRUE(later) << "the status thread must keep answering";
  EXPECT_EQ(number(*later, "cycles"), 800) << *later;
  p.signal(SIGTERM);
  EXPECT_EQ(p.wait(), 0) << p.log();

  int before = 0;
  int after = 0;
  bool ready = false;
  std::chrono::steady_clock::time_point last_feed{};
  for (const auto& [t, msg] : notify.messages()) {
    ready = ready || msg.find("READY=1") != std::string::npos;
    if (msg.find("WATCHDOG=1") != std::string::npos) {
      (t < stalled_seen ? before : after) += 1;
      last_feed = t;
    }
  }
  EXPECT_TRUE(ready);
  EXPECT_GE(before, 3) << "fed while the loop ran (0.8 s at one feed per 100 ms)";
  // The stall is seen one feed period after it began at most (the feeder compares the heartbeat
  // with the one of its previous check): no feed later than that.
  EXPECT_LE(after, 1);
  EXPECT_LT(last_feed, stalled_seen + 250ms);
  EXPECT_NE(p.log().find("loop heartbeat stalled at"), std::string::npos) << p.log();
}

// SIGTERM leaves the final state on disk: with min_interval_s = 3600 the loop persists once (the
// ramp's first step) and not again; the value the ramp reached afterwards arrives in the file
// only through the write at exit.
TEST(NccompdProcess, SigtermWritesTheFinalState) {
  TempDir d;
  std::string text = config_text(5.0, 50.0);
  text.replace(text.find("min_interval_s = 0.05"), 21, "min_interval_s = 3600");
  d.write("nccompd.toml", text);
  const auto path = (d.path / "state" / "state.bin").string();
  Daemon p(d.path);
  p.start();
  const auto s = p.wait_status([](const std::string& j) { return number(j, "output_um") >= 5.0; });
  EXPECT_DOUBLE_EQ(number(s, "output_um"), 5.0);
  std::this_thread::sleep_for(100ms);
  // The one periodic write came at the first change (or not at all, when the machine has been up
  // for less than min_interval_s of CLOCK_MONOTONIC): it does not hold the 5 µm.
  const auto during = nccomp::daemon::read_state_file(path);
  std::uint64_t during_sequence = 0;
  if (during.status == nccomp::daemon::StateFileStatus::kOk) {
    EXPECT_LT(register_in_state(during.payload), 1.0) << "periodic write after the first step";
    during_sequence = during.sequence;
  } else {
    EXPECT_EQ(during.status, nccomp::daemon::StateFileStatus::kAbsent) << during.reason;
  }
  p.signal(SIGTERM);
  EXPECT_EQ(p.wait(), 0) << p.log();
  const auto after = nccomp::daemon::read_state_file(path);
  ASSERT_EQ(after.status, nccomp::daemon::StateFileStatus::kOk) << after.reason;
  EXPECT_GT(after.sequence, during_sequence);
  EXPECT_DOUBLE_EQ(register_in_state(after.payload), 5.0);
}

// The value of `Key=` in systemd/nccompd.service ("" if absent).
std::string unit_setting(const std::string& key) {
  std::ifstream in(std::string(NCCOMP_SOURCE_DIR) + "/systemd/nccompd.service");
  for (std::string l; std::getline(in, l);) {
    if (l.rfind(key + "=", 0) == 0) {
      return l.substr(key.size() + 1);
    }
  }
  return {};
}

constexpr int kCannotSetLimits = 120;

// nccompd as the unit runs it: an unprivileged user (no capabilities) with the unit's
// LimitRTPRIO / LimitMEMLOCK (memlock 0 = leave it), and the shipped [daemon.realtime] settings.
// Returns the log, or nullopt if this machine does not let root set those limits.
std::optional<std::string> run_as_unprivileged(const fs::path& dir, rlim_t rtprio, rlim_t memlock) {
  const std::string cfg = (dir / "nccompd.toml").string();
  const std::string log = (dir / "nccompd.log").string();
  const pid_t pid = ::fork();
  if (pid == 0) {
    // Child: async-signal-safe calls only until exec.
    const rlimit rt{rtprio, rtprio};
    const rlimit ml{memlock, memlock};
    const int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (fd < 0 || ::dup2(fd, 1) < 0 || ::dup2(fd, 2) < 0) {
      ::_exit(119);
    }
    if (::setrlimit(RLIMIT_RTPRIO, &rt) != 0 ||
        (memlock != 0 && ::setrlimit(RLIMIT_MEMLOCK, &ml) != 0)) {
      ::_exit(kCannotSetLimits);  // raising a hard limit needs CAP_SYS_RESOURCE
    }
    if (::setgroups(0, nullptr) != 0 || ::setgid(65534) != 0 || ::setuid(65534) != 0) {
      ::_exit(119);
    }
    const char* argv[] = {NCCOMPD_BIN, "--config", cfg.c_str(), nullptr};
    ::execve(NCCOMPD_BIN, const_cast<char* const*>(argv), environ);
    ::_exit(121);
  }
  // Until the loop runs (its set-up is logged before READY), then stop it. Up to 120 s: in the
  // system test's VM (tests/system, emulated CPU) the sanitizer build takes tens of seconds to
  // start.
  std::string text;
  for (int i = 0; i < 2400 && text.find("loop running at") == std::string::npos; ++i) {
    int early = 0;
    if (::waitpid(pid, &early, WNOHANG) == pid) {
      if (WIFEXITED(early) && WEXITSTATUS(early) == kCannotSetLimits) {
        return std::nullopt;
      }
      ADD_FAILURE() << "nccompd ended early, status " << early;
      return std::string();
    }
    std::this_thread::sleep_for(50ms);
    std::ifstream in(log);
    std::ostringstream ss;
    ss << in.rdbuf();
    text = ss.str();
  }
  std::this_thread::sleep_for(200ms);
  ::kill(pid, SIGTERM);
  int st = 0;
  ::waitpid(pid, &st, 0);
  std::ifstream in(log);
  std::ostringstream ss;
  ss << in.rdbuf();
  EXPECT_TRUE(WIFEXITED(st) && WEXITSTATUS(st) == 0) << "status " << st << "\n" << ss.str();
  return ss.str();
}

// What the shipped config asks for and what the unit grants, read from the files themselves.
struct RealtimePolicy {
  int priority{0};
  std::size_t prefault_kib{0};
  int unit_rtprio{0};
};
RealtimePolicy shipped_policy() {
  auto shipped =
      nccomp::daemon::config::load_file(std::string(NCCOMP_SOURCE_DIR) + "/config/nccompd.toml");
  EXPECT_TRUE(shipped.config) << shipped.diagnostics.to_string();
  if (!shipped.config) {
    return {};
  }
  const auto& rt = nccomp::daemon::config::daemon_section(*shipped.config);
  EXPECT_GT(rt.sched_fifo_priority, 0) << "the shipped config must ask for SCHED_FIFO";
  EXPECT_TRUE(rt.lock_memory) << "the shipped config must lock memory";
  EXPECT_GT(rt.prefault_stack_kib, 0U);
  const int unit_rtprio = std::stoi("0" + unit_setting("LimitRTPRIO"));
  EXPECT_GE(unit_rtprio, rt.sched_fifo_priority) << "LimitRTPRIO below the shipped priority";
  EXPECT_EQ(unit_setting("LimitMEMLOCK"), "infinity");
  EXPECT_EQ(unit_setting("RestrictRealtime"), "no");
  EXPECT_EQ(unit_setting("CapabilityBoundingSet"), "") << "the limits replace capabilities";
  return {rt.sched_fifo_priority, rt.prefault_stack_kib, unit_rtprio};
}

void write_realtime_config(const TempDir& d, const RealtimePolicy& p) {
  fs::permissions(d.path, fs::perms::all);  // the unprivileged user writes state, log, socket
  std::ostringstream realtime;
  realtime << "[daemon.realtime]\nsched_fifo_priority = " << p.priority
           << "\nlock_memory = true\nprefault_stack_kib = " << p.prefault_kib << "\n";
  d.write("nccompd.toml", config_text(5.0, 50.0, realtime.str()));
}

// The shipped config asks for SCHED_FIFO and locked memory, the unit allows both through its
// rlimits only; without LimitRTPRIO an unprivileged nccompd is refused, says so and runs on
// (SCHED_OTHER): the rlimit is what grants the policy.
TEST(NccompdProcess, ShippedRealtimePolicyNeedsTheUnitsRtprioLimit) {
  if (::geteuid() != 0) {
    GTEST_SKIP() << "needs root to become the unprivileged user (CI runs as root)";
  }
  const RealtimePolicy p = shipped_policy();
  ASSERT_GT(p.priority, 0);
  TempDir d;
  write_realtime_config(d, p);
  const auto refused = run_as_unprivileged(d.path, 0, 0);
  ASSERT_TRUE(refused.has_value());
  EXPECT_NE(refused->find("SCHED_FIFO priority " + std::to_string(p.priority) +
                          " refused: Operation not permitted (running SCHED_OTHER)"),
            std::string::npos)
      << *refused;
}

// On an installed system the loop runs SCHED_FIFO with its memory locked: an unprivileged user
// with no capability and the unit's LimitRTPRIO / LimitMEMLOCK gets the shipped policy.
TEST(NccompdProcess, UnitLimitsGrantTheShippedRealtimePolicy) {
  if (::geteuid() != 0) {
    GTEST_SKIP() << "needs root to become the unprivileged user (CI runs as root)";
  }
  const RealtimePolicy p = shipped_policy();
  ASSERT_GT(p.priority, 0);
  TempDir d;
  write_realtime_config(d, p);
  const auto granted_log =
      run_as_unprivileged(d.path, static_cast<rlim_t>(p.unit_rtprio), RLIM_INFINITY);
  if (!granted_log) {
    GTEST_SKIP() << "this machine does not let root raise RLIMIT_RTPRIO / RLIMIT_MEMLOCK (no "
                    "CAP_SYS_RESOURCE, e.g. a container): this test needs a host where root (or "
                    "systemd) can set the unit's limits";
  }
  const std::string& granted = *granted_log;
  EXPECT_NE(granted.find("loop thread: SCHED_FIFO priority " + std::to_string(p.priority) + "\n"),
            std::string::npos)
      << granted;
  EXPECT_NE(
      granted.find("loop thread: " + std::to_string(p.prefault_kib) + " KiB of stack pre-faulted"),
      std::string::npos)
      << granted;
#if defined(NCCOMP_ASAN) || defined(NCCOMP_TSAN)
  EXPECT_NE(granted.find("lock_memory ignored: this is a sanitizer build"), std::string::npos)
      << granted;
#else
  EXPECT_NE(granted.find("memory locked (mlockall)"), std::string::npos) << granted;
#endif
}

TEST(NccompdProcess, InvalidConfigExitsWithStatus3AndNamesTheLine) {
  TempDir d;
  d.write("nccompd.toml", "[daemon]\nrate_hz = 1000\nrate_khz = 1\n");
  Daemon p(d.path);
  p.start();
  EXPECT_EQ(p.wait(), 3);
  EXPECT_NE(p.log().find("nccompd.toml:3:12: daemon.rate_khz: unknown key"), std::string::npos)
      << p.log();
}

}  // namespace
