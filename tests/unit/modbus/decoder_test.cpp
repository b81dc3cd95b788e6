#include "drivers/modbus/decoder.hpp"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <variant>
#include <vector>

#include "formats/toml/diagnostics.hpp"
#include "tests/support/alloc_counter.hpp"

namespace nccomp::drivers::modbus {
namespace {

const char* const kMap = R"([modbus]
transport = "tcp"
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int32", scale = 0.001 }
y_mm = { table = "input", address = 2, type = "float32", word_order = "low_first" }
tool = { table = "input", address = 4, type = "uint16" }
program_path_mm = { table = "input", address = 5, type = "float32" }
cutting = { table = "coil", address = 3 }
[modbus.tool_measurement]
sequence = { table = "holding", address = 100, type = "uint16" }
tool = { table = "holding", address = 101, type = "uint16" }
wear_um = { table = "holding", address = 102, type = "float32" }
broken = { table = "holding", address = 104, type = "uint16" }
[modbus.calibration_touch]
sequence = { table = "holding", address = 110, type = "uint32" }
axis = { table = "holding", address = 112, type = "uint16" }
direction = { table = "holding", address = 113, type = "int16" }
trigger_position_mm = { table = "holding", address = 114, type = "int32", scale = 0.0001 }
[[modbus.temperature]]
sensor = 2
table = "input"
address = 50
type = "int16"
scale = 0.01
)";

void put_float(std::span<std::uint16_t> b, std::size_t at, float v, bool low_first) {
  std::uint32_t u = 0;
  std::memcpy(&u, &v, 4);
  const auto hi = static_cast<std::uint16_t>(u >> 16U);
  const auto lo = static_cast<std::uint16_t>(u & 0xFFFFU);
  b[at] = low_first ? lo : hi;
  b[at + 1] = low_first ? hi : lo;
}

/// An event to deliver, not a counter the decoder consumed without one (counter_only: the
/// engine's cursor follows it, nothing else sees it).
bool delivered(const core::Event& e) {
  const core::EventOrigin* o = core::origin_of(e);
  return o == nullptr || !o->counter_only;
}

struct ModbusDecoder : ::testing::Test {
  ModbusConfig config = parse_modbus_config(kMap, "t.toml");
  PollDecoder dec{config};
  std::vector<std::uint8_t> ok = std::vector<std::uint8_t>(config.blocks.size(), 1);

  // Blocks, sorted by table and address: 0 = coil (axis), 1 = holding (tool measurement),
  // 2 = holding (touch), 3 = input (axis), 4 = input (temperature).
  std::span<std::uint16_t> axis() { return dec.block(3); }
  std::span<std::uint16_t> meas() { return dec.block(1); }
  std::span<std::uint16_t> touch() { return dec.block(2); }

  template <typename T>
  std::vector<T> events_of(std::span<const core::Event> ev) {
    std::vector<T> out;
    for (const auto& e : ev) {
      if (const auto* p = std::get_if<T>(&e); p != nullptr && delivered(e)) {
        out.push_back(*p);
      }
    }
    return out;
  }
};

TEST_F(ModbusDecoder, BlockLayout) {
  ASSERT_EQ(config.blocks.size(), 5U);
  EXPECT_EQ(config.blocks[0].table, Table::kCoil);
  EXPECT_EQ(config.blocks[0].start, 3);
  EXPECT_EQ(config.blocks[3].count, 7);
  EXPECT_EQ(config.blocks[2].count, 6);
}

TEST_F(ModbusDecoder, AxisSampleEveryPollWithAllEncodings) {
  // GIVEN x = -12.345 mm (int32, 0.001), y = 2.5 mm (float, low word first), tool 7, path 100.25
  axis()[0] = 0xFFFF;
  axis()[1] = static_cast<std::uint16_t>(-12345 & 0xFFFF);
  put_float(axis(), 2, 2.5F, true);
  axis()[4] = 7;
  put_float(axis(), 5, 100.25F, false);
  dec.block(0)[0] = 0;  // not cutting
  const auto samples = events_of<core::AxisSample>(dec.decode(42, ok));
  ASSERT_EQ(samples.size(), 1U);
  const core::AxisSample& s = samples[0];
  EXPECT_EQ(s.time_ns, 42);
  EXPECT_EQ(s.axis_count, 2);
  EXPECT_NEAR(s.position_mm[0], -12.345, 1e-9);
  EXPECT_DOUBLE_EQ(s.position_mm[1], 2.5);
  EXPECT_EQ(s.tool, 7);
  EXPECT_DOUBLE_EQ(s.program_path_mm, 100.25);
  EXPECT_FALSE(s.cutting);
  EXPECT_FALSE(s.has_normal);
  // A second poll gives a second sample (state, not an event).
  EXPECT_EQ(events_of<core::AxisSample>(dec.decode(43, ok)).size(), 1U);
}

TEST_F(ModbusDecoder, NaNPositionDropsTheSampleAndCountsIt) {
  put_float(axis(), 2, std::nanf(""), true);
  EXPECT_TRUE(events_of<core::AxisSample>(dec.decode(1, ok)).empty());
  EXPECT_EQ(dec.counters().values_invalid, 1U);
  // NaN program path means "unknown" and is passed on.
  put_float(axis(), 2, 1.0F, true);
  put_float(axis(), 5, std::nanf(""), false);
  const auto s = events_of<core::AxisSample>(dec.decode(2, ok));
  ASSERT_EQ(s.size(), 1U);
  EXPECT_TRUE(std::isnan(s[0].program_path_mm));
}

TEST_F(ModbusDecoder, SequenceCounterBaselineOnceJumpAndWrap) {
  meas()[0] = 65534;
  meas()[1] = 5;
  put_float(meas(), 2, 12.5F, false);
  // WHEN the first poll sees counter 65534 THEN it is only a baseline
  EXPECT_TRUE(events_of<core::ToolMeasurement>(dec.decode(1, ok)).empty());
  // WHEN the counter does not move THEN nothing, however often polled
  EXPECT_TRUE(events_of<core::ToolMeasurement>(dec.decode(2, ok)).empty());
  // WHEN it advances by one THEN one event with the values read in the same request
  meas()[0] = 65535;
  put_float(meas(), 2, 13.0F, false);
  auto tm = events_of<core::ToolMeasurement>(dec.decode(3, ok));
  ASSERT_EQ(tm.size(), 1U);
  EXPECT_EQ(tm[0].tool, 5);
  EXPECT_DOUBLE_EQ(tm[0].wear_um[0], 13.0);
  EXPECT_FALSE(tm[0].broken);
  EXPECT_TRUE(events_of<core::ToolMeasurement>(dec.decode(4, ok)).empty());
  // WHEN it wraps 65535 -> 2 (3 steps) THEN the latest event is emitted and 2 are lost
  meas()[0] = 2;
  meas()[4] = 1;
  tm = events_of<core::ToolMeasurement>(dec.decode(5, ok));
  ASSERT_EQ(tm.size(), 1U);
  EXPECT_TRUE(tm[0].broken);
  EXPECT_EQ(dec.counters().events_lost, 2U);
  // WHEN the NC restarts its counter (backwards) THEN re-baseline, no event
  meas()[0] = 0;
  EXPECT_TRUE(events_of<core::ToolMeasurement>(dec.decode(6, ok)).empty());
  EXPECT_EQ(dec.counters().sequence_resets, 1U);
  meas()[0] = 1;
  EXPECT_EQ(events_of<core::ToolMeasurement>(dec.decode(7, ok)).size(), 1U);
}

TEST_F(ModbusDecoder, UnreadBlockSkipsItsGroupAndKeepsTheCounter) {
  dec.decode(1, ok);  // baselines (counter 0)
  meas()[0] = 1;
  ok[1] = 0;  // the tool measurement request failed this poll
  auto ev = dec.decode(2, ok);
  EXPECT_TRUE(events_of<core::ToolMeasurement>(ev).empty());
  EXPECT_EQ(events_of<core::AxisSample>(ev).size(), 1U);
  ok[1] = 1;
  EXPECT_EQ(events_of<core::ToolMeasurement>(dec.decode(3, ok)).size(), 1U);
  EXPECT_EQ(dec.counters().events_lost, 0U);
}

TEST_F(ModbusDecoder, Uint32CounterAndRangeChecks) {
  touch()[0] = 0x0001;
  touch()[1] = 0xFFFF;  // 0x0001FFFF
  dec.decode(1, ok);
  // +1 across the word boundary: 0x00020000
  touch()[0] = 0x0002;
  touch()[1] = 0x0000;
  touch()[2] = 2;                                        // axis Z
  touch()[3] = static_cast<std::uint16_t>(-1 & 0xFFFF);  // direction -1
  touch()[4] = 0x0001;
  touch()[5] = 0x86A0;  // 100000 * 0.0001 = 10 mm
  auto t = events_of<core::CalibrationTouch>(dec.decode(2, ok));
  ASSERT_EQ(t.size(), 1U);
  EXPECT_EQ(t[0].axis, 2);
  EXPECT_EQ(t[0].direction, -1);
  EXPECT_NEAR(t[0].trigger_position_mm, 10.0, 1e-12);
  EXPECT_EQ(dec.counters().events_lost, 0U);
  // WHEN the NC sends axis 5 (no such axis) THEN the event is consumed, counted invalid and
  // delivered once as a faulted touch without a position (its method raises the alarm)
  touch()[1] = 0x0001;
  touch()[2] = 5;
  t = events_of<core::CalibrationTouch>(dec.decode(3, ok));
  ASSERT_EQ(t.size(), 1U);
  EXPECT_EQ(t[0].fault, core::InputFault::kInvalid);
  EXPECT_EQ(t[0].axis, 0);  // unknown: the default
  EXPECT_EQ(t[0].trigger_position_mm, 0.0);
  EXPECT_EQ(dec.counters().values_invalid, 1U);
  EXPECT_TRUE(events_of<core::CalibrationTouch>(dec.decode(4, ok)).empty());  // not re-read
  // and direction 0 is invalid too; the faulted touch still carries a valid direction
  touch()[1] = 0x0002;
  touch()[2] = 0;
  touch()[3] = 0;
  t = events_of<core::CalibrationTouch>(dec.decode(5, ok));
  ASSERT_EQ(t.size(), 1U);
  EXPECT_EQ(t[0].fault, core::InputFault::kInvalid);
  EXPECT_EQ(t[0].direction, 1);
  EXPECT_EQ(dec.counters().values_invalid, 2U);
}

TEST_F(ModbusDecoder, TemperatureOnChangeOnly) {
  dec.block(4)[0] = 2150;  // 21.50 °C
  auto t = events_of<core::TemperatureSample>(dec.decode(1, ok));
  ASSERT_EQ(t.size(), 1U);
  EXPECT_EQ(t[0].sensor, 2);
  EXPECT_DOUBLE_EQ(t[0].temperature_c, 21.5);
  EXPECT_TRUE(events_of<core::TemperatureSample>(dec.decode(2, ok)).empty());
  dec.block(4)[0] = static_cast<std::uint16_t>(-125 & 0xFFFF);
  t = events_of<core::TemperatureSample>(dec.decode(3, ok));
  ASSERT_EQ(t.size(), 1U);
  EXPECT_DOUBLE_EQ(t[0].temperature_c, -1.25);
}

TEST_F(ModbusDecoder, DecodeIsAllocationFree) {
  dec.decode(1, ok);
  meas()[0] = 1;
  touch()[1] = 1;
  touch()[3] = 1;
  dec.block(4)[0] = 7;
  const nccomp::test::AllocationScope scope;
  const auto ev = dec.decode(2, ok);
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_EQ(ev.size(), 4U);  // axis sample, tool measurement, touch, temperature
}

// An NC that restarts counts its events again from 0 (kSequenceStart). GIVEN the uint16 tool
// measurement counter read at `before`, WHEN the next poll reads `after` (with the values of the
// newest event: tool 8, 33 µm), THEN `delivered` events come out, `lost` are counted lost and
// `resets` sequence resets.
struct CounterCase {
  const char* what;
  std::uint32_t before;
  std::uint32_t after;
  std::size_t delivered;
  std::uint64_t lost;
  std::uint64_t resets;
};

TEST(ModbusDecoderRestart, BackwardIsARestartForwardIsEventsWrapOnlyNearTheTop) {
  const ModbusConfig config = parse_modbus_config(kMap, "t.toml");
  const std::uint32_t near_top = 65536U - kMaxWrapEvents;  // + 9 -> 9 is +256 events
  const std::array<CounterCase, 11> cases = {{
      {"unchanged", 42, 42, 0, 0, 0},
      {"restart, no event since: nothing to deliver", 42, 0, 0, 0, 1},
      {"restart from above half the range: not +25536", 40000, 0, 0, 0, 1},
      {"restart, 3 events since: the newest delivered, 2 lost", 42, 3, 1, 2, 1},
      {"restart from above half the range, 3 events since: not +25539", 40000, 3, 1, 2, 1},
      {"forward: +3 (a restart with 9 events since looks the same)", 6, 9, 1, 2, 0},
      {"forward however far: +39991, not backwards through the wrap", 9, 40000, 1, 39990, 0},
      {"wrap 65535 -> 0: +1", 65535, 0, 1, 0, 0},
      {"wrap 65500 -> 100: +136", 65500, 100, 1, 135, 0},
      {"wrap of kMaxWrapEvents: still a wrap", near_top + 9, 9, 1, kMaxWrapEvents - 1U, 0},
      {"one more than kMaxWrapEvents: a restart, 9 events since", near_top + 8, 9, 1, 8, 1},
  }};
  const auto tool_measurements = [](std::span<const core::Event> ev) {
    std::vector<core::ToolMeasurement> out;
    for (const core::Event& e : ev) {
      if (const auto* p = std::get_if<core::ToolMeasurement>(&e); p != nullptr && delivered(e)) {
        out.push_back(*p);
      }
    }
    return out;
  };
  for (const CounterCase& c : cases) {
    SCOPED_TRACE(::testing::Message() << c.what << ": " << c.before << " -> " << c.after);
    PollDecoder dec(config);
    const std::vector<std::uint8_t> ok(config.blocks.size(), 1);
    std::span<std::uint16_t> meas = dec.block(1);
    meas[0] = static_cast<std::uint16_t>(c.before);
    meas[1] = 5;
    put_float(meas, 2, 12.5F, false);
    ASSERT_TRUE(tool_measurements(dec.decode(1, ok)).empty()) << "a baseline";
    meas[0] = static_cast<std::uint16_t>(c.after);
    meas[1] = 8;
    put_float(meas, 2, 33.0F, false);
    const std::vector<core::ToolMeasurement> tm = tool_measurements(dec.decode(2, ok));
    EXPECT_EQ(tm.size(), c.delivered);
    if (c.delivered == 1U && tm.size() == 1U) {
      EXPECT_EQ(tm[0].tool, 8);
      EXPECT_DOUBLE_EQ(tm[0].wear_um[0], 33.0);
    }
    EXPECT_EQ(dec.counters().events_lost, c.lost);
    EXPECT_EQ(dec.counters().sequence_resets, c.resets);
    EXPECT_EQ(dec.counters().sequence_unchanged_after_reconnect, 0U);
    // Never twice: the next poll with the same counter delivers nothing.
    EXPECT_TRUE(tool_measurements(dec.decode(3, ok)).empty());
  }
}

TEST_F(ModbusDecoder, Uint32CounterWrapsNearTheTopAndRestartsBelow) {
  // GIVEN the uint32 touch counter at 0xFFFFFFFF (values: axis Z, direction -1, 10 mm)
  touch()[0] = 0xFFFF;
  touch()[1] = 0xFFFF;
  touch()[2] = 2;
  touch()[3] = static_cast<std::uint16_t>(-1 & 0xFFFF);
  touch()[4] = 0x0001;
  touch()[5] = 0x86A0;
  dec.decode(1, ok);
  // WHEN it wraps to 1 THEN +2: one delivered, one lost
  touch()[0] = 0;
  touch()[1] = 1;
  ASSERT_EQ(events_of<core::CalibrationTouch>(dec.decode(2, ok)).size(), 1U);
  EXPECT_EQ(dec.counters().events_lost, 1U);
  // WHEN it reaches 0x00020000 THEN forward (+0x1FFFF)
  touch()[0] = 0x0002;
  touch()[1] = 0x0000;
  ASSERT_EQ(events_of<core::CalibrationTouch>(dec.decode(3, ok)).size(), 1U);
  EXPECT_EQ(dec.counters().events_lost, std::uint64_t{1} + 0x1FFFEU);
  EXPECT_EQ(dec.counters().sequence_resets, 0U);
  // WHEN the NC restarts and makes 5 touches before the next poll THEN the newest is delivered,
  // 4 lost, one reset
  touch()[0] = 0;
  touch()[1] = 5;
  const auto t = events_of<core::CalibrationTouch>(dec.decode(4, ok));
  ASSERT_EQ(t.size(), 1U);
  EXPECT_NEAR(t[0].trigger_position_mm, 10.0, 1e-12);
  EXPECT_EQ(dec.counters().events_lost, std::uint64_t{1} + 0x1FFFEU + 4U);
  EXPECT_EQ(dec.counters().sequence_resets, 1U);
}

// The first read of a counter after a reconnect (the NC may have restarted meanwhile).
struct ModbusDecoderReconnect : ModbusDecoder {
  /// Baseline at `before`, then one event (before + 1) delivered.
  void run_up_to(std::uint16_t before) {
    meas()[0] = before;
    ASSERT_TRUE(events_of<core::ToolMeasurement>(dec.decode(1, ok)).empty());
    meas()[0] = static_cast<std::uint16_t>(before + 1U);
    meas()[1] = 5;
    put_float(meas(), 2, 12.5F, false);
    ASSERT_EQ(events_of<core::ToolMeasurement>(dec.decode(2, ok)).size(), 1U);
  }
  /// The NC answers with the tool measurement counter at `counter`.
  std::vector<core::ToolMeasurement> poll_at(std::uint16_t counter, core::TimeNs t) {
    meas()[0] = counter;
    return events_of<core::ToolMeasurement>(dec.decode(t, ok));
  }
};

TEST_F(ModbusDecoderReconnect, UnchangedCounterAtTheFirstReadAfterAReconnectIsCounted) {
  // GIVEN the tool measurement counter at 7 and the touch counter at 0
  run_up_to(6);
  // WHEN the link is re-established and the counter still reads 7
  dec.note_reconnect();
  // THEN nothing is delivered (the driver cannot know), but the doubt is counted, once per
  // reconnect and group; the touch counter at 0 leaves no doubt (nothing can have been missed)
  EXPECT_TRUE(poll_at(7, 3).empty());
  EXPECT_EQ(dec.counters().sequence_unchanged_after_reconnect, 1U);
  EXPECT_TRUE(poll_at(7, 4).empty());
  EXPECT_EQ(dec.counters().sequence_unchanged_after_reconnect, 1U);
  // WHEN the group is not read in the first poll after a reconnect THEN the check waits for the
  // first read
  dec.note_reconnect();
  ok[1] = 0;
  EXPECT_TRUE(poll_at(7, 5).empty());
  EXPECT_EQ(dec.counters().sequence_unchanged_after_reconnect, 1U);
  ok[1] = 1;
  EXPECT_TRUE(poll_at(7, 6).empty());
  EXPECT_EQ(dec.counters().sequence_unchanged_after_reconnect, 2U);
  // WHEN it moved on after a reconnect THEN delivered as usual, no doubt counted
  dec.note_reconnect();
  EXPECT_EQ(poll_at(8, 7).size(), 1U);
  EXPECT_EQ(dec.counters().sequence_unchanged_after_reconnect, 2U);
  EXPECT_EQ(dec.counters().events_lost, 0U);
  EXPECT_EQ(dec.counters().sequence_resets, 0U);
}

// The engine's event cursors (docs/daemon.md, "Events while nccompd was down"): every counter the
// decoder consumes reaches the engine with an event, a counter it consumes without one as a
// counter_only event, so that a restarted daemon can resume from it.
TEST_F(ModbusDecoder, EveryConsumedCounterReachesTheEngineAlsoWithoutAnEvent) {
  // GIVEN the tool measurement counter at 7 and the uint32 touch counter at 0x00010002
  meas()[0] = 7;
  touch()[0] = 0x0001;
  touch()[1] = 0x0002;
  // WHEN the first poll takes them as the baseline THEN nothing is delivered, but each counter
  // leaves as a counter_only event of its kind
  const auto first = dec.decode(1, ok);
  std::vector<std::pair<std::size_t, core::EventOrigin>> origins;
  for (const core::Event& e : first) {
    if (const core::EventOrigin* o = core::origin_of(e)) {
      origins.emplace_back(e.index(), *o);
    }
  }
  ASSERT_EQ(origins.size(), 2U);
  EXPECT_EQ(core::numbered_kind(first[1]), 0);  // tool measurement, then the touch
  EXPECT_TRUE(origins[0].second.numbered && origins[0].second.counter_only);
  EXPECT_EQ(origins[0].second.sequence, 7U);
  EXPECT_TRUE(origins[1].second.numbered && origins[1].second.counter_only);
  EXPECT_EQ(origins[1].second.sequence, 0x00010002U);
  EXPECT_EQ(core::numbered_kind(first[2]), 2);
  // WHEN the tool measurement counter moves to 8 THEN its event carries 8 and is delivered
  meas()[0] = 8;
  meas()[1] = 3;
  put_float(meas(), 2, 4.5F, false);
  const auto tm = events_of<core::ToolMeasurement>(dec.decode(2, ok));
  ASSERT_EQ(tm.size(), 1U);
  EXPECT_TRUE(tm[0].origin.numbered);
  EXPECT_FALSE(tm[0].origin.counter_only);
  EXPECT_EQ(tm[0].origin.sequence, 8U);
  // WHEN the NC restarts with no event since (counter 0) THEN the 0 leaves as counter_only
  meas()[0] = 0;
  const auto after_restart = dec.decode(3, ok);
  EXPECT_TRUE(events_of<core::ToolMeasurement>(after_restart).empty());
  ASSERT_EQ(after_restart.size(), 2U);  // the axis sample and the counter
  const core::EventOrigin* o = core::origin_of(after_restart[1]);
  ASSERT_NE(o, nullptr);
  EXPECT_TRUE(o->counter_only);
  EXPECT_EQ(o->sequence, 0U);
  EXPECT_EQ(dec.counters().sequence_resets, 1U);
}

// GIVEN the engine's cursor of the tool measurement counter restored from the state (nccompd
// was down), WHEN its first read finds `after` (the newest event's values: tool 8, 33 µm), THEN
// `delivered` events come out, `lost` are counted lost while down, and the report says so.
struct ResumeCase {
  const char* what;
  std::uint32_t cursor;
  std::uint32_t after;
  std::size_t delivered;
  std::uint64_t lost;
  bool nc_restarted;
  std::uint32_t events;
  std::uint64_t unchanged;  // sequence_unchanged_after_reconnect
};

TEST(ModbusDecoderResume, TheNewestEventSinceTheCursorIsDeliveredOnceTheOthersCountedLost) {
  const ModbusConfig config = parse_modbus_config(kMap, "t.toml");
  const std::array<ResumeCase, 7> cases = {{
      {"nothing while down", 5, 5, 0, 0, false, 0, 1},
      {"nothing while down, counter 0: no doubt", 0, 0, 0, 0, false, 0, 0},
      {"one while down", 5, 6, 1, 0, false, 1, 0},
      {"three while down: the newest delivered, two lost", 5, 8, 1, 2, false, 3, 0},
      {"through the top of the range", 65534, 1, 1, 2, false, 3, 0},
      {"the NC restarted, two since", 5, 2, 1, 1, true, 2, 0},
      {"the NC restarted, none since", 5, 0, 0, 0, true, 0, 0},
  }};
  for (const ResumeCase& c : cases) {
    SCOPED_TRACE(::testing::Message() << c.what << ": " << c.cursor << " -> " << c.after);
    PollDecoder dec(config);
    core::EventCursorSet cursors{};
    cursors[0] = core::EventCursor{true, c.cursor};  // the tool measurement; the touch unknown
    dec.resume(cursors);
    const std::vector<std::uint8_t> ok(config.blocks.size(), 1);
    std::span<std::uint16_t> meas = dec.block(1);
    meas[0] = static_cast<std::uint16_t>(c.after);
    meas[1] = 8;
    put_float(meas, 2, 33.0F, false);
    std::vector<core::ToolMeasurement> tm;
    for (const core::Event& e : dec.decode(1, ok)) {
      if (const auto* p = std::get_if<core::ToolMeasurement>(&e); p != nullptr && delivered(e)) {
        tm.push_back(*p);
      }
    }
    ASSERT_EQ(tm.size(), c.delivered);
    if (c.delivered == 1U) {
      EXPECT_EQ(tm[0].tool, 8);
      EXPECT_DOUBLE_EQ(tm[0].wear_um[0], 33.0);
      EXPECT_EQ(tm[0].origin.sequence, c.after);
    }
    EXPECT_EQ(dec.counters().events_lost_while_down, c.lost);
    EXPECT_EQ(dec.counters().events_recovered_after_start, c.delivered);
    EXPECT_EQ(dec.counters().events_lost, 0U);
    EXPECT_EQ(dec.counters().sequence_resets, c.nc_restarted ? 1U : 0U);
    EXPECT_EQ(dec.counters().sequence_unchanged_after_reconnect, c.unchanged);
    const ResumeReport& r = dec.resume_reports()[static_cast<std::size_t>(Group::kToolMeasurement)];
    EXPECT_TRUE(r.done);
    EXPECT_EQ(r.cursor, c.cursor);
    EXPECT_EQ(r.counter, c.after);
    EXPECT_EQ(r.nc_restarted, c.nc_restarted);
    EXPECT_EQ(r.events, c.events);
    EXPECT_EQ(r.delivered, c.delivered == 1U);
    // The touch had no cursor: its first read is the baseline, nothing reported.
    EXPECT_FALSE(dec.resume_reports()[static_cast<std::size_t>(Group::kCalibrationTouch)].done);
    // Never twice: the next poll with the same counter delivers nothing, and later events
    // are counted as usual (not as while down).
    EXPECT_EQ(dec.decode(2, ok).size(), 1U);  // the axis sample only
    meas[0] = static_cast<std::uint16_t>(c.after + 3U);
    EXPECT_EQ(dec.decode(3, ok).size(), 2U);
    EXPECT_EQ(dec.counters().events_lost, 2U);
    EXPECT_EQ(dec.counters().events_lost_while_down, c.lost);
  }
}

// The newest event published while nccompd was down has an invalid value: like any invalid
// measurement it is delivered once, marked faulted with its values cleared (its method raises its
// alarm and changes nothing), and its counter becomes the cursor; the one before it is lost.
TEST(ModbusDecoderResume, ANewestEventWithInvalidValuesIsDeliveredFaulted) {
  const ModbusConfig config = parse_modbus_config(kMap, "t.toml");
  PollDecoder dec(config);
  core::EventCursorSet cursors{};
  cursors[0] = core::EventCursor{true, 5};
  dec.resume(cursors);
  const std::vector<std::uint8_t> ok(config.blocks.size(), 1);
  std::span<std::uint16_t> meas = dec.block(1);
  meas[0] = 7;
  put_float(meas, 2, std::nanf(""), false);
  int measurements = 0;
  for (const core::Event& e : dec.decode(1, ok)) {
    if (const auto* t = std::get_if<core::ToolMeasurement>(&e)) {
      ++measurements;
      EXPECT_EQ(t->fault, core::InputFault::kInvalid);
      EXPECT_EQ(t->wear_um[0], 0.0);
      EXPECT_EQ(t->origin.sequence, 7U);
    }
  }
  EXPECT_EQ(measurements, 1);
  EXPECT_EQ(dec.counters().values_invalid, 1U);
  EXPECT_EQ(dec.counters().events_lost_while_down, 1U);
  EXPECT_EQ(dec.counters().events_recovered_after_start, 1U);
  const ResumeReport& r = dec.resume_reports()[static_cast<std::size_t>(Group::kToolMeasurement)];
  EXPECT_TRUE(r.done);
  EXPECT_EQ(r.events, 2U);
  EXPECT_TRUE(r.delivered);
}

TEST_F(ModbusDecoderReconnect, AReconnectBeforeTheFirstReadIsJustTheBaseline) {
  dec.note_reconnect();
  meas()[0] = 7;
  EXPECT_TRUE(events_of<core::ToolMeasurement>(dec.decode(1, ok)).empty());
  EXPECT_TRUE(events_of<core::ToolMeasurement>(dec.decode(2, ok)).empty());
  EXPECT_EQ(dec.counters().sequence_unchanged_after_reconnect, 0U);
}

}  // namespace
}  // namespace nccomp::drivers::modbus

namespace nccomp::drivers::modbus {
namespace {

TEST(ModbusDecoderRange, FiniteButAbsurdValuesAreDroppedAndCountedOnce) {
  // GIVEN a map with plausibility ranges: X within ±1200 mm, wear within -50..500 µm, the
  // spindle temperature within -20..80 °C
  const ModbusConfig c = parse_modbus_config(R"([modbus]
transport = "tcp"
[modbus.axis]
x_mm = { table = "input", address = 0, type = "float32", min = -1200, max = 1200 }
program_path_mm = { table = "input", address = 2, type = "float32", min = 0 }
[modbus.tool_measurement]
sequence = { address = 10, type = "uint16" }
tool = { address = 11 }
wear_um = { address = 12, type = "int16", scale = 0.1, count = 2, min = -50, max = 500 }
[[modbus.temperature]]
sensor = 4
table = "input"
address = 20
type = "int16"
scale = 0.01
min = -20
max = 80
)",
                                             "t.toml");
  PollDecoder dec(c);
  std::vector<std::uint8_t> ok(c.blocks.size(), 1);
  ASSERT_EQ(c.blocks.size(), 3U);  // holding 10..13; input 0..3; input 20
  auto axis = dec.block(1);
  auto meas = dec.block(0);
  auto temp = dec.block(2);
  const auto count = [](std::span<const core::Event> ev, auto tag) {
    using T = decltype(tag);
    std::size_t n = 0;
    for (const auto& e : ev) {
      n += std::holds_alternative<T>(e) ? 1U : 0U;
    }
    return n;
  };
  put_float(axis, 0, 1e30F, false);  // finite, absurd
  put_float(axis, 2, 10.0F, false);
  temp[0] = 2150;               // 21.5 °C
  auto ev = dec.decode(1, ok);  // also the tool measurement baseline
  EXPECT_EQ(count(ev, core::AxisSample{}), 0U);
  EXPECT_EQ(count(ev, core::TemperatureSample{}), 1U);
  EXPECT_EQ(dec.counters().values_out_of_range, 1U);
  EXPECT_EQ(dec.counters().values_invalid, 0U);
  // The bounds themselves are accepted; just beyond them is not.
  put_float(axis, 0, 1200.0F, false);
  EXPECT_EQ(count(dec.decode(2, ok), core::AxisSample{}), 1U);
  put_float(axis, 0, -1200.125F, false);
  EXPECT_EQ(count(dec.decode(3, ok), core::AxisSample{}), 0U);
  EXPECT_EQ(dec.counters().values_out_of_range, 2U);
  // A NaN path is "unknown" (passed on), not out of range; a negative one is.
  put_float(axis, 0, 5.0F, false);
  put_float(axis, 2, std::nanf(""), false);
  ev = dec.decode(4, ok);
  ASSERT_EQ(count(ev, core::AxisSample{}), 1U);
  put_float(axis, 2, -1.0F, false);
  EXPECT_EQ(count(dec.decode(5, ok), core::AxisSample{}), 0U);
  EXPECT_EQ(dec.counters().values_out_of_range, 3U);
  // NaN X is invalid, not out of range.
  put_float(axis, 2, 1.0F, false);
  put_float(axis, 0, std::nanf(""), false);
  EXPECT_EQ(count(dec.decode(6, ok), core::AxisSample{}), 0U);
  EXPECT_EQ(dec.counters().values_invalid, 1U);
  EXPECT_EQ(dec.counters().values_out_of_range, 3U);
  put_float(axis, 0, 5.0F, false);

  // An event whose second wear point is 3276.7 µm (> 500): delivered once as a faulted
  // measurement of tool 4 without values, its counter consumed, so the next poll does not read
  // it again.
  meas[0] = 1;
  meas[1] = 4;
  meas[2] = 25;     // 2.5 µm
  meas[3] = 32767;  // 3276.7 µm
  ev = dec.decode(7, ok);
  ASSERT_EQ(count(ev, core::ToolMeasurement{}), 1U);
  for (const auto& e : ev) {
    if (const auto* m = std::get_if<core::ToolMeasurement>(&e)) {
      EXPECT_EQ(m->fault, core::InputFault::kOutOfRange);
      EXPECT_EQ(m->tool, 4);
      EXPECT_EQ(m->wear_um[0], 0.0);
      EXPECT_EQ(m->wear_um[1], 0.0);
    }
  }
  EXPECT_EQ(dec.counters().values_out_of_range, 4U);
  EXPECT_EQ(dec.counters().values_invalid, 1U);  // out of range is not counted twice
  EXPECT_EQ(count(dec.decode(8, ok), core::ToolMeasurement{}), 0U);
  EXPECT_EQ(dec.counters().values_out_of_range, 4U);
  // The next event is plausible: delivered, nothing lost.
  meas[0] = 2;
  meas[3] = 30;
  ev = dec.decode(9, ok);
  ASSERT_EQ(count(ev, core::ToolMeasurement{}), 1U);
  EXPECT_EQ(std::get<core::ToolMeasurement>(ev.back()).fault, core::InputFault::kNone);
  EXPECT_EQ(dec.counters().events_lost, 0U);

  // A temperature of 95 °C (> 80): no sample; back to 22 °C: a sample.
  temp[0] = 9500;
  EXPECT_EQ(count(dec.decode(10, ok), core::TemperatureSample{}), 0U);
  EXPECT_EQ(dec.counters().values_out_of_range, 5U);
  temp[0] = 2200;
  {
    const nccomp::test::AllocationScope scope;  // range checks allocate nothing either
    ev = dec.decode(11, ok);
    EXPECT_EQ(scope.count(), 0U);
  }
  EXPECT_EQ(count(ev, core::TemperatureSample{}), 1U);
  EXPECT_EQ(count(ev, core::AxisSample{}), 1U);
}

// The reference map's encoding of the surface normal: three int16 components in 1/10000.
struct ModbusDecoderNormal : ::testing::Test {
  const ModbusConfig c = parse_modbus_config(R"([modbus]
transport = "tcp"
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int16", scale = 0.01 }
normal_x = { table = "input", address = 1, type = "int16", scale = 0.0001 }
normal_y = { table = "input", address = 2, type = "int16", scale = 0.0001 }
normal_z = { table = "input", address = 3, type = "int16", scale = 0.0001 }
)",
                                             "t.toml");
  PollDecoder dec{c};
  std::vector<std::uint8_t> ok = std::vector<std::uint8_t>(c.blocks.size(), 1);

  // The axis samples one poll with these normal registers decodes to.
  std::vector<core::AxisSample> sample(std::int16_t nx, std::int16_t ny, std::int16_t nz,
                                       core::TimeNs t) {
    auto axis = dec.block(0);
    axis[0] = 1234;  // 12.34 mm
    axis[1] = static_cast<std::uint16_t>(nx);
    axis[2] = static_cast<std::uint16_t>(ny);
    axis[3] = static_cast<std::uint16_t>(nz);
    std::vector<core::AxisSample> out;
    for (const auto& e : dec.decode(t, ok)) {
      if (const auto* p = std::get_if<core::AxisSample>(&e)) out.push_back(*p);
    }
    return out;
  }
};

TEST_F(ModbusDecoderNormal, AllZeroIsNoNormalAnyOtherNonUnitVectorDropsTheSample) {
  ASSERT_EQ(c.blocks.size(), 1U);
  // A unit normal at 30° (rounded to 1/10000): passed on, renormalised.
  auto s = sample(5000, 0, 8660, 1);
  ASSERT_EQ(s.size(), 1U);
  EXPECT_TRUE(s[0].has_normal);
  EXPECT_NEAR(s[0].normal[0], 0.5, 1e-4);
  EXPECT_NEAR(s[0].normal[2], std::sqrt(0.75), 1e-4);
  // WHEN all three are 0 (the NC knows no normal: not cutting, the trip to the laser)
  // THEN the sample is valid, without a normal, and nothing is counted.
  s = sample(0, 0, 0, 2);
  ASSERT_EQ(s.size(), 1U);
  EXPECT_FALSE(s[0].has_normal);
  EXPECT_NEAR(s[0].position_mm[0], 12.34, 1e-9);
  EXPECT_EQ(dec.counters().values_invalid, 0U);
  // WHEN the vector is neither 0 nor of unit length (a half-written or garbled normal)
  // THEN the sample is dropped and counted, each time.
  EXPECT_TRUE(sample(0, 0, 1, 3).empty());        // 0.0001: not zero, not unit
  EXPECT_TRUE(sample(5000, 0, 0, 4).empty());     // 0.5
  EXPECT_TRUE(sample(8000, 0, 8000, 5).empty());  // 1.13
  EXPECT_EQ(dec.counters().values_invalid, 3U);
}

// Pins the documented tolerance (docs/modbus.md: a unit vector ±1 % for the registers' rounding):
// lengths within 1 % pass and are renormalised, 1.5 % or 8 % off is a garbled normal.
TEST_F(ModbusDecoderNormal, UnitLengthWithinOnePercentPassesBeyondItDropsTheSample) {
  struct Case {
    std::int16_t nx, nz;
    double length;  // independently: sqrt(nx² + nz²) / 10000
    bool passes;
  };
  const Case cases[] = {
      {0, 9950, 0.995, true},  {0, 10050, 1.005, true},  {6000, 8040, 1.00320, true},
      {0, 9850, 0.985, false}, {0, 10150, 1.015, false}, {6000, 7800, 0.98408, false},
      {0, 9200, 0.92, false},  {0, 10800, 1.08, false},
  };
  core::TimeNs t = 1;
  std::uint64_t dropped = 0;
  for (const Case& k : cases) {
    SCOPED_TRACE(k.length);
    ASSERT_NEAR(std::hypot(k.nx, k.nz) / 10000.0, k.length, 1e-5);
    const auto s = sample(k.nx, 0, k.nz, t++);
    if (k.passes) {
      ASSERT_EQ(s.size(), 1U);
      EXPECT_TRUE(s[0].has_normal);
      EXPECT_NEAR(s[0].normal[0], k.nx / 10000.0 / k.length, 1e-5);
      EXPECT_NEAR(s[0].normal[2], k.nz / 10000.0 / k.length, 1e-5);
    } else {
      EXPECT_TRUE(s.empty());
      ++dropped;
    }
    EXPECT_EQ(dec.counters().values_invalid, dropped);
  }
}

TEST(ModbusDecoderProfile, WearProfileOverEdgeSupportPoints) {
  // GIVEN a laser that publishes wear at 4 support points along the edge, int16 in 0.1 µm
  const ModbusConfig c = parse_modbus_config(R"([modbus]
transport = "tcp"
[modbus.tool_measurement]
sequence = { address = 0, type = "uint16" }
tool = { address = 1 }
wear_um = { address = 2, type = "int16", scale = 0.1, count = 4 }
broken = { address = 6, type = "uint16" }
)",
                                             "t.toml");
  ASSERT_EQ(c.blocks.size(), 1U);
  EXPECT_EQ(c.blocks[0].count, 7);
  PollDecoder dec(c);
  std::vector<std::uint8_t> ok(1, 1);
  dec.decode(1, ok);  // baseline
  auto b = dec.block(0);
  b[0] = 1;
  b[1] = 3;
  b[2] = 10;
  b[3] = 25;
  b[4] = static_cast<std::uint16_t>(-5 & 0xFFFF);
  b[5] = 120;
  const auto ev = dec.decode(2, ok);
  ASSERT_EQ(ev.size(), 1U);
  const auto& m = std::get<core::ToolMeasurement>(ev[0]);
  EXPECT_EQ(m.tool, 3);
  ASSERT_EQ(m.point_count, 4);
  EXPECT_DOUBLE_EQ(m.wear_um[0], 1.0);
  EXPECT_DOUBLE_EQ(m.wear_um[1], 2.5);
  EXPECT_DOUBLE_EQ(m.wear_um[2], -0.5);
  EXPECT_DOUBLE_EQ(m.wear_um[3], 12.0);
}

TEST(ModbusDecoderProfile, CountOnlyOnTheWearProfileAndWithinLimits) {
  const auto err = [](const std::string& t) {
    try {
      (void)parse_modbus_config(t, "t.toml");
    } catch (const formats::DiagnosticsError& e) {
      return std::string(e.what());
    }
    return std::string("(accepted)");
  };
  EXPECT_EQ(err(R"([modbus]
transport = "tcp"
[modbus.axis]
x_mm = { address = 0, count = 2 }
)"),
            "t.toml:4:31: modbus.axis.x_mm.count: unknown key");
  EXPECT_EQ(
      err(R"([modbus]
transport = "tcp"
[modbus.tool_measurement]
sequence = { address = 0, type = "uint16" }
tool = { address = 1 }
wear_um = { address = 2, count = 33 }
)"),
      "t.toml:6:34: modbus.tool_measurement.wear_um.count: must be an integer in [1, 32], got 33");
  // The profile's registers are claimed: a signal inside it overlaps.
  EXPECT_EQ(err(R"([modbus]
transport = "tcp"
[modbus.tool_measurement]
sequence = { address = 0, type = "uint16" }
tool = { address = 1 }
wear_um = { address = 2, type = "float32", count = 3 }
broken = { address = 7 }
)"),
            "t.toml:7: modbus.tool_measurement.broken: holding address 7 overlaps "
            "modbus.tool_measurement.wear_um (line 6)");
}

}  // namespace
// Issue 17, finding 4: a measurement whose value arrives NaN, ±inf or beyond the map's range is
// not lost in silence. GIVEN a laser (float32 wear), a probe (float32 deviation, within ±500 µm)
// and a touch probe (float32 trigger position), WHEN each publishes a bad value with its counter
// advanced, THEN each measurement comes out exactly once, marked faulted (kInvalid for NaN / inf,
// kOutOfRange beyond min / max), with every value field 0 and its identity (tool, checkpoint,
// axis) as received, counted once; a good value next is an ordinary measurement again.
TEST(ModbusDecoderFault, BadMeasuredValuesAreDeliveredOnceAsFaultedMeasurements) {
  const ModbusConfig c = parse_modbus_config(R"([modbus]
transport = "tcp"
[modbus.tool_measurement]
sequence = { address = 0, type = "uint16" }
tool = { address = 1 }
wear_um = { address = 2, type = "float32" }
[modbus.probe_measurement]
sequence = { address = 4, type = "uint16" }
part = { address = 5 }
checkpoint = { address = 6 }
raw_deviation_um = { address = 7, type = "float32", min = -500, max = 500 }
wall_angle_deg = { address = 9, type = "int16", scale = 0.1 }
ball_radius_mm = { address = 10, type = "uint16", scale = 0.001 }
[modbus.calibration_touch]
sequence = { address = 11, type = "uint16" }
axis = { address = 12 }
direction = { address = 13, type = "int16" }
trigger_position_mm = { address = 14, type = "float32" }
)",
                                             "t.toml");
  ASSERT_EQ(c.blocks.size(), 1U);  // holding 0..15: one request
  PollDecoder dec(c);
  std::vector<std::uint8_t> ok(1, 1);
  auto b = dec.block(0);
  b[1] = 7;      // tool 7
  b[5] = 42;     // part 42
  b[6] = 3;      // checkpoint 3
  b[10] = 2000;  // r 2 mm
  b[12] = 1;     // axis Y
  b[13] = static_cast<std::uint16_t>(-1 & 0xFFFF);
  dec.decode(1, ok);  // baselines
  const auto only = [](std::span<const core::Event> ev) {
    EXPECT_EQ(ev.size(), 1U);
    return ev.empty() ? core::Event{} : ev[0];
  };
  const float inf = std::numeric_limits<float>::infinity();
  std::uint16_t seq = 0;
  for (const float bad : {std::nanf(""), inf, -inf}) {
    ++seq;
    b[0] = seq;
    put_float(b, 2, bad, false);
    const core::Event e = only(dec.decode(10 + seq, ok));
    const auto& m = std::get<core::ToolMeasurement>(e);
    EXPECT_EQ(m.fault, core::InputFault::kInvalid) << bad;
    EXPECT_EQ(m.tool, 7);
    EXPECT_EQ(m.wear_um[0], 0.0);
    EXPECT_EQ(m.time_ns, 10 + seq);
    EXPECT_EQ(dec.counters().values_invalid, seq);
    EXPECT_TRUE(dec.decode(20 + seq, ok).empty()) << "read again";
  }
  b[0] = ++seq;
  put_float(b, 2, 12.5F, false);
  auto m = std::get<core::ToolMeasurement>(only(dec.decode(30, ok)));
  EXPECT_EQ(m.fault, core::InputFault::kNone);
  EXPECT_EQ(m.wear_um[0], 12.5);

  // The probe: 800 µm is beyond max = 500, NaN is invalid.
  b[4] = 1;
  put_float(b, 7, 800.0F, false);
  auto p = std::get<core::ProbeMeasurement>(only(dec.decode(31, ok)));
  EXPECT_EQ(p.fault, core::InputFault::kOutOfRange);
  EXPECT_EQ(p.checkpoint, 3);
  EXPECT_EQ(p.part, 42);
  EXPECT_EQ(p.raw_deviation_um, 0.0);
  EXPECT_EQ(p.ball_radius_mm, 0.0);
  EXPECT_EQ(dec.counters().values_out_of_range, 1U);
  b[4] = 2;
  put_float(b, 7, std::nanf(""), false);
  p = std::get<core::ProbeMeasurement>(only(dec.decode(32, ok)));
  EXPECT_EQ(p.fault, core::InputFault::kInvalid);
  EXPECT_EQ(dec.counters().values_invalid, 4U);
  // The touch: +inf trigger position.
  b[11] = 1;
  put_float(b, 14, inf, false);
  auto t = std::get<core::CalibrationTouch>(only(dec.decode(34, ok)));
  EXPECT_EQ(t.fault, core::InputFault::kInvalid);
  EXPECT_EQ(t.axis, 1);
  EXPECT_EQ(t.direction, -1);
  EXPECT_EQ(t.trigger_position_mm, 0.0);
  EXPECT_EQ(dec.counters().values_invalid, 5U);
  EXPECT_EQ(dec.counters().values_out_of_range, 1U);
  // Faulted or not, decoding allocates nothing.
  b[11] = 2;
  const nccomp::test::AllocationScope scope;
  const auto ev = dec.decode(35, ok);
  EXPECT_EQ(scope.count(), 0U);
  ASSERT_EQ(ev.size(), 1U);
  EXPECT_EQ(std::get<core::CalibrationTouch>(ev[0]).fault, core::InputFault::kInvalid);
}

TEST(ModbusDecoderFault, AFractionalNumberIsInvalidNotRoundedToANeighbour) {
  // GIVEN a checkpoint number in a float32 register and a tool number in counts of 0.5 (a map
  // with a wrong scale, or an NC that writes garbage)
  const ModbusConfig c = parse_modbus_config(R"([modbus]
transport = "tcp"
[modbus.probe_measurement]
sequence = { address = 0, type = "uint16" }
checkpoint = { address = 1, type = "float32" }
raw_deviation_um = { address = 3, type = "float32" }
[modbus.tool_change]
sequence = { address = 5, type = "uint16" }
tool = { address = 6, type = "uint16", scale = 0.5 }
)",
                                             "t.toml");
  PollDecoder dec(c);
  std::vector<std::uint8_t> ok(c.blocks.size(), 1);
  auto b = dec.block(0);
  dec.decode(1, ok);  // baselines
  // WHEN checkpoint 3 and tool 14 * 0.5 = 7 arrive THEN both are taken
  b[0] = 1;
  put_float(b, 1, 3.0F, false);
  put_float(b, 3, 12.0F, false);
  b[5] = 1;
  b[6] = 14;
  auto ev = dec.decode(2, ok);
  ASSERT_EQ(ev.size(), 2U);
  const auto& p = std::get<core::ProbeMeasurement>(ev[0]);
  EXPECT_EQ(p.fault, core::InputFault::kNone);
  EXPECT_EQ(p.checkpoint, 3);
  EXPECT_EQ(std::get<core::ToolChange>(ev[1]).tool, 7);
  // WHEN checkpoint 3.25 and tool 15 * 0.5 = 7.5 arrive THEN neither is rounded to checkpoint 3
  // or tool 8: the probe reading is delivered faulted without a checkpoint, the tool change is
  // dropped, both counted invalid
  b[0] = 2;
  put_float(b, 1, 3.25F, false);
  b[5] = 2;
  b[6] = 15;
  ev = dec.decode(3, ok);
  ASSERT_EQ(ev.size(), 1U);
  const auto& q = std::get<core::ProbeMeasurement>(ev[0]);
  EXPECT_EQ(q.fault, core::InputFault::kInvalid);
  EXPECT_EQ(q.checkpoint, -1);
  EXPECT_EQ(dec.counters().values_invalid, 2U);
}

}  // namespace nccomp::drivers::modbus
