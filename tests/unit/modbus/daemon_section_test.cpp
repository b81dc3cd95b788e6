// GIVEN nccompd configs with a [modbus] section and a [daemon] loop rate, WHEN the daemon's loader
// reads them, THEN poll_rate_hz defaults to the loop rate, a poll faster than the loop is refused
// at its key (file:line:column), an RTU bus that cannot carry the loop rate is refused saying so,
// and the built bus runs at the resolved rate. The I/O thread's SCHED_FIFO priority is checked
// against [daemon.realtime] sched_fifo_priority: not below it is refused at its key.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "daemon/config/config.hpp"
#include "drivers/modbus/modbus_bus.hpp"

namespace nccomp::daemon::config {

using formats::Diagnostic;
namespace {

namespace fs = std::filesystem;

class TempDir {
 public:
  TempDir() {
    path_ = fs::temp_directory_path() /
            ("nccomp_mb_section_" + std::to_string(::getpid()) + "_" + std::to_string(counter_++));
    fs::create_directories(path_);
  }
  ~TempDir() { fs::remove_all(path_); }
  [[nodiscard]] std::string write(const std::string& text) const {
    const auto p = path_ / "n.toml";
    std::ofstream(p) << text;
    return p.string();
  }

 private:
  static inline int counter_ = 0;
  fs::path path_;
};

const char* const kRegister = R"(
[[registers]]
name = "T1"
kind = "tool_length_wear"
bus = "modbus"
max_abs_um = 100
max_step_um = 5
max_rate_um_per_s = 50
)";

// [daemon] is lines 1-2, [modbus] starts at line 3; modbus_top from line 5.
std::string config(double loop_hz, const std::string& modbus_top,
                   const std::string& transport = "transport = \"tcp\"\n") {
  return "[daemon]\nrate_hz = " + std::to_string(loop_hz) + "\n[modbus]\n" + transport +
         modbus_top + R"(
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int32", scale = 0.0001 }
[[modbus.offset]]
register_index = 0
address = 200
type = "int32"
)" + kRegister;
}

const drivers::modbus::ModbusConfig* bus_config(const Config& c,
                                                std::unique_ptr<drivers::Bus>& keep) {
  keep = find_section_parser("modbus")->make_bus(c);
  const auto* mb = dynamic_cast<const drivers::modbus::ModbusBus*>(keep.get());
  return mb == nullptr ? nullptr : &mb->config();
}

TEST(ModbusDaemonSection, PollRateDefaultsToTheLoopRate) {
  TempDir d;
  auto r = load_file(d.write(config(500.0, "")));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  std::unique_ptr<drivers::Bus> bus;
  const auto* c = bus_config(*r.config, bus);
  ASSERT_NE(c, nullptr);
  EXPECT_DOUBLE_EQ(c->poll_rate_hz, 500.0);
  EXPECT_TRUE(c->poll_rate_defaulted);
  EXPECT_DOUBLE_EQ(c->offset_write_rate_hz, 500.0);  // derived from the poll rate on TCP
  // An explicit slower rate stays.
  r = load_file(d.write(config(500.0, "poll_rate_hz = 125\n")));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  c = bus_config(*r.config, bus);
  ASSERT_NE(c, nullptr);
  EXPECT_DOUBLE_EQ(c->poll_rate_hz, 125.0);
  EXPECT_DOUBLE_EQ(c->offset_write_rate_hz, 125.0);
}

TEST(ModbusDaemonSection, PollFasterThanTheLoopIsRefusedAtItsKey) {
  TempDir d;
  const std::string f = d.write(config(1000.0, "poll_rate_hz = 2000\n"));
  auto r = load_file(f);
  ASSERT_FALSE(r.config);
  ASSERT_EQ(r.diagnostics.items().size(), 1U) << r.diagnostics.to_string();
  const Diagnostic& e = r.diagnostics.items()[0];
  EXPECT_EQ(e.where.file, f);
  EXPECT_EQ(e.where.line, 5);
  EXPECT_GT(e.where.column, 0);
  EXPECT_EQ(e.where.key_path, "modbus.poll_rate_hz");
  EXPECT_EQ(e.message,
            "2000 Hz is faster than the loop (daemon.rate_hz = 1000 Hz), which takes at most one "
            "sample per cycle: the extra polls only load the NC and the bus; at most 1000 Hz "
            "(leave poll_rate_hz out to poll at the loop rate)");
}

TEST(ModbusDaemonSection, RtuBusThatCannotCarryTheLoopRateIsRefusedWithTheRateThatFits) {
  TempDir d;
  const std::string rtu = "transport = \"rtu\"\ndevice = \"/dev/null\"\nbaud = 115200\n";
  // One read of 2 registers + the 1.75 ms gaps: about 5 ms per poll at 115200 baud.
  auto r = load_file(d.write(config(1000.0, "", rtu)));
  ASSERT_FALSE(r.config);
  ASSERT_EQ(r.diagnostics.items().size(), 1U) << r.diagnostics.to_string();
  const Diagnostic& e = r.diagnostics.items()[0];
  EXPECT_EQ(e.where.key_path, "modbus.poll_rate_hz");
  EXPECT_EQ(e.where.line, 3);  // the [modbus] table: the key is absent
  EXPECT_EQ(e.message.rfind("1000 Hz (poll_rate_hz is not set: the loop rate daemon.rate_hz) "
                            "needs ",
                            0),
            0U)
      << e.message;
  EXPECT_NE(e.message.find("; at most "), std::string::npos) << e.message;
  // At a 100 Hz loop the same bus polls at the loop rate: nothing refused, although
  // parse() saw no poll rate (the bus budget is judged on the loop's rate, not on a default).
  r = load_file(d.write(config(100.0, "", rtu)));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  std::unique_ptr<drivers::Bus> bus;
  const auto* c = bus_config(*r.config, bus);
  ASSERT_NE(c, nullptr);
  EXPECT_DOUBLE_EQ(c->poll_rate_hz, 100.0);
  EXPECT_GT(c->offset_write_rate_hz, 0.0);
  EXPECT_LE(c->offset_write_rate_hz, 100.0);
}

TEST(ModbusDaemonSection, MinMaxErrorsCarryFileLineColumnAndKeyPath) {
  TempDir d;
  std::string text = config(1000.0, "");
  text.replace(text.find("scale = 0.0001 }"), 16, "scale = 0.0001, min = 10, max = -10 }");
  const std::string f = d.write(text);
  auto r = load_file(f);
  ASSERT_FALSE(r.config);
  ASSERT_EQ(r.diagnostics.items().size(), 1U) << r.diagnostics.to_string();
  const Diagnostic& e = r.diagnostics.items()[0];
  EXPECT_EQ(e.where.file, f);
  EXPECT_EQ(e.where.line, 7);     // x_mm's line (a blank line precedes [modbus.axis])
  EXPECT_GT(e.where.column, 60);  // at the max value inside the inline table
  EXPECT_EQ(e.where.key_path, "modbus.axis.x_mm.max");
  EXPECT_EQ(e.message, "max -10 is below min 10");
}

// GIVEN [daemon.realtime] sched_fifo_priority = 50, WHEN [modbus] io_sched_fifo_priority is 50
// (equal) or set while the loop runs at normal scheduling, THEN the loader refuses it at its
// file:line:column and key path; 49 is accepted and reaches the built bus.
TEST(ModbusDaemonSection, IoThreadPriorityMustBeBelowTheLoopsPriority) {
  TempDir d;
  const auto with_loop = [](int loop_prio, const std::string& modbus_top) {
    std::string text = config(1000.0, modbus_top);
    return text + "[daemon.realtime]\nsched_fifo_priority = " + std::to_string(loop_prio) + "\n";
  };
  std::string f = d.write(with_loop(50, "io_sched_fifo_priority = 50\n"));
  auto r = load_file(f);
  ASSERT_FALSE(r.config);
  ASSERT_EQ(r.diagnostics.items().size(), 1U) << r.diagnostics.to_string();
  const Diagnostic& e = r.diagnostics.items()[0];
  EXPECT_EQ(e.where.file, f);
  EXPECT_EQ(e.where.line, 5);
  EXPECT_EQ(e.where.column, 26);  // the value
  EXPECT_EQ(e.where.key_path, "modbus.io_sched_fifo_priority");
  EXPECT_EQ(e.message,
            "50 is not below the loop thread's SCHED_FIFO priority "
            "(daemon.realtime.sched_fifo_priority = 50): the loop must always preempt the "
            "driver's I/O thread; at most 49 (0 = off)");
  // The loop without [daemon.realtime] runs at normal scheduling: any SCHED_FIFO I/O thread is
  // refused.
  r = load_file(d.write(config(1000.0, "io_sched_fifo_priority = 10\n")));
  ASSERT_FALSE(r.config);
  ASSERT_EQ(r.diagnostics.items().size(), 1U) << r.diagnostics.to_string();
  EXPECT_EQ(r.diagnostics.items()[0].where.key_path, "modbus.io_sched_fifo_priority");
  EXPECT_NE(r.diagnostics.items()[0].message.find("sched_fifo_priority = 0: the loop runs at "
                                                  "normal scheduling"),
            std::string::npos)
      << r.diagnostics.to_string();
  // Below the loop: accepted, and the bus gets it with the affinity.
  r = load_file(d.write(with_loop(50, "io_sched_fifo_priority = 49\nio_cpu_affinity = [0]\n")));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  std::unique_ptr<drivers::Bus> bus;
  const auto* c = bus_config(*r.config, bus);
  ASSERT_NE(c, nullptr);
  EXPECT_EQ(c->io_sched_fifo_priority, 49);
  EXPECT_EQ(c->io_cpu_affinity, (std::vector<int>{0}));
}

}  // namespace
}  // namespace nccomp::daemon::config
