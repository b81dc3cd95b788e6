#include "drivers/modbus/config.hpp"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "formats/toml/diagnostics.hpp"

namespace nccomp::drivers::modbus {
namespace {

using ::testing::HasSubstr;

std::string error_of(const std::string& text) {
  try {
    (void)parse_modbus_config(text, "t.toml");
  } catch (const formats::DiagnosticsError& e) {
    return e.what();
  }
  return "(accepted)";
}

const char* const kMinimal = R"(
[modbus]
transport = "tcp"
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int32", scale = 0.001 }
)";

TEST(ModbusConfig, ReferenceProfileParsesIntoOneRequestPerGroup) {
  const ModbusConfig c = load_modbus_config(NCCOMP_SOURCE_DIR "/config/reference-nc-modbus.toml");
  EXPECT_EQ(c.transport, Transport::kTcp);
  EXPECT_EQ(c.port, 1502);
  EXPECT_TRUE(c.verify_writes);
  // discrete input 0; input 0..11 (axis); the five event groups and the temperatures at input
  // 100..161 merged (merge_gap_registers = 16) into one 62-register request.
  ASSERT_EQ(c.blocks.size(), 3U);
  EXPECT_EQ(c.blocks[0].table, Table::kDiscreteInput);
  EXPECT_EQ(c.blocks[1].table, Table::kInput);
  EXPECT_EQ(c.blocks[1].start, 0);
  EXPECT_EQ(c.blocks[1].count, 12);
  EXPECT_EQ(c.blocks[2].start, 100);
  EXPECT_EQ(c.blocks[2].count, 62);
  ASSERT_EQ(c.offsets.size(), 9U);
  EXPECT_EQ(c.offsets[8].register_index, 8);  // contiguous: the [[registers]] positions
  EXPECT_EQ(c.offsets[8].encoding.word_order, WordOrder::kLowFirst);
  EXPECT_DOUBLE_EQ(c.offset_write_rate_hz, c.poll_rate_hz);  // TCP: derived = poll rate
  const SignalMap& wear =
      c.groups[static_cast<std::size_t>(Group::kToolMeasurement)].fields[tool_meas_field::kWear];
  EXPECT_EQ(wear.block, 2U);
  EXPECT_EQ(wear.block_offset, 2);
  const SignalMap& kind =
      c.groups[static_cast<std::size_t>(Group::kProgramEvent)].fields[program_field::kKind];
  EXPECT_EQ(kind.block, 2U);
  EXPECT_EQ(kind.block_offset, 51);
  EXPECT_EQ(c.temperatures[1].value.block, 2U);
  EXPECT_EQ(c.temperatures[1].value.block_offset, 61);
}

TEST(ModbusConfig, AdjacentBlocksMergeGapsOnlyWhenAllowed) {
  const std::string groups = R"(
[modbus.tool_change]
sequence = { address = 10, type = "uint16" }
tool = { address = 11 }
[modbus.program_event]
sequence = { address = 12, type = "uint16" }
kind = { address = 13 }
[modbus.tool_measurement]
sequence = { address = 20, type = "uint16" }
tool = { address = 21 }
wear_um = { address = 22, type = "float32" }
)";
  // Default: 10..11 and 12..13 are adjacent -> one request; 20..23 after a gap of 6 -> its own.
  ModbusConfig c = parse_modbus_config("[modbus]\ntransport = \"tcp\"\n" + groups, "t.toml");
  ASSERT_EQ(c.blocks.size(), 2U);
  EXPECT_EQ(c.blocks[0].start, 10);
  EXPECT_EQ(c.blocks[0].count, 4);
  const auto& kind =
      c.groups[static_cast<std::size_t>(Group::kProgramEvent)].fields[program_field::kKind];
  EXPECT_EQ(kind.block, 0U);
  EXPECT_EQ(kind.block_offset, 3);
  // With a gap allowance of 6 everything is one request.
  c = parse_modbus_config("[modbus]\ntransport = \"tcp\"\nmerge_gap_registers = 6\n" + groups,
                          "t.toml");
  ASSERT_EQ(c.blocks.size(), 1U);
  EXPECT_EQ(c.blocks[0].count, 14);
  const auto& wear =
      c.groups[static_cast<std::size_t>(Group::kToolMeasurement)].fields[tool_meas_field::kWear];
  EXPECT_EQ(wear.block, 0U);
  EXPECT_EQ(wear.block_offset, 12);
}

TEST(ModbusConfig, MinimalDefaults) {
  const ModbusConfig c = parse_modbus_config(kMinimal, "t.toml");
  EXPECT_EQ(c.host, "127.0.0.1");
  EXPECT_EQ(c.port, 502);
  EXPECT_DOUBLE_EQ(c.response_timeout_s, 0.5);
  EXPECT_DOUBLE_EQ(c.byte_timeout_s, 0.5);
  EXPECT_EQ(c.dead_after_failures, 3U);
  ASSERT_EQ(c.blocks.size(), 1U);
  EXPECT_EQ(c.blocks[0].count, 2);
}

// The reconnect back-off: 0.1 s doubling to 5 s, back to 0.1 s after 10 s healthy; the reset
// time is at least the cap (defaulted to it above 10 s, refused below it when given).
TEST(ModbusConfig, ReconnectBackOffKeys) {
  const ModbusConfig d = parse_modbus_config(kMinimal, "t.toml");
  EXPECT_DOUBLE_EQ(d.reconnect_min_s, 0.1);
  EXPECT_DOUBLE_EQ(d.reconnect_max_s, 5.0);
  EXPECT_DOUBLE_EQ(d.reconnect_reset_after_s, 10.0);
  const std::string head = "[modbus]\ntransport = \"tcp\"\n";
  const std::string axis = "[modbus.axis]\nx_mm = { table = \"input\", address = 0 }\n";
  const ModbusConfig c = parse_modbus_config(
      head + "reconnect_min_s = 0.5\nreconnect_max_s = 30\nreconnect_reset_after_s = 60\n" + axis,
      "t.toml");
  EXPECT_DOUBLE_EQ(c.reconnect_reset_after_s, 60.0);
  EXPECT_DOUBLE_EQ(
      parse_modbus_config(head + "reconnect_max_s = 30\n" + axis, "t.toml").reconnect_reset_after_s,
      30.0);
  EXPECT_EQ(error_of(head + "reconnect_max_s = 30\nreconnect_reset_after_s = 20\n" + axis),
            "t.toml:4:27: modbus.reconnect_reset_after_s: smaller than reconnect_max_s");
  EXPECT_EQ(error_of(head + "reconnect_min_s = 2\nreconnect_max_s = 1\n" + axis),
            "t.toml:4:19: modbus.reconnect_max_s: smaller than reconnect_min_s");
}

TEST(ModbusConfig, DegradedAlarmAfterParsedDefaultedAndRangeChecked) {
  EXPECT_DOUBLE_EQ(parse_modbus_config(kMinimal, "t.toml").degraded_alarm_after_s, 5.0);
  const std::string head = "[modbus]\ntransport = \"tcp\"\n";
  const std::string axis = "[modbus.axis]\nx_mm = { table = \"input\", address = 0 }\n";
  EXPECT_DOUBLE_EQ(parse_modbus_config(head + "degraded_alarm_after_s = 0.5\n" + axis, "t.toml")
                       .degraded_alarm_after_s,
                   0.5);
  EXPECT_THAT(
      error_of(head + "degraded_alarm_after_s = 0\n" + axis),
      HasSubstr(
          "t.toml:3:26: modbus.degraded_alarm_after_s: must be a number in [0.01, 3600], got 0"));
}

TEST(ModbusConfig, UnknownKeyNamesFileLineAndPath) {
  EXPECT_EQ(error_of(std::string(kMinimal) + "pol_rate_hz = 5\n"),
            "t.toml:6:15: modbus.axis.pol_rate_hz: unknown signal");
  EXPECT_EQ(error_of("[modbus]\ntransport = \"tcp\"\npol_rate_hz = 5\n"),
            "t.toml:3:15: modbus.pol_rate_hz: unknown key");
  EXPECT_THAT(error_of(R"([modbus]
transport = "tcp"
[modbus.axis]
x_mm = { table = "input", address = 0, typ = "int32" }
)"),
              "t.toml:4:46: modbus.axis.x_mm.typ: unknown key");
}

TEST(ModbusConfig, RefusesOverlapsWithBothKeyPaths) {
  EXPECT_EQ(error_of(R"([modbus]
transport = "tcp"
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int32" }
y_mm = { table = "input", address = 1, type = "int16" }
)"),
            "t.toml:5: modbus.axis.y_mm: input address 1 overlaps modbus.axis.x_mm (line 4)");
  // An offset register on top of a holding signal.
  EXPECT_THAT(error_of(R"([modbus]
transport = "tcp"
[modbus.axis]
x_mm = { address = 200, type = "int32" }
[[modbus.offset]]
register_index = 0
address = 201
)"),
              HasSubstr("modbus.offset[0]: holding address 201 overlaps modbus.axis.x_mm"));
  // Same address in different tables is fine.
  EXPECT_EQ(error_of(R"([modbus]
transport = "tcp"
[modbus.axis]
x_mm = { table = "input", address = 0 }
cutting = { table = "coil", address = 0 }
)"),
            "(accepted)");
}

TEST(ModbusConfig, RefusesOutOfRangeAddressesAndBadTypes) {
  EXPECT_EQ(error_of(R"([modbus]
transport = "tcp"
[modbus.axis]
x_mm = { address = 65535, type = "int32" }
)"),
            "t.toml:4:20: modbus.axis.x_mm.address: does not fit below address 65535");
  EXPECT_EQ(error_of(R"([modbus]
transport = "tcp"
[modbus.axis]
x_mm = { address = 70000 }
)"),
            "t.toml:4:20: modbus.axis.x_mm.address: must be an integer in [0, 65535], got 70000");
  EXPECT_THAT(error_of(R"([modbus]
transport = "tcp"
[modbus.axis]
x_mm = { address = 0, type = "int8" }
)"),
              HasSubstr("modbus.axis.x_mm.type: must be one of \"bool\", \"int16\""));
  EXPECT_THAT(error_of(R"([modbus]
transport = "tcp"
[modbus.axis]
x_mm = { address = 0 }
cutting = { table = "coil", address = 0, type = "int16" }
)"),
              HasSubstr("modbus.axis.cutting.type: a coil is one bit: type must be bool"));
  EXPECT_THAT(error_of(R"([modbus]
transport = "tcp"
[modbus.axis]
x_mm = { address = 0, scale = 0 }
)"),
              HasSubstr("modbus.axis.x_mm.scale: must not be 0"));
}

TEST(ModbusConfig, EventGroupMustBeOneRequest) {
  EXPECT_THAT(error_of(R"([modbus]
transport = "tcp"
[modbus.tool_change]
sequence = { table = "input", address = 10, type = "uint16" }
tool = { table = "holding", address = 11 }
)"),
              HasSubstr("modbus.tool_change.tool: must be in the same table as sequence (input)"));
  EXPECT_THAT(error_of(R"([modbus]
transport = "tcp"
[modbus.tool_change]
sequence = { address = 10, type = "uint16" }
tool = { address = 200 }
)"),
              HasSubstr("modbus.tool_change: its holding signals span 191 addresses"));
  EXPECT_THAT(
      error_of(R"([modbus]
transport = "tcp"
[modbus.tool_change]
sequence = { address = 10, type = "int16" }
tool = { address = 11 }
)"),
      HasSubstr("modbus.tool_change.sequence: a sequence counter must be uint16 or uint32"));
  EXPECT_THAT(error_of(R"([modbus]
transport = "tcp"
[modbus.tool_change]
sequence = { address = 10, type = "uint16" }
)"),
              HasSubstr("modbus.tool_change.tool: missing required key (this group needs it)"));
}

TEST(ModbusConfig, AxesInOrderAndNormalsTogether) {
  EXPECT_THAT(error_of(R"([modbus]
transport = "tcp"
[modbus.axis]
x_mm = { address = 0 }
z_mm = { address = 2 }
)"),
              HasSubstr("modbus.axis.z_mm: axes must be mapped in order"));
  EXPECT_THAT(error_of(R"([modbus]
transport = "tcp"
[modbus.axis]
x_mm = { address = 0 }
normal_x = { address = 2 }
)"),
              HasSubstr("normal_x, normal_y and normal_z go together"));
}

TEST(ModbusConfig, MissingOrDuplicateItems) {
  EXPECT_THAT(error_of("[modbus]\n[modbus.axis]\nx_mm = { address = 0 }\n"),
              HasSubstr("modbus.transport: missing"));
  EXPECT_THAT(error_of("[other]\n"), HasSubstr("modbus: missing [modbus] table"));
  EXPECT_THAT(error_of("[modbus]\ntransport = \"tcp\"\n"), HasSubstr("no signal mapped"));
  EXPECT_THAT(
      error_of(std::string(kMinimal) + R"(
[[modbus.offset]]
register_index = 3
address = 10
[[modbus.offset]]
register_index = 3
address = 20
)"),
      HasSubstr("t.toml:11:18: modbus.offset[1].register_index: register_index mapped twice"));
  EXPECT_THAT(error_of("[modbus]\ntransport = \"rtu\"\n[modbus.axis]\nx_mm = { address = 0 }\n"),
              HasSubstr("modbus.device: missing required key: RTU needs a serial device path"));
  EXPECT_THAT(error_of("[modbus]\ntransport = \"tcp\"\nrx_capacity = 1000\n"),
              HasSubstr("modbus.rx_capacity: must be a power of two"));
  EXPECT_THAT(error_of("[modbus]\ntransport = [\n"), HasSubstr("t.toml:"));
}

TEST(ModbusConfig, MinMaxPerSignalAreValidatedWithTheirKeyPath) {
  // GIVEN plausibility ranges on an axis, a wear profile and a temperature
  const ModbusConfig c = parse_modbus_config(R"([modbus]
transport = "tcp"
[modbus.axis]
x_mm = { table = "input", address = 0, type = "float32", min = -1200, max = 1200.5 }
y_mm = { table = "input", address = 2, type = "float32", max = 800 }
[modbus.tool_measurement]
sequence = { address = 10, type = "uint16" }
tool = { address = 11 }
wear_um = { address = 12, type = "int16", scale = 0.1, count = 2, min = -50, max = 500 }
[[modbus.temperature]]
sensor = 0
table = "input"
address = 40
scale = 0.01
min = -20
max = 80
)",
                                             "t.toml");
  const auto& axis = c.groups[static_cast<std::size_t>(Group::kAxis)];
  EXPECT_DOUBLE_EQ(axis.fields[axis_field::kX].min, -1200.0);
  EXPECT_DOUBLE_EQ(axis.fields[axis_field::kX].max, 1200.5);
  EXPECT_TRUE(std::isinf(axis.fields[axis_field::kY].min));  // only max given
  EXPECT_LT(axis.fields[axis_field::kY].min, 0.0);
  EXPECT_DOUBLE_EQ(axis.fields[axis_field::kY].max, 800.0);
  const auto& wear =
      c.groups[static_cast<std::size_t>(Group::kToolMeasurement)].fields[tool_meas_field::kWear];
  EXPECT_DOUBLE_EQ(wear.min, -50.0);
  EXPECT_DOUBLE_EQ(wear.max, 500.0);
  EXPECT_DOUBLE_EQ(c.temperatures[0].value.min, -20.0);
  EXPECT_DOUBLE_EQ(c.temperatures[0].value.max, 80.0);
  // Without min / max a signal is unbounded (NaN / inf are refused by the decoder anyway).
  EXPECT_TRUE(std::isinf(c.groups[static_cast<std::size_t>(Group::kToolMeasurement)]
                             .fields[tool_meas_field::kTool]
                             .max));

  const std::string head = "[modbus]\ntransport = \"tcp\"\n[modbus.axis]\n";
  EXPECT_EQ(error_of(head + "x_mm = { address = 0, min = 5, max = -5 }\n"),
            "t.toml:4:38: modbus.axis.x_mm.max: max -5 is below min 5");
  EXPECT_EQ(error_of(head + "x_mm = { address = 0, min = \"low\" }\n"),
            "t.toml:4:29: modbus.axis.x_mm.min: must be a number");
  EXPECT_EQ(error_of(head + "x_mm = { address = 0, max = nan }\n"),
            "t.toml:4:29: modbus.axis.x_mm.max: must be a number in [-1e+300, 1e+300], got nan");
  EXPECT_EQ(error_of(head + "x_mm = { address = 0 }\ncutting = { table = \"coil\", address = 1, "
                            "max = 1 }\n"),
            "t.toml:5:48: modbus.axis.cutting.max: a coil is one bit: min / max do not apply");
  EXPECT_EQ(
      error_of("[modbus]\ntransport = \"tcp\"\n[modbus.tool_change]\n"
               "sequence = { address = 0, type = \"uint16\", min = 0 }\ntool = { address = 1 }\n"),
      "t.toml:4:50: modbus.tool_change.sequence.min: a sequence counter has no range: it counts "
      "events and wraps");
  EXPECT_EQ(error_of("[modbus]\ntransport = \"tcp\"\n[modbus.axis]\nx_mm = { address = 0 }\n"
                     "[[modbus.temperature]]\nsensor = 0\naddress = 9\nmin = 30\nmax = 20\n"),
            "t.toml:9:7: modbus.temperature[0].max: max 20 is below min 30");
  // Offsets are bounded by the engine's limiter and the register's encoding, not here.
  EXPECT_EQ(error_of("[modbus]\ntransport = \"tcp\"\n[modbus.axis]\nx_mm = { address = 0 }\n"
                     "[[modbus.offset]]\nregister_index = 0\naddress = 9\nmax = 20\n"),
            "t.toml:8:7: modbus.offset[0].max: unknown key");
}

TEST(ModbusConfig, PollRateDefaultsToTheLoopRateAndIsNotFasterThanIt) {
  // Stand-alone (modbus_map, ncsim): 100 Hz when the key is absent, no upper bound but the range.
  ModbusConfig c = parse_modbus_config(kMinimal, "t.toml");
  EXPECT_DOUBLE_EQ(c.poll_rate_hz, 100.0);
  EXPECT_TRUE(c.poll_rate_defaulted);
  // nccompd: the loop rate is the default, and the derived write rate follows it.
  ParseOptions loop;
  loop.default_poll_rate_hz = 1000.0;
  loop.max_poll_rate_hz = 1000.0;
  loop.rate_source = "daemon.rate_hz";
  c = parse_modbus_config(kMinimal, "t.toml", loop);
  EXPECT_DOUBLE_EQ(c.poll_rate_hz, 1000.0);
  EXPECT_DOUBLE_EQ(c.offset_write_rate_hz, 1000.0);
  // A slower poll is allowed (the loop then reuses the latest sample).
  const std::string with_rate = R"(
[modbus]
transport = "tcp"
poll_rate_hz = RATE
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int32", scale = 0.001 }
)";
  const auto rate = [&](const std::string& r) {
    std::string t = with_rate;
    t.replace(t.find("RATE"), 4, r);
    return t;
  };
  c = parse_modbus_config(rate("250"), "t.toml", loop);
  EXPECT_DOUBLE_EQ(c.poll_rate_hz, 250.0);
  EXPECT_FALSE(c.poll_rate_defaulted);
  // A faster one is refused at its key, saying why and what is allowed.
  try {
    (void)parse_modbus_config(rate("2000"), "t.toml", loop);
    ADD_FAILURE() << "2000 Hz accepted with a 1000 Hz loop";
  } catch (const formats::DiagnosticsError& e) {
    ASSERT_EQ(e.diagnostics().items().size(), 1U);
    const formats::Diagnostic& d = e.diagnostics().items().front();
    EXPECT_EQ(d.where.line, 4);
    EXPECT_EQ(d.where.key_path, "modbus.poll_rate_hz");
    EXPECT_EQ(d.message,
              "2000 Hz is faster than the loop (daemon.rate_hz = 1000 Hz), which takes at most one "
              "sample per cycle: the extra polls only load the NC and the bus; at most 1000 Hz "
              "(leave poll_rate_hz out to poll at the loop rate)");
  }
  // RTU: a loop rate the bus cannot carry is refused as such, with the rate that fits.
  EXPECT_THAT(
      [&] {
        try {
          (void)parse_modbus_config(
              "[modbus]\ntransport = \"rtu\"\ndevice = \"/dev/null\"\nbaud = 115200\n"
              "[modbus.axis]\nx_mm = { address = 0, type = \"int32\" }\n",
              "t.toml", loop);
        } catch (const formats::DiagnosticsError& e) {
          return std::string(e.what());
        }
        return std::string("(accepted)");
      }(),
      HasSubstr("modbus.poll_rate_hz: 1000 Hz (poll_rate_hz is not set: the loop rate "
                "daemon.rate_hz) needs"));
}

// GIVEN the I/O thread's real-time keys, WHEN parsed stand-alone and with the loop's priority
// known (nccompd), THEN valid values are kept, bad ones refused at their key path, and a priority
// not below the loop's is refused with the loop's key path and the highest one allowed.
TEST(ModbusConfig, IoThreadPriorityAndAffinityAreValidatedAgainstTheLoop) {
  ModbusConfig c = parse_modbus_config(kMinimal, "t.toml");
  EXPECT_EQ(c.io_sched_fifo_priority, 0);  // off by default
  EXPECT_TRUE(c.io_cpu_affinity.empty());
  const auto with = [](const std::string& keys) {
    return "[modbus]\ntransport = \"tcp\"\n" + keys +
           "\n[modbus.axis]\nx_mm = { table = \"input\", address = 0, type = \"int32\" }\n";
  };
  // Stand-alone (modbus_map, tests): the loop's priority is unknown, any 1..99 is taken.
  c = parse_modbus_config(with("io_sched_fifo_priority = 99\nio_cpu_affinity = [1, 0]"), "t.toml");
  EXPECT_EQ(c.io_sched_fifo_priority, 99);
  EXPECT_EQ(c.io_cpu_affinity, (std::vector<int>{1, 0}));
  c = parse_modbus_config(with("io_cpu_affinity = []"), "t.toml");
  EXPECT_TRUE(c.io_cpu_affinity.empty());

  const auto error_with = [&](const std::string& keys, const ParseOptions& o = {}) {
    try {
      (void)parse_modbus_config(with(keys), "t.toml", o);
    } catch (const formats::DiagnosticsError& e) {
      return std::string(e.what());
    }
    return std::string("(accepted)");
  };
  EXPECT_EQ(error_with("io_sched_fifo_priority = 100"),
            "t.toml:3:26: modbus.io_sched_fifo_priority: must be an integer in [0, 99], got 100");
  EXPECT_EQ(error_with("io_sched_fifo_priority = -1"),
            "t.toml:3:26: modbus.io_sched_fifo_priority: must be an integer in [0, 99], got -1");
  EXPECT_EQ(error_with("io_sched_fifo_priority = \"high\""),
            "t.toml:3:26: modbus.io_sched_fifo_priority: must be an integer");
  EXPECT_EQ(error_with("io_sched_fifo_priority = 1.5"),
            "t.toml:3:26: modbus.io_sched_fifo_priority: must be an integer");
  EXPECT_EQ(error_with("io_cpu_affinity = 1"),
            "t.toml:3:19: modbus.io_cpu_affinity: must be an array of integers");
  EXPECT_EQ(error_with("io_cpu_affinity = [0, \"1\"]"),
            "t.toml:3:23: modbus.io_cpu_affinity[1]: must be an integer");
  EXPECT_EQ(error_with("io_cpu_affinity = [1024]"),
            "t.toml:3:20: modbus.io_cpu_affinity[0]: must be an integer in [0, 1023], got 1024");
  EXPECT_EQ(error_with("io_cpu_affinity = [-1]"),
            "t.toml:3:20: modbus.io_cpu_affinity[0]: must be an integer in [0, 1023], got -1");
  EXPECT_EQ(error_with("io_cpu_affinity = [1, 1]"),
            "t.toml:3:19: modbus.io_cpu_affinity: CPU 1 is listed twice");

  // nccompd: the loop at SCHED_FIFO 50.
  ParseOptions loop;
  loop.loop_sched_fifo_priority = 50;
  loop.loop_priority_source = "daemon.realtime.sched_fifo_priority";
  c = parse_modbus_config(with("io_sched_fifo_priority = 49"), "t.toml", loop);
  EXPECT_EQ(c.io_sched_fifo_priority, 49);
  c = parse_modbus_config(with("io_sched_fifo_priority = 0"), "t.toml", loop);
  EXPECT_EQ(c.io_sched_fifo_priority, 0);
  const std::string not_below =
      ": the loop must always preempt the driver's I/O thread; at most 49 (0 = off)";
  EXPECT_EQ(error_with("io_sched_fifo_priority = 50", loop),
            "t.toml:3:26: modbus.io_sched_fifo_priority: 50 is not below the loop thread's "
            "SCHED_FIFO priority (daemon.realtime.sched_fifo_priority = 50)" +
                not_below);
  EXPECT_EQ(error_with("io_sched_fifo_priority = 80", loop),
            "t.toml:3:26: modbus.io_sched_fifo_priority: 80 is not below the loop thread's "
            "SCHED_FIFO priority (daemon.realtime.sched_fifo_priority = 50)" +
                not_below);
  // The loop at normal scheduling: any SCHED_FIFO I/O thread would preempt it.
  loop.loop_sched_fifo_priority = 0;
  EXPECT_EQ(error_with("io_sched_fifo_priority = 1", loop),
            "t.toml:3:26: modbus.io_sched_fifo_priority: 1 is not below the loop thread's "
            "SCHED_FIFO priority (daemon.realtime.sched_fifo_priority = 0: the loop runs at normal "
            "scheduling, so any SCHED_FIFO I/O thread would preempt it); raise the loop's priority "
            "above this one, or set 0 here");
  c = parse_modbus_config(with("io_sched_fifo_priority = 0\nio_cpu_affinity = [0]"), "t.toml",
                          loop);
  EXPECT_EQ(c.io_cpu_affinity, (std::vector<int>{0}));
}

TEST(ModbusConfig, RtuRateBudget) {
  // GIVEN 9600 baud 8E1 (11 bits per char): one read of 2 registers = 8 + 9 bytes + 2 gaps of
  // 3.5 chars = 24 chars = 27.5 ms
  const auto base = [](const std::string& top) {
    return R"([modbus]
transport = "rtu"
device = "/dev/null"
baud = 9600
parity = "even"
)" + top + R"(
[modbus.axis]
x_mm = { address = 0, type = "int32" }
)";
  };
  const ModbusConfig c = parse_modbus_config(base("poll_rate_hz = 10"), "t.toml");
  // (8 + 5 + 4) chars + 7 chars of gap = 24 chars * 11 bits / 9600
  EXPECT_NEAR(c.poll_bus_time_s, 24.0 * 11.0 / 9600.0, 1e-9);
  EXPECT_NEAR(rtu_frame_gap_s(c), 3.5 * 11.0 / 9600.0, 1e-12);
  // Above 19200 baud the gap is fixed at 1.75 ms.
  const ModbusConfig fast = parse_modbus_config(std::string(R"([modbus]
transport = "rtu"
device = "/dev/null"
baud = 115200
[modbus.axis]
x_mm = { address = 0, type = "int32" }
)"),
                                                "t.toml");
  EXPECT_DOUBLE_EQ(rtu_frame_gap_s(fast), 0.00175);
  // WHEN 100 Hz is asked of 9600 baud THEN it is refused with the achievable rate.
  EXPECT_THAT(error_of(base("poll_rate_hz = 100")),
              HasSubstr("t.toml:6:16: modbus.poll_rate_hz: 100 Hz needs"));
  // An explicit offset write rate beyond the bus budget is refused too.
  EXPECT_THAT(error_of(base("poll_rate_hz = 10\noffset_write_rate_hz = 50") + R"(
[[modbus.offset]]
register_index = 0
address = 100
type = "int32"
)"),
              HasSubstr("modbus.offset_write_rate_hz: 50 Hz does not fit"));
}

}  // namespace
}  // namespace nccomp::drivers::modbus

namespace nccomp::drivers::modbus {
namespace {

// GIVEN a map with four mistakes in different tables, THEN all four are reported, each at its
// file:line:column and key path (parse_modbus_config's what(), one per line, and
// read_modbus_table's diagnostics), not only the first.
TEST(ModbusConfig, EveryErrorOfAMapIsReportedNotOnlyTheFirst) {
  const std::string text =
      "[modbus]\ntransport = \"tcp\"\nport = 0\nunit_id = 300\n[modbus.axis]\n"
      "x_mm = { address = 70000 }\ny_mm = { address = 1, type = \"int8\" }\n";
  EXPECT_EQ(error_of(text),
            "t.toml:3:8: modbus.port: must be an integer in [1, 65535], got 0\n"
            "t.toml:4:11: modbus.unit_id: must be an integer in [0, 247], got 300\n"
            "t.toml:6:20: modbus.axis.x_mm.address: must be an integer in [0, 65535], got 70000\n"
            "t.toml:7:30: modbus.axis.y_mm.type: must be one of \"bool\", \"int16\", \"uint16\", "
            "\"int32\", \"uint32\", \"float32\", got \"int8\"");
  const toml::table root = toml::parse(std::string_view(text), std::string_view("t.toml"));
  formats::Diagnostics diag;
  EXPECT_FALSE(read_modbus_table(*root["modbus"].as_table(), "t.toml", {}, diag));
  ASSERT_EQ(diag.items().size(), 4U);
  EXPECT_EQ(diag.items()[2].where.key_path, "modbus.axis.x_mm.address");
  EXPECT_EQ(diag.items()[2].where.line, 6);
}

}  // namespace
}  // namespace nccomp::drivers::modbus
