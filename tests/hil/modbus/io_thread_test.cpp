// The I/O thread's opt-in real-time policy (io_sched_fifo_priority, io_cpu_affinity) against
// the project's NC server on loopback TCP: the thread applies it to itself before its first
// request and the kernel confirms it (sched_getscheduler / pthread_getschedparam /
// sched_getaffinity on the driver's thread); what it got is in io_thread_setup(), the status
// counters and the log lines; a refusal is a warning and the driver runs on at normal priority.
#include <gtest/gtest.h>
#include <linux/capability.h>
#include <pthread.h>
#include <sched.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstdint>
#include <cstring>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "sim/modbus_nc/nc_server.hpp"
#include "tests/hil/modbus/hil_common.hpp"

namespace nccomp::test::modbus {
namespace {

using sim::modbus_nc::NcServer;
using sim::modbus_nc::ServerConfig;
using sim::modbus_nc::Tables;

const char* const kMap = R"(
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int32", scale = 0.0001 }
[[modbus.offset]]
register_index = 0
address = 200
type = "int32"
scale = 0.1
)";

void publish_x(NcServer& nc) {
  nc.update([](Tables& t) {
    t.input[0] = 0x0001;  // 0x0001E240 = 123456 counts = 12.3456 mm
    t.input[1] = 0xE240;
  });
}

std::int32_t holding_i32(NcServer& nc, std::uint16_t address) {
  const auto r = nc.holding(address, 2);
  return static_cast<std::int32_t>((std::uint32_t{r[0]} << 16) | r[1]);
}

std::optional<std::uint64_t> extra(const mb::ModbusBus& bus, std::string_view name) {
  std::array<drivers::BusCounterValue, drivers::kMaxBusExtraCounters> out{};
  const std::size_t n = bus.extra_counters(out);
  for (std::size_t i = 0; i < n; ++i) {
    if (name == out[i].name) {
      return out[i].value;
    }
  }
  return std::nullopt;
}

/// The driver works: a sample with the NC's X arrives and a queued offset reaches the NC.
void expect_it_polls_and_writes(mb::ModbusBus& bus, NcServer& nc) {
  Collected got;
  ASSERT_TRUE(wait_until([&] {
    got.drain(bus);
    return !got.axis.empty();
  }));
  EXPECT_DOUBLE_EQ(got.axis.back().position_mm[0], 12.3456);
  push_offset(bus, 0, 4.5);
  EXPECT_TRUE(wait_until([&] { return holding_i32(nc, 200) == 45; }));
}

/// Records the lines start() hands to the callback (what nccompd logs).
struct SetupLog {
  int calls{0};
  std::vector<mb::IoSetupLine> lines;
  void attach(mb::ModbusBus& bus) {
    bus.on_io_thread_setup([this, &bus](const mb::IoThreadSetup& s) {
      ++calls;
      lines = mb::describe_io_setup(s, bus.config());
    });
  }
};

TEST(ModbusHilIoThread, WithoutTheKeysTheThreadStaysAtNormalSchedulingAndSaysSo) {
  NcServer nc(ServerConfig{});
  publish_x(nc);
  nc.start();
  auto bus = make_bus(tcp_header(nc.port()) + kMap);
  SetupLog log;
  log.attach(*bus);
  bus->start();
  const mb::IoThreadSetup& s = bus->io_thread_setup();
  EXPECT_EQ(log.calls, 1);
  EXPECT_EQ(s.requested_fifo_priority, 0);
  EXPECT_FALSE(s.affinity_requested);
  EXPECT_EQ(s.policy, SCHED_OTHER);
  ASSERT_GT(s.tid, 0);
  EXPECT_EQ(sched_getscheduler(s.tid), SCHED_OTHER);
  ASSERT_EQ(log.lines.size(), 1U);
  EXPECT_FALSE(log.lines[0].warning);
  EXPECT_EQ(log.lines[0].text,
            "I/O thread: SCHED_OTHER (io_sched_fifo_priority not set; under load its polls may "
            "overrun, see poll_overruns)");
  expect_it_polls_and_writes(*bus, nc);
  EXPECT_EQ(extra(*bus, "io_sched_fifo_priority"), 0U);
  EXPECT_EQ(extra(*bus, "io_sched_errno"), 0U);
  EXPECT_EQ(extra(*bus, "io_affinity_errno"), 0U);
  bus->stop();
}

TEST(ModbusHilIoThread, FifoPriorityAndAffinityAreAppliedByTheThreadItself) {
  NcServer nc(ServerConfig{});
  publish_x(nc);
  nc.start();
  auto bus =
      make_bus(tcp_header(nc.port(), "io_sched_fifo_priority = 20\nio_cpu_affinity = [0]") + kMap);
  SetupLog log;
  log.attach(*bus);
  bus->start();
  const mb::IoThreadSetup& s = bus->io_thread_setup();
  if (s.sched_errno == EPERM) {
    bus->stop();
    GTEST_SKIP() << "SCHED_FIFO refused here (EPERM: no CAP_SYS_NICE and RLIMIT_RTPRIO below 20); "
                    "the refusal itself is tested by "
                    "RefusedPriorityAndAffinityAreWarningsAndTheDriverRunsOn";
  }
  EXPECT_EQ(s.sched_errno, 0) << std::strerror(s.sched_errno);
  EXPECT_EQ(s.requested_fifo_priority, 20);
  EXPECT_EQ(s.policy, SCHED_FIFO);
  EXPECT_EQ(s.priority, 20);
  // The kernel's view of the driver's thread, asked from here, not from the thread.
  int policy = -1;
  sched_param sp{};
  ASSERT_EQ(pthread_getschedparam(bus->io_native_handle(), &policy, &sp), 0);
  EXPECT_EQ(policy, SCHED_FIFO);
  EXPECT_EQ(sp.sched_priority, 20);
  ASSERT_GT(s.tid, 0);
  EXPECT_EQ(sched_getscheduler(s.tid), SCHED_FIFO);
  sched_param by_tid{};
  ASSERT_EQ(sched_getparam(s.tid, &by_tid), 0);
  EXPECT_EQ(by_tid.sched_priority, 20);
  EXPECT_TRUE(s.affinity_requested);
  EXPECT_EQ(s.affinity_errno, 0) << std::strerror(s.affinity_errno);
  cpu_set_t set;
  CPU_ZERO(&set);
  ASSERT_EQ(sched_getaffinity(s.tid, sizeof(set), &set), 0);
  EXPECT_EQ(CPU_COUNT(&set), 1);
  EXPECT_TRUE(CPU_ISSET(0, &set));
  // The thread that started it is untouched.
  EXPECT_EQ(sched_getscheduler(0), SCHED_OTHER);
  // The log lines and the status counters say the same.
  EXPECT_EQ(log.calls, 1);
  ASSERT_EQ(log.lines.size(), 2U);
  EXPECT_FALSE(log.lines[0].warning);
  EXPECT_EQ(log.lines[0].text, "I/O thread: SCHED_FIFO priority 20");
  EXPECT_FALSE(log.lines[1].warning);
  EXPECT_EQ(log.lines[1].text, "I/O thread: pinned to CPU(s) 0");
  expect_it_polls_and_writes(*bus, nc);
  const mb::ModbusStatus st = bus->modbus_status();
  EXPECT_EQ(st.io_sched_fifo_priority, 20U);
  EXPECT_EQ(st.io_sched_errno, 0U);
  EXPECT_EQ(extra(*bus, "io_sched_fifo_priority"), 20U);
  EXPECT_EQ(extra(*bus, "io_sched_errno"), 0U);
  EXPECT_EQ(extra(*bus, "io_affinity_errno"), 0U);
  bus->stop();
}

/// Drops CAP_SYS_NICE from the calling thread's effective set (capabilities are per thread, and
/// a thread it creates inherits them). Returns errno of capget / capset, 0 on success.
int drop_sys_nice_in_this_thread() {
  __user_cap_header_struct hdr{};
  hdr.version = _LINUX_CAPABILITY_VERSION_3;
  hdr.pid = 0;
  __user_cap_data_struct data[2]{};
  if (syscall(SYS_capget, &hdr, data) != 0) {
    return errno;
  }
  data[CAP_TO_INDEX(CAP_SYS_NICE)].effective &= ~CAP_TO_MASK(CAP_SYS_NICE);
  if (syscall(SYS_capset, &hdr, data) != 0) {
    return errno;
  }
  return 0;
}

// GIVEN a process whose RLIMIT_RTPRIO is 0 and a starting thread without CAP_SYS_NICE (so the
// I/O thread inherits neither), and a CPU set naming only CPU 1023 (no such CPU here), WHEN the
// driver starts with io_sched_fifo_priority = 20 and io_cpu_affinity = [1023], THEN both are
// refused, reported as warnings with the reason, counted in the status (io_sched_errno = EPERM,
// io_affinity_errno = EINVAL), and the driver polls and writes at normal priority.
TEST(ModbusHilIoThread, RefusedPriorityAndAffinityAreWarningsAndTheDriverRunsOn) {
  NcServer nc(ServerConfig{});
  publish_x(nc);
  nc.start();
  rlimit saved{};
  ASSERT_EQ(getrlimit(RLIMIT_RTPRIO, &saved), 0);
  rlimit none = saved;
  none.rlim_cur = 0;
  ASSERT_EQ(setrlimit(RLIMIT_RTPRIO, &none), 0);
  auto bus = make_bus(
      tcp_header(nc.port(), "io_sched_fifo_priority = 20\nio_cpu_affinity = [1023]") + kMap);
  SetupLog log;
  log.attach(*bus);
  int drop_errno = -1;
  // The driver is started from a thread without CAP_SYS_NICE; the test's thread keeps it.
  std::thread starter([&] {
    drop_errno = drop_sys_nice_in_this_thread();
    if (drop_errno == 0) {
      bus->start();
    }
  });
  starter.join();
  ASSERT_EQ(setrlimit(RLIMIT_RTPRIO, &saved), 0);
  ASSERT_EQ(drop_errno, 0) << "capset: " << std::strerror(drop_errno);
  const mb::IoThreadSetup& s = bus->io_thread_setup();
  EXPECT_EQ(s.requested_fifo_priority, 20);
  EXPECT_EQ(s.sched_errno, EPERM) << std::strerror(s.sched_errno);
  EXPECT_EQ(s.policy, SCHED_OTHER);
  EXPECT_EQ(sched_getscheduler(s.tid), SCHED_OTHER);
  EXPECT_EQ(s.affinity_errno, EINVAL) << std::strerror(s.affinity_errno);
  EXPECT_EQ(log.calls, 1);
  ASSERT_EQ(log.lines.size(), 2U);
  EXPECT_TRUE(log.lines[0].warning);
  EXPECT_EQ(log.lines[0].text,
            "I/O thread: SCHED_FIFO priority 20 refused: Operation not permitted (running "
            "SCHED_OTHER; SCHED_FIFO needs CAP_SYS_NICE or an RLIMIT_RTPRIO of at least 20)");
  EXPECT_TRUE(log.lines[1].warning);
  EXPECT_EQ(log.lines[1].text,
            "I/O thread: CPU affinity 1023 refused: Invalid argument (running on any CPU)");
  expect_it_polls_and_writes(*bus, nc);
  const mb::ModbusStatus st = bus->modbus_status();
  EXPECT_EQ(st.bus.state, drivers::LinkState::kUp);
  EXPECT_EQ(extra(*bus, "io_sched_fifo_priority"), 0U);
  EXPECT_EQ(extra(*bus, "io_sched_errno"), static_cast<std::uint64_t>(EPERM));
  EXPECT_EQ(extra(*bus, "io_affinity_errno"), static_cast<std::uint64_t>(EINVAL));
  bus->stop();
}

// GIVEN a driver started by a SCHED_FIFO thread without io_sched_fifo_priority, THEN it reports
// the policy it inherited (what it runs at), not "normal scheduling".
TEST(ModbusHilIoThread, AnInheritedFifoPolicyIsReportedAsIs) {
  NcServer nc(ServerConfig{});
  publish_x(nc);
  nc.start();
  auto bus = make_bus(tcp_header(nc.port()) + kMap);
  SetupLog log;
  log.attach(*bus);
  int rc = -1;
  std::thread starter([&] {
    sched_param sp{};
    sp.sched_priority = 5;
    rc = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp);
    if (rc == 0) {
      bus->start();
    }
  });
  starter.join();
  if (rc == EPERM) {
    GTEST_SKIP() << "SCHED_FIFO refused here (EPERM): cannot start the driver from a FIFO thread";
  }
  ASSERT_EQ(rc, 0) << std::strerror(rc);
  const mb::IoThreadSetup& s = bus->io_thread_setup();
  EXPECT_EQ(s.requested_fifo_priority, 0);
  EXPECT_EQ(s.policy, SCHED_FIFO);
  EXPECT_EQ(s.priority, 5);
  ASSERT_EQ(log.lines.size(), 1U);
  EXPECT_FALSE(log.lines[0].warning);
  EXPECT_EQ(log.lines[0].text,
            "I/O thread: SCHED_FIFO priority 5, inherited from the thread that started it "
            "(io_sched_fifo_priority not set)");
  expect_it_polls_and_writes(*bus, nc);
  EXPECT_EQ(extra(*bus, "io_sched_fifo_priority"), 5U);
  bus->stop();
}

}  // namespace
}  // namespace nccomp::test::modbus
