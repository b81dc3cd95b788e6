// GIVEN the nccompd binary polling the project's Modbus NC server (sim/modbus_nc) on 127.0.0.1
// with a map that reads two fault-triggering addresses (exception 2 and exception 6 every poll),
// a plausibility range on X, read-back verification, and an NC that alters the first offset write
// it acknowledges, WHEN the NC skips two tool-measurement events and publishes an absurd X,
// THEN the Modbus driver's own counters (exceptions per code, lost events, out-of-range values,
// verify mismatches, pending offsets, connect attempts) are in the running daemon's status: the
// JSON `nccomp status --json` prints (client::query, the call the CLI makes), the text
// status (non-zero ones) and the Prometheus metrics.
//
// The I/O thread's real-time policy in the running daemon: with [modbus] io_sched_fifo_priority
// below the loop's, nccompd logs what the thread got and shows it in the status
// (io_sched_fifo_priority); started without CAP_SYS_NICE and with RLIMIT_RTPRIO 0, both the loop's
// and the I/O thread's SCHED_FIFO are refused with warnings and the daemon runs on.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <linux/capability.h>
#include <sched.h>
#include <signal.h>
#include <spawn.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <optional>
#include <regex>
#include <span>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "client/status_client.hpp"
#include "sim/modbus_nc/nc_server.hpp"
#include "tests/support/temp_dir.hpp"
#include "tests/support/wait.hpp"

extern char** environ;

namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using nccomp::sim::modbus_nc::kExceptionBase;
using nccomp::sim::modbus_nc::NcServer;
using nccomp::sim::modbus_nc::ServerConfig;
using nccomp::sim::modbus_nc::Tables;
using nccomp::sim::modbus_nc::WriteRecord;

std::string config_text(std::uint16_t port, const std::string& realtime = "",
                        const std::string& modbus_rt = "") {
  std::ostringstream s;
  s << "[daemon]\nrate_hz = 200\n"
    << realtime << "[state]\ndirectory = \"state\"\nmin_interval_s = 0.05\n"
    << "[measurement_log]\ndirectory = \"log\"\n"
    << "[status]\nsocket_path = \"status.sock\"\n"
    // No poll_rate_hz: the driver polls at the loop rate.
    << "[modbus]\ntransport = \"tcp\"\nhost = \"127.0.0.1\"\nport = " << port << "\n"
    << "response_timeout_s = 0.5\nverify_writes = true\n"
    << modbus_rt << "[modbus.axis]\n"
    << "x_mm = { table = \"input\", address = 0, type = \"int32\", scale = 0.0001, min = -1000, "
       "max = 1000 }\n"
    << "[modbus.tool_measurement]\n"
    << "sequence = { table = \"input\", address = 100, type = \"uint16\" }\n"
    << "tool = { table = \"input\", address = 101, type = \"uint16\" }\n"
    << "wear_um = { table = \"input\", address = 102, type = \"float32\" }\n"
    << "[[modbus.temperature]]\nsensor = 0\ntable = \"input\"\naddress = " << kExceptionBase + 2
    << "\n"
    << "[[modbus.temperature]]\nsensor = 1\ntable = \"holding\"\naddress = " << kExceptionBase + 6
    << "\n"
    << "[[modbus.offset]]\nregister_index = 0\naddress = 200\ntype = \"int32\"\nscale = 0.1\n"
    << "[[registers]]\nname = \"T1_length_wear\"\nkind = \"tool_length_wear\"\nbus = \"modbus\"\n"
    << "max_abs_um = 200\nmax_step_um = 5\nmax_rate_um_per_s = 1000\n"
    << "[[ramp]]\nname = \"commissioning\"\nregister = \"T1_length_wear\"\ntarget_um = 12.3\n"
    << "rate_um_per_s = 100\n";
  return s.str();
}

using nccomp::test::TempDir;

/// nccompd as a child process; SIGKILLed by the destructor if still running.
class Daemon {
 public:
  explicit Daemon(fs::path dir) : dir_(std::move(dir)) {}
  ~Daemon() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
  }
  Daemon(const Daemon&) = delete;
  Daemon& operator=(const Daemon&) = delete;
  /// without_realtime: the daemon runs without CAP_SYS_NICE (dropped from the bounding set, so
  /// root's exec does not regain it) and with RLIMIT_RTPRIO 0: SCHED_FIFO is refused.
  void start(bool without_realtime = false) {
    std::string bin = NCCOMPD_BIN;
    std::string flag = "--config";
    std::string cfg = (dir_ / "nccompd.toml").string();
    std::vector<char*> argv{bin.data(), flag.data(), cfg.data(), nullptr};
    if (without_realtime) {
      const std::string log = (dir_ / "nccompd.log").string();
      pid_ = ::fork();
      ASSERT_GE(pid_, 0);
      if (pid_ == 0) {
        // The child of a threaded process: async-signal-safe calls only, then exec.
        const rlimit none{0, 0};
        if (::prctl(PR_CAPBSET_DROP, CAP_SYS_NICE, 0, 0, 0) != 0 ||
            ::setrlimit(RLIMIT_RTPRIO, &none) != 0) {
          ::_exit(126);
        }
        const int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
        if (fd < 0 || ::dup2(fd, 1) < 0 || ::dup2(fd, 2) < 0) {
          ::_exit(126);
        }
        ::execve(bin.c_str(), argv.data(), environ);
        ::_exit(127);
      }
      return;
    }
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    const std::string log = (dir_ / "nccompd.log").string();
    posix_spawn_file_actions_addopen(&fa, 1, log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
    posix_spawn_file_actions_adddup2(&fa, 1, 2);
    ASSERT_EQ(posix_spawn(&pid_, bin.c_str(), &fa, nullptr, argv.data(), environ), 0);
    posix_spawn_file_actions_destroy(&fa);
  }
  /// SIGTERM and the exit status (-1 if it did not end within 10 s).
  int terminate() {
    ::kill(pid_, SIGTERM);
    const auto end = std::chrono::steady_clock::now() + 10s;
    while (std::chrono::steady_clock::now() < end) {
      int st = 0;
      if (::waitpid(pid_, &st, WNOHANG) == pid_) {
        pid_ = -1;
        return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
      }
      std::this_thread::sleep_for(10ms);
    }
    return -1;
  }
  [[nodiscard]] std::string status(const std::string& what) const {
    try {
      return nccomp::client::query((dir_ / "status.sock").string(), what);
    } catch (const std::exception&) {
      return {};
    }
  }
  [[nodiscard]] pid_t pid() const { return pid_; }
  [[nodiscard]] std::string log() const {
    std::ifstream in(dir_ / "nccompd.log");
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
  }

 private:
  fs::path dir_;
  pid_t pid_{-1};
};

/// The "counters" object of the bus named `bus` in the status JSON ("" if absent).
std::string bus_counters(const std::string& json, const std::string& bus) {
  const auto at = json.find("{\"name\":\"" + bus + "\",\"state\"");
  if (at == std::string::npos) {
    return {};
  }
  const auto c = json.find("\"counters\":{", at);
  const auto e = c == std::string::npos ? c : json.find('}', c);
  return e == std::string::npos ? std::string{} : json.substr(c, e - c + 1);
}

/// A counter's value in that object; nullopt if the name is not there.
std::optional<std::uint64_t> counter(const std::string& counters, const std::string& name) {
  const std::regex re("\"" + name + "\":([0-9]+)");
  std::smatch m;
  if (!std::regex_search(counters, m, re)) {
    return std::nullopt;
  }
  return std::stoull(m[1]);
}

using nccomp::test::wait_until;

void set_i32(std::span<std::uint16_t> regs, std::size_t at, std::int32_t v) {
  const auto u = static_cast<std::uint32_t>(v);
  regs[at] = static_cast<std::uint16_t>(u >> 16);
  regs[at + 1] = static_cast<std::uint16_t>(u & 0xFFFF);
}

std::int32_t holding_i32(NcServer& nc, std::uint16_t address) {
  const auto r = nc.holding(address, 2);
  return static_cast<std::int32_t>((std::uint32_t{r[0]} << 16) | r[1]);
}

TEST(ModbusNccompdCounters, FaultCountersOfTheDriverAreInTheDaemonsStatus) {
  TempDir d;
  NcServer nc(ServerConfig{});
  // The NC acknowledges the first write of the offset register but holds one count more.
  std::atomic<int> writes_to_200{0};
  nc.set_after_write([&](const WriteRecord& w, Tables& t) {
    if (w.address == 200 && ++writes_to_200 == 1) {
      t.holding[201] = static_cast<std::uint16_t>(t.holding[201] + 1);
    }
  });
  nc.update([](Tables& t) { set_i32(t.input, 0, 123456); });  // X = 12.3456 mm
  nc.start();
  std::ofstream(d.path / "nccompd.toml") << config_text(nc.port());
  Daemon daemon(d.path);
  daemon.start();
  // The ramp's 12.3 µm arrive (123 counts), verified by read-back.
  ASSERT_TRUE(wait_until([&] { return holding_i32(nc, 200) == 123; }, 15000ms)) << daemon.log();
  std::string json;
  ASSERT_TRUE(wait_until(
      [&] {
        json = daemon.status("json");
        return !bus_counters(json, "modbus").empty();
      },
      5000ms))
      << daemon.log();

  // The NC produces three tool measurements between two polls (two lost), then an X of
  // 2000 mm, beyond the map's max of 1000 mm.
  nc.update([](Tables& t) {
    t.input[101] = 1;
    t.input[100] = 3;
  });
  nc.update([](Tables& t) { set_i32(t.input, 0, 20'000'000); });
  std::string c;
  ASSERT_TRUE(wait_until(
      [&] {
        json = daemon.status("json");
        c = bus_counters(json, "modbus");
        return counter(c, "events_lost").value_or(0) == 2 &&
               counter(c, "values_out_of_range").value_or(0) >= 3 &&
               counter(c, "exception_illegal_address").value_or(0) >= 10 &&
               counter(c, "exception_server_busy").value_or(0) >= 10;
      },
      5000ms))
      << c << "\n"
      << daemon.log();
  // Every name is there (zeros too), in the JSON as in the driver.
  for (const char* name :
       {"exception_illegal_function", "exception_illegal_value", "exception_gateway_path",
        "exception_gateway_target", "exception_other", "timeouts", "crc_errors", "bad_responses",
        "connection_errors", "poll_overruns", "sequence_resets",
        "sequence_unchanged_after_reconnect", "values_invalid", "offsets_rejected"}) {
    EXPECT_TRUE(counter(c, name).has_value()) << name << " missing in " << c;
  }
  EXPECT_EQ(counter(c, "verify_mismatches"), 1U) << c;
  EXPECT_EQ(counter(c, "offsets_pending"), 0U) << c;
  // One connection for nccompd's start-up read-back of the offset register (read_offset, before
  // the bus starts), one for the I/O thread; no reconnect.
  EXPECT_EQ(counter(c, "connect_attempts"), 2U) << c;
  EXPECT_EQ(counter(c, "timeouts"), 0U) << c;
  EXPECT_EQ(counter(c, "exception_illegal_value"), 0U) << c;
  EXPECT_EQ(counter(c, "values_invalid"), 0U) << c;
  // An exception is an answer: the link stays up (degraded: faults every poll), no alarm, nothing
  // is reconnected.
  EXPECT_NE(json.find("{\"name\":\"modbus\",\"state\":\"degraded\",\"alarm\":false"),
            std::string::npos)
      << json;
  EXPECT_NE(json.find("\"reconnects\":0,"), std::string::npos) << json;

  // Text status: the non-zero ones, by name.
  const std::string text = daemon.status("text");
  EXPECT_NE(text.find("events_lost 2"), std::string::npos) << text;
  EXPECT_NE(text.find("verify_mismatches 1"), std::string::npos) << text;
  EXPECT_NE(text.find("exception_illegal_address "), std::string::npos) << text;
  EXPECT_NE(text.find("exception_server_busy "), std::string::npos) << text;
  EXPECT_NE(text.find("values_out_of_range "), std::string::npos) << text;
  EXPECT_EQ(text.find("crc_errors"), std::string::npos) << "zero counters are not printed\n"
                                                        << text;
  // Metrics: one series per counter.
  const std::string metrics = daemon.status("metrics");
  EXPECT_NE(metrics.find("nccompd_bus_events_total{bus=\"modbus\",event=\"events_lost\"} 2\n"),
            std::string::npos)
      << metrics;
  EXPECT_NE(metrics.find("nccompd_bus_events_total{bus=\"modbus\",event=\"verify_mismatches\"} "
                         "1\n"),
            std::string::npos)
      << metrics;
  EXPECT_EQ(daemon.terminate(), 0) << daemon.log();
  nc.stop();
}

// GIVEN nccompd with its loop at SCHED_FIFO 30 and [modbus] io_sched_fifo_priority = 20,
// io_cpu_affinity = [0], WHEN it runs, THEN its log says what the I/O thread got, the status shows
// io_sched_fifo_priority 20 (JSON and text), and the kernel confirms SCHED_FIFO 20 on the thread.
TEST(ModbusNccompdCounters, IoThreadPolicyIsLoggedAndInTheStatus) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.update([](Tables& t) { set_i32(t.input, 0, 123456); });
  nc.start();
  std::ofstream(d.path / "nccompd.toml")
      << config_text(nc.port(), "[daemon.realtime]\nsched_fifo_priority = 30\n",
                     "io_sched_fifo_priority = 20\nio_cpu_affinity = [0]\n");
  Daemon daemon(d.path);
  daemon.start();
  ASSERT_TRUE(wait_until([&] { return holding_i32(nc, 200) == 123; }, 15000ms)) << daemon.log();
  const std::string log = daemon.log();
  if (log.find("bus modbus: I/O thread: SCHED_FIFO priority 20 refused") != std::string::npos) {
    (void)daemon.terminate();
    GTEST_SKIP() << "SCHED_FIFO refused here; the refusal is tested by "
                    "RefusedIoThreadPriorityIsAWarningAndTheDaemonRuns\n"
                 << log;
  }
  EXPECT_NE(log.find("bus modbus: I/O thread: SCHED_FIFO priority 20\n"), std::string::npos) << log;
  EXPECT_NE(log.find("bus modbus: I/O thread: pinned to CPU(s) 0\n"), std::string::npos) << log;
  EXPECT_NE(log.find("loop thread: SCHED_FIFO priority 30\n"), std::string::npos) << log;
  const std::string c = bus_counters(daemon.status("json"), "modbus");
  EXPECT_EQ(counter(c, "io_sched_fifo_priority"), 20U) << c;
  EXPECT_EQ(counter(c, "io_sched_errno"), 0U) << c;
  EXPECT_EQ(counter(c, "io_affinity_errno"), 0U) << c;
  const std::string text = daemon.status("text");
  EXPECT_NE(text.find("io_sched_fifo_priority 20"), std::string::npos) << text;
  // The kernel's view: exactly one thread of the daemon at SCHED_FIFO 20, the I/O thread.
  int at_20 = 0;
  for (const auto& task :
       fs::directory_iterator("/proc/" + std::to_string(daemon.pid()) + "/task")) {
    const pid_t tid = static_cast<pid_t>(std::stol(task.path().filename().string()));
    sched_param sp{};
    if (sched_getscheduler(tid) == SCHED_FIFO && sched_getparam(tid, &sp) == 0 &&
        sp.sched_priority == 20) {
      ++at_20;
    }
  }
  EXPECT_EQ(at_20, 1);
  EXPECT_EQ(daemon.terminate(), 0) << daemon.log();
  nc.stop();
}

// GIVEN the same config, WHEN nccompd runs without CAP_SYS_NICE and with RLIMIT_RTPRIO 0, THEN
// the loop's and the I/O thread's SCHED_FIFO are refused with warnings naming the reason, the
// status shows io_sched_errno 1 (EPERM) and io_sched_fifo_priority 0, and offsets still arrive.
TEST(ModbusNccompdCounters, RefusedIoThreadPriorityIsAWarningAndTheDaemonRuns) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.update([](Tables& t) { set_i32(t.input, 0, 123456); });
  nc.start();
  std::ofstream(d.path / "nccompd.toml") << config_text(
      nc.port(), "[daemon.realtime]\nsched_fifo_priority = 30\n", "io_sched_fifo_priority = 20\n");
  Daemon daemon(d.path);
  daemon.start(/*without_realtime=*/true);
  ASSERT_TRUE(wait_until([&] { return holding_i32(nc, 200) == 123; }, 15000ms)) << daemon.log();
  const std::string log = daemon.log();
  EXPECT_NE(log.find("bus modbus: I/O thread: SCHED_FIFO priority 20 refused: Operation not "
                     "permitted (running SCHED_OTHER; SCHED_FIFO needs CAP_SYS_NICE or an "
                     "RLIMIT_RTPRIO of at least 20)"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find(" warning bus modbus: I/O thread: SCHED_FIFO priority 20 refused"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("loop thread: SCHED_FIFO priority 30 refused"), std::string::npos) << log;
  std::string c;
  ASSERT_TRUE(wait_until(
      [&] {
        c = bus_counters(daemon.status("json"), "modbus");
        return !c.empty();
      },
      5000ms))
      << daemon.log();
  EXPECT_EQ(counter(c, "io_sched_errno"), static_cast<std::uint64_t>(EPERM)) << c;
  EXPECT_EQ(counter(c, "io_sched_fifo_priority"), 0U) << c;
  const std::string text = daemon.status("text");
  EXPECT_NE(text.find("io_sched_errno 1"), std::string::npos) << text;
  EXPECT_EQ(daemon.terminate(), 0) << daemon.log();
  nc.stop();
}

}  // namespace
