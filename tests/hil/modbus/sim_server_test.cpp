// The driver against the project's libmodbus NC server (sim/modbus_nc) on loopback TCP and on
// a pseudo-terminal pair (RTU).
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <limits>
#include <string_view>
#include <thread>

#include "sim/modbus_nc/nc_server.hpp"
#include "tests/hil/modbus/hil_common.hpp"

namespace nccomp::test::modbus {
namespace {

using sim::modbus_nc::NcServer;
using sim::modbus_nc::ServerConfig;
using sim::modbus_nc::Tables;

const char* const kEveryEncoding = R"(
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int32", scale = 0.0001 }
y_mm = { table = "holding", address = 0, type = "float32", word_order = "low_first", byte_order = "swapped" }
z_mm = { table = "input", address = 2, type = "int16", scale = 0.01, offset = 100 }
a_deg = { table = "input", address = 3, type = "uint16", byte_order = "swapped" }
b_deg = { table = "input", address = 4, type = "uint32", word_order = "low_first" }
c_deg = { table = "input", address = 6, type = "float32" }
tool = { table = "holding", address = 2, type = "uint16" }
cutting = { table = "coil", address = 5 }
[[modbus.temperature]]
sensor = 3
table = "discrete_input"
address = 7
)";

void fill_every_encoding(Tables& t) {
  t.input[0] = 0xFFED;  // -1234567 * 0.0001 = -123.4567 mm
  t.input[1] = 0x2979;
  t.holding[0] = 0x0000;  // 2.5f = 0x40200000, low word first, bytes swapped
  t.holding[1] = 0x2040;
  t.input[2] = 0xFE0C;  // -500 * 0.01 + 100 = 95 mm
  t.input[3] = 0x2C01;  // 300 with swapped bytes
  t.input[4] = 0x1170;  // 70000 = 0x00011170, low word first
  t.input[5] = 0x0001;
  t.input[6] = 0xBF00;  // -0.5f
  t.input[7] = 0x0000;
  t.holding[2] = 12;
  t.coils[5] = 1;
  t.discrete_inputs[7] = 1;
}

TEST(ModbusHilSim, EveryRegisterTypeAndEncodingOverTcp) {
  NcServer server(ServerConfig{});
  server.update(fill_every_encoding);
  server.start();
  auto bus = make_bus(tcp_header(server.port()) + kEveryEncoding);
  bus->start();
  Collected got;
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return got.axis.size() >= 3 && !got.temperatures.empty();
  }));
  const core::AxisSample& s = got.axis.back();
  EXPECT_EQ(s.axis_count, 6);
  EXPECT_NEAR(s.position_mm[0], -123.4567, 1e-9);
  EXPECT_DOUBLE_EQ(s.position_mm[1], 2.5);
  EXPECT_NEAR(s.position_mm[2], 95.0, 1e-12);
  EXPECT_DOUBLE_EQ(s.position_mm[3], 300.0);
  EXPECT_DOUBLE_EQ(s.position_mm[4], 70000.0);
  EXPECT_DOUBLE_EQ(s.position_mm[5], -0.5);
  EXPECT_EQ(s.tool, 12);
  EXPECT_TRUE(s.cutting);
  EXPECT_EQ(got.temperatures[0].sensor, 3);
  EXPECT_DOUBLE_EQ(got.temperatures[0].temperature_c, 1.0);
  // WHEN the coil drops THEN the next samples say so.
  server.update([](Tables& t) { t.coils[5] = 0; });
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return !got.axis.back().cutting;
  }));
  // WHEN the NC publishes NaN for Y (float32 0x7FC00000) THEN no sample carries it: dropped and
  // counted; a finite value again brings the samples back.
  server.update([](Tables& t) {
    t.holding[0] = 0x0000;
    t.holding[1] = 0xC07F;  // low word first, bytes swapped
  });
  ASSERT_TRUE(wait_until([&] { return bus->modbus_status().values_invalid >= 3; }));
  server.update(fill_every_encoding);
  const std::size_t n = got.axis.size();
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return got.axis.size() > n + 2;
  }));
  for (const auto& a : got.axis) {
    ASSERT_TRUE(std::isfinite(a.position_mm[1]));
  }
  bus->stop();
  const mb::ModbusStatus st = bus->modbus_status();
  EXPECT_EQ(st.bus.state, drivers::LinkState::kStopped);
  EXPECT_EQ(st.bus.counters.faults, 0U);
  EXPECT_EQ(st.bus.counters.events_dropped, 0U);
  EXPECT_GE(st.bus.counters.frames_rx, 3U * 4U);  // 4 read requests per poll
}

const char* const kEventsAndOffsets = R"(
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int32", scale = 0.001 }
[modbus.tool_measurement]
sequence = { table = "holding", address = 100, type = "uint16" }
tool = { table = "holding", address = 101, type = "uint16" }
wear_um = { table = "holding", address = 102, type = "float32" }
broken = { table = "holding", address = 104, type = "uint16" }
[[modbus.offset]]
register_index = 0
address = 200
type = "int32"
scale = 0.1
[[modbus.offset]]
register_index = 1
address = 202
type = "float32"
word_order = "low_first"
[[modbus.offset]]
register_index = 2
address = 204
type = "int16"
)";

/// The NC side of a tool measurement: values first, then the counter, in one atomic update.
void nc_measure(NcServer& s, std::uint16_t tool, float wear_um, int increments = 1) {
  s.update([&](Tables& t) {
    std::uint32_t u = 0;
    std::memcpy(&u, &wear_um, 4);
    t.holding[101] = tool;
    t.holding[102] = static_cast<std::uint16_t>(u >> 16U);
    t.holding[103] = static_cast<std::uint16_t>(u & 0xFFFFU);
    t.holding[100] = static_cast<std::uint16_t>(t.holding[100] + increments);
  });
}

std::int32_t holding_i32(NcServer& s, std::uint16_t address) {
  const auto r = s.holding(address, 2);
  return static_cast<std::int32_t>((static_cast<std::uint32_t>(r[0]) << 16U) | r[1]);
}

TEST(ModbusHilSim, EventsExactlyOnceLostCountedOffsetsLatestWinsAcrossRestart) {
  NcServer server(ServerConfig{});
  server.update([](Tables& t) { t.holding[100] = 41; });  // an old event before the daemon
  server.start();
  auto bus = make_bus(tcp_header(server.port(), "verify_writes = true") + kEventsAndOffsets);
  bus->start();
  Collected got;
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return got.axis.size() >= 2;
  }));
  EXPECT_TRUE(got.tool_measurements.empty()) << "the counter found at start is a baseline";

  // One event: delivered once, with its own values.
  nc_measure(server, 5, 12.5F);
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return !got.tool_measurements.empty();
  }));
  const std::size_t axis_before = got.axis.size();
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return got.axis.size() > axis_before + 10;  // many polls later ...
  }));
  ASSERT_EQ(got.tool_measurements.size(), 1U);  // ... still exactly one
  EXPECT_EQ(got.tool_measurements[0].tool, 5);
  EXPECT_DOUBLE_EQ(got.tool_measurements[0].wear_um[0], 12.5);

  // Three events between two polls: the latest is delivered, two are counted lost.
  nc_measure(server, 6, 20.0F, 3);
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return got.tool_measurements.size() == 2;
  }));
  EXPECT_EQ(got.tool_measurements[1].tool, 6);
  EXPECT_EQ(bus->modbus_status().events_lost, 2U);

  // Offsets: the latest value per register wins; verified by read-back.
  push_offset(*bus, 0, 12.3);
  push_offset(*bus, 0, 15.0);
  push_offset(*bus, 1, -7.25);
  ASSERT_TRUE(wait_until(
      [&] { return holding_i32(server, 200) == 150 && server.holding(202, 2)[1] == 0xC0E8; }));
  const auto f = server.holding(202, 2);
  EXPECT_EQ(f[0], 0x0000);  // -7.25f = 0xC0E80000, low word first
  EXPECT_EQ(f[1], 0xC0E8);

  // NaN and out-of-range are refused (never clamped) and raise the alarm; the NC keeps its value.
  push_offset(*bus, 1, core::kNaN);
  push_offset(*bus, 2, 40000.0);  // int16
  push_offset(*bus, 9, 1.0);      // no such register
  ASSERT_TRUE(wait_until([&] { return bus->modbus_status().offsets_rejected == 3; }));
  EXPECT_TRUE(bus->status().alarm);
  EXPECT_EQ(server.holding(202, 2)[1], 0xC0E8);
  EXPECT_EQ(server.holding(204, 1)[0], 0);
  push_offset(*bus, 1, 1.5);
  push_offset(*bus, 2, -3.0);
  ASSERT_TRUE(wait_until([&] { return !bus->status().alarm; }));
  EXPECT_EQ(server.holding(204, 1)[0], 0xFFFD);

  // The NC restarts: while it is down the loop moves the offset on, the NC produces 2 events.
  const std::uint64_t written_before = bus->status().counters.offsets_written;
  server.stop();
  ASSERT_TRUE(wait_until([&] { return bus->status().state == drivers::LinkState::kDown; }));
  push_offset(*bus, 0, 20.0);
  nc_measure(server, 7, 30.0F, 2);
  ASSERT_TRUE(wait_until([&] { return bus->status().alarm; }));  // link down > alarm_after_s
  server.start();
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return holding_i32(server, 200) == 200 && got.tool_measurements.size() == 3;
  }));
  ASSERT_TRUE(wait_until([&] { return bus->modbus_status().offsets_pending == 0; }));
  const mb::ModbusStatus st = bus->modbus_status();
  EXPECT_GE(st.bus.counters.reconnects, 1U);
  EXPECT_EQ(st.events_lost, 3U);
  EXPECT_EQ(got.tool_measurements[2].tool, 7);
  // Every known offset was written again after the reconnect (absolute values).
  EXPECT_GE(st.bus.counters.offsets_written, written_before + 3);
  EXPECT_GE(st.bus.counters.offsets_retried, 3U);
  EXPECT_FALSE(st.bus.alarm);

  // Never an older value after a newer one: register 200 saw 150 (maybe 123 first), then 200.
  std::vector<std::int32_t> seq;
  for (const auto& w : server.writes()) {
    if (w.address == 200 && w.values.size() == 2) {
      seq.push_back(static_cast<std::int32_t>((std::uint32_t{w.values[0]} << 16U) | w.values[1]));
    }
  }
  ASSERT_FALSE(seq.empty());
  EXPECT_TRUE(std::is_sorted(seq.begin(), seq.end()));
  EXPECT_EQ(seq.back(), 200);
  bus->stop();
}

/// The NC restarts (sim/modbus_nc keeps its registers across stop() / start(), so the test does
/// what a restarting NC does: its tool measurement group powers up at 0) and produces `events`
/// tool measurements (the newest: tool 8, 33 µm) before the driver is back. Returns once the
/// driver has reconnected and polled a few times since.
void restart_nc(NcServer& server, mb::ModbusBus& bus, int events) {
  const std::uint64_t reconnects = bus.status().counters.reconnects;
  server.stop();
  ASSERT_TRUE(wait_until([&] { return bus.status().state == drivers::LinkState::kDown; }));
  server.update([](Tables& t) { std::fill_n(t.holding.begin() + 100, 5, std::uint16_t{0}); });
  if (events > 0) {
    nc_measure(server, 8, 33.0F, events);
  }
  server.start();
  ASSERT_TRUE(wait_until([&] { return bus.status().counters.reconnects > reconnects; }));
  const std::uint64_t polls = bus.modbus_status().polls;
  ASSERT_TRUE(wait_until([&] { return bus.modbus_status().polls > polls + 10; }));
}

// GIVEN the driver polling an NC whose tool measurement counter is at 42, WHEN the NC restarts
// (counting again from 0) and has produced 3, then exactly 3 again, then no events by the time the
// driver is back, THEN: the newest of the 3 is delivered once and 2 are counted lost with a reset;
// an unchanged counter (3 -> 3) delivers nothing but is counted as a doubt the operator can see in
// the status; a counter back at 0 is a reset with nothing to deliver.
TEST(ModbusHilSim, NcRestartNewestEventDeliveredRestCountedUnchangedCounterShown) {
  NcServer server(ServerConfig{});
  server.update([](Tables& t) { t.holding[100] = 41; });
  server.start();
  auto bus = make_bus(tcp_header(server.port()) + kEventsAndOffsets);
  bus->start();
  Collected got;
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return got.axis.size() >= 2;
  }));
  nc_measure(server, 5, 12.5F);  // counter 42
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return got.tool_measurements.size() == 1;
  }));

  // 42 -> restart -> 3: the newest of the three is on the registers.
  ASSERT_NO_FATAL_FAILURE(restart_nc(server, *bus, 3));
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return got.tool_measurements.size() == 2;
  })) << "the event produced after the NC's restart was not delivered";
  EXPECT_EQ(got.tool_measurements[1].tool, 8);
  EXPECT_DOUBLE_EQ(got.tool_measurements[1].wear_um[0], 33.0);
  mb::ModbusStatus st = bus->modbus_status();
  EXPECT_EQ(st.sequence_resets, 1U);
  EXPECT_EQ(st.events_lost, 2U);
  EXPECT_EQ(st.sequence_unchanged_after_reconnect, 0U);

  // 3 -> restart -> 3: indistinguishable from no restart; nothing delivered, the doubt counted.
  ASSERT_NO_FATAL_FAILURE(restart_nc(server, *bus, 3));
  got.drain(*bus);
  EXPECT_EQ(got.tool_measurements.size(), 2U);
  st = bus->modbus_status();
  EXPECT_EQ(st.sequence_unchanged_after_reconnect, 1U);
  EXPECT_EQ(st.sequence_resets, 1U);
  EXPECT_EQ(st.events_lost, 2U);

  // 3 -> restart -> 0: a reset, no event to deliver, nothing lost; the next one comes through.
  ASSERT_NO_FATAL_FAILURE(restart_nc(server, *bus, 0));
  got.drain(*bus);
  EXPECT_EQ(got.tool_measurements.size(), 2U);
  st = bus->modbus_status();
  EXPECT_EQ(st.sequence_resets, 2U);
  EXPECT_EQ(st.events_lost, 2U);
  EXPECT_EQ(st.sequence_unchanged_after_reconnect, 1U);
  nc_measure(server, 9, 1.5F);
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return got.tool_measurements.size() == 3;
  }));
  EXPECT_EQ(got.tool_measurements[2].tool, 9);
  EXPECT_GE(bus->status().counters.reconnects, 3U);

  // The counters as nccomp status shows them (the driver's extra counters, by name).
  std::array<drivers::BusCounterValue, drivers::kMaxBusExtraCounters> c{};
  const std::size_t n = bus->extra_counters(c);
  const auto value_of = [&](std::string_view name) {
    for (std::size_t i = 0; i < n; ++i) {
      if (name == c[i].name) {
        return c[i].value;
      }
    }
    ADD_FAILURE() << name << " not among the counters";
    return std::uint64_t{0};
  };
  EXPECT_EQ(value_of("sequence_resets"), 2U);
  EXPECT_EQ(value_of("events_lost"), 2U);
  EXPECT_EQ(value_of("sequence_unchanged_after_reconnect"), 1U);
  bus->stop();
}

// Read-back verification: the NC acknowledges a write but does not hold the value (it rounded it,
// or silently ignored it). verify_writes reads every written offset back, counts the mismatch and
// writes the same absolute value again until the NC holds it.
TEST(ModbusHilSim, ReadBackMismatchIsCountedAndRewrittenUntilTheNcHoldsTheTarget) {
  NcServer server(ServerConfig{});
  std::atomic<int> writes_to_200{0};
  std::array<std::uint16_t, 2> held{};  // what the NC keeps when it ignores a write
  server.set_after_write([&](const sim::modbus_nc::WriteRecord& w, Tables& t) {
    if (w.address != 200) {
      return;
    }
    const int n = ++writes_to_200;
    if (n == 1) {
      t.holding[201] = static_cast<std::uint16_t>(t.holding[201] + 1);  // "rounded" by one count
      held = {t.holding[200], t.holding[201]};
    } else if (n == 2) {
      t.holding[200] = held[0];  // acknowledged, silently ignored
      t.holding[201] = held[1];
    }
  });
  server.start();
  auto bus = make_bus(tcp_header(server.port(), "verify_writes = true") + kEventsAndOffsets);
  bus->start();
  push_offset(*bus, 0, 15.0);  // int32 at 0.1 µm: 150 counts
  ASSERT_TRUE(wait_until([&] {
    return bus->modbus_status().offsets_pending == 0 && bus->status().counters.offsets_written == 1;
  }));
  const mb::ModbusStatus st = bus->modbus_status();
  EXPECT_EQ(st.verify_mismatches, 2U);
  EXPECT_EQ(holding_i32(server, 200), 150);
  // Three function-16 writes of the same absolute value: the target, never an accumulation.
  std::vector<std::int32_t> sent;
  for (const auto& w : server.writes()) {
    if (w.address == 200 && w.values.size() == 2) {
      sent.push_back(static_cast<std::int32_t>((std::uint32_t{w.values[0]} << 16U) | w.values[1]));
    }
  }
  EXPECT_EQ(sent, (std::vector<std::int32_t>{150, 150, 150}));
  EXPECT_EQ(st.bus.counters.offsets_retried, 2U);
  EXPECT_EQ(st.bus.counters.offsets_written, 1U);
  EXPECT_EQ(st.bus.counters.reconnects, 0U);
  EXPECT_FALSE(st.bus.alarm);
  // The mismatches are in the driver's status counters, as nccomp status shows them.
  std::array<drivers::BusCounterValue, drivers::kMaxBusExtraCounters> c{};
  const std::size_t n = bus->extra_counters(c);
  ASSERT_EQ(n, mb::kModbusCounterNames.size());
  const auto value_of = [&](std::string_view name) {
    for (std::size_t i = 0; i < n; ++i) {
      if (name == c[i].name) {
        return c[i].value;
      }
    }
    ADD_FAILURE() << name << " not among the counters";
    return std::uint64_t{0};
  };
  EXPECT_EQ(value_of("verify_mismatches"), 2U);
  EXPECT_EQ(value_of("offsets_pending"), 0U);
  bus->stop();
}

TEST(ModbusHilSim, AnNcThatNeverHoldsTheValueKeepsItPendingAndRaisesTheAlarm) {
  NcServer server(ServerConfig{});
  // The NC clamps register 204 (int16) to 100 counts: 250 never sticks, 80 does.
  server.set_after_write([](const sim::modbus_nc::WriteRecord& w, Tables& t) {
    if (w.address == 204 && static_cast<std::int16_t>(t.holding[204]) > 100) {
      t.holding[204] = 100;
    }
  });
  server.start();
  auto bus = make_bus(tcp_header(server.port(), "verify_writes = true") + kEventsAndOffsets);
  bus->start();
  push_offset(*bus, 2, 250.0);
  ASSERT_TRUE(wait_until([&] {
    const auto st = bus->modbus_status();
    return st.verify_mismatches >= 5 && st.bus.alarm;
  }));
  EXPECT_EQ(bus->modbus_status().offsets_pending, 1U);
  EXPECT_EQ(server.holding(204, 1)[0], 100);
  // A value the NC accepts: verified, the alarm clears, the counter stops.
  push_offset(*bus, 2, 80.0);
  ASSERT_TRUE(wait_until([&] { return !bus->status().alarm && server.holding(204, 1)[0] == 80; }));
  const std::uint64_t mismatches = bus->modbus_status().verify_mismatches;
  std::this_thread::sleep_for(std::chrono::milliseconds(100));  // 20 more polls
  EXPECT_EQ(bus->modbus_status().verify_mismatches, mismatches);
  EXPECT_EQ(bus->modbus_status().offsets_pending, 0U);
  bus->stop();
}

TEST(ModbusHilSim, ServerThatStopsAnsweringIsDetectedAndOffsetsArriveAfterwards) {
  NcServer server(ServerConfig{});
  server.start();
  auto bus = make_bus(tcp_header(server.port()) + kEventsAndOffsets);
  bus->start();
  ASSERT_TRUE(wait_until([&] { return bus->status().state == drivers::LinkState::kUp; }));
  // A hung NC: the connection stays open, nothing is answered (a pulled cable looks the same).
  server.set_silent(true);
  push_offset(*bus, 0, 42.0);
  ASSERT_TRUE(wait_until([&] {
    const auto st = bus->modbus_status();
    return st.timeouts >= 3 && st.bus.counters.reconnects >= 1 && st.bus.alarm;
  }));
  EXPECT_EQ(bus->modbus_status().offsets_pending, 1U);
  server.set_silent(false);
  ASSERT_TRUE(wait_until([&] { return holding_i32(server, 200) == 420; }));
  ASSERT_TRUE(wait_until([&] { return !bus->status().alarm; }));
  EXPECT_EQ(bus->modbus_status().offsets_pending, 0U);
  bus->stop();
}

TEST(ModbusHilSim, ExceptionResponsesCountedPerKindOthersKeepFlowing) {
  using sim::modbus_nc::kExceptionBase;
  NcServer server(ServerConfig{});
  server.update([](Tables& t) { t.input[1] = 1000; });
  server.start();
  const std::string map = R"(
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int32", scale = 0.001 }
[modbus.tool_change]
sequence = { table = "holding", address = 65302, type = "uint16" }
tool = { table = "holding", address = 65303 }
[[modbus.temperature]]
sensor = 0
table = "input"
address = 65298
[[modbus.temperature]]
sensor = 1
table = "coil"
address = 65306
[[modbus.temperature]]
sensor = 2
table = "discrete_input"
address = 65307
[[modbus.offset]]
register_index = 0
address = 65299
)";
  static_assert(kExceptionBase + 2 == 65298 && kExceptionBase + 3 == 65299 &&
                kExceptionBase + 6 == 65302 && kExceptionBase + 10 == 65306);
  auto bus = make_bus(tcp_header(server.port()) + map);
  bus->start();
  push_offset(*bus, 0, 5.0);
  Collected got;
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    const auto st = bus->modbus_status();
    return got.axis.size() >= 5 && st.exceptions[2] >= 5 && st.exceptions[3] >= 2 &&
           st.exceptions[6] >= 5 && st.exceptions[10] >= 5 && st.exceptions[11] >= 5 &&
           st.bus.alarm;
  }));
  const auto st = bus->modbus_status();
  EXPECT_DOUBLE_EQ(got.axis.back().position_mm[0], 1.0);
  EXPECT_EQ(st.bus.counters.reconnects, 0U) << "an exception is an answer, not a dead link";
  EXPECT_EQ(st.timeouts, 0U);
  EXPECT_EQ(st.offsets_pending, 1U);  // illegal value: kept, retried, alarmed
  EXPECT_TRUE(got.temperatures.empty());
  EXPECT_TRUE(got.tool_changes.empty());
  bus->stop();
}

// Issue 17, finding 4. GIVEN the driver on the NC server with degraded_alarm_after_s = 0.5, up and
// decoding valid samples, WHEN the NC answers every read with exception 4 (server failure), THEN
// the link stays "degraded" (an exception is an answer: no reconnect, not down) and the driver
// raises input_stale; it clears once the NC answers again. WHEN the NC answers but publishes a
// NaN X position, THEN the link is up, the samples are counted invalid and the input is stale
// just the same; valid samples clear it. WHEN the laser's wear register holds +inf as its counter
// advances, THEN exactly one tool measurement comes out, faulted, its wear 0.
TEST(ModbusHilSim, ExceptionsOnEveryReadOrOnlyNaNPositionsMakeTheInputStale) {
  NcServer server(ServerConfig{});
  const auto put_x = [&](float x) {
    std::uint32_t bits = 0;
    std::memcpy(&bits, &x, sizeof bits);
    server.update([&](Tables& t) {
      t.input[0] = static_cast<std::uint16_t>(bits >> 16);
      t.input[1] = static_cast<std::uint16_t>(bits & 0xFFFF);
    });
  };
  put_x(12.5F);
  server.start();
  const std::string map = R"(
[modbus.axis]
x_mm = { table = "input", address = 0, type = "float32" }
[modbus.tool_measurement]
sequence = { table = "input", address = 10, type = "uint16" }
tool = { table = "input", address = 11 }
wear_um = { table = "input", address = 12, type = "float32" }
)";
  auto bus = make_bus(tcp_header(server.port(), "degraded_alarm_after_s = 0.5") + map);
  bus->start();
  Collected got;
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return got.axis.size() >= 5;
  }));
  EXPECT_FALSE(bus->status().input_stale);

  const auto t0 = std::chrono::steady_clock::now();
  server.set_read_exception(4);
  ASSERT_TRUE(wait_until([&] { return bus->status().input_stale; }));
  std::printf("every read answered with exception 4 -> input_stale after %.3f s (0.5 s set)\n",
              std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  auto st = bus->modbus_status();
  EXPECT_EQ(st.bus.state, drivers::LinkState::kDegraded);
  EXPECT_GE(st.exceptions[4], 5U);
  EXPECT_EQ(st.bus.counters.reconnects, 0U);
  EXPECT_FALSE(st.bus.alarm);  // offsets are not the question: nothing is pending
  server.set_read_exception(0);
  ASSERT_TRUE(wait_until([&] { return !bus->status().input_stale; }));
  EXPECT_EQ(bus->status().state, drivers::LinkState::kUp);

  put_x(std::nanf(""));
  ASSERT_TRUE(wait_until([&] { return bus->status().input_stale; }));
  st = bus->modbus_status();
  EXPECT_EQ(st.bus.state, drivers::LinkState::kUp);
  EXPECT_GE(st.values_invalid, 5U);
  put_x(7.0F);
  ASSERT_TRUE(wait_until([&] { return !bus->status().input_stale; }));

  got.drain(*bus);
  got.tool_measurements.clear();
  const float inf = std::numeric_limits<float>::infinity();
  std::uint32_t bits = 0;
  std::memcpy(&bits, &inf, sizeof bits);
  server.update([&](Tables& t) {
    t.input[11] = 3;
    t.input[12] = static_cast<std::uint16_t>(bits >> 16);
    t.input[13] = static_cast<std::uint16_t>(bits & 0xFFFF);
    t.input[10] = 1;
  });
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return !got.tool_measurements.empty();
  }));
  const std::uint64_t polls = bus->modbus_status().polls;
  ASSERT_TRUE(wait_until([&] { return bus->modbus_status().polls >= polls + 20; }));
  got.drain(*bus);
  ASSERT_EQ(got.tool_measurements.size(), 1U);
  EXPECT_EQ(got.tool_measurements[0].fault, core::InputFault::kInvalid);
  EXPECT_EQ(got.tool_measurements[0].tool, 3);
  EXPECT_EQ(got.tool_measurements[0].wear_um[0], 0.0);
  EXPECT_FALSE(bus->status().input_stale);
  bus->stop();
}

TEST(ModbusHilSim, LateAndWrongTransactionAnswersAreNeverTakenForData) {
  using sim::modbus_nc::kDelayAddress;
  using sim::modbus_nc::kWrongTidAddress;
  NcServer server(ServerConfig{});
  server.set_delay_ms(150);  // > response_timeout_s = 0.1
  server.update([](Tables& t) {
    t.input[1] = 777;
    t.input[kDelayAddress] = 9999;
    t.holding[kWrongTidAddress] = 8888;
  });
  server.start();
  const std::string map = R"(
dead_after_failures = 100
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int32" }
[[modbus.temperature]]
sensor = 0
table = "input"
address = 65280
[[modbus.temperature]]
sensor = 1
table = "holding"
address = 65312
)";
  auto bus = make_bus(tcp_header(server.port()) + map);
  bus->start();
  Collected got;
  // A single-threaded NC that needs 150 ms per delayed request falls behind for good, so the
  // delay is lifted once it has produced timeouts; its late answers are still in flight then.
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return bus->modbus_status().timeouts >= 2;
  }));
  server.set_delay_ms(0);
  const std::size_t before = got.axis.size();
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return got.axis.size() >= before + 5 && bus->modbus_status().bad_responses >= 3;
  })) << "timeouts "
      << bus->modbus_status().timeouts << " bad " << bus->modbus_status().bad_responses
      << " samples " << got.axis.size();
  bus->stop();
  got.drain(*bus);
  for (const auto& s : got.axis) {
    ASSERT_DOUBLE_EQ(s.position_mm[0], 777.0);  // never 9999 or 8888 from a stray answer
  }
  // Sensor 0 reads 9999 once its answers come in time; sensor 1 (wrong transaction id) never.
  for (const auto& t : got.temperatures) {
    EXPECT_EQ(t.sensor, 0) << "temperature " << t.temperature_c << " from a foreign answer";
    EXPECT_DOUBLE_EQ(t.temperature_c, 9999.0);
  }
}

TEST(ModbusHilSim, UnreachableNcBacksOffRaisesTheAlarmAndStopsPromptly) {
  // A port nobody listens on (the server is stopped right after binding it).
  std::uint16_t port = 0;
  {
    NcServer probe(ServerConfig{});
    probe.start();
    port = probe.port();
  }
  auto bus = make_bus(tcp_header(port) + kEventsAndOffsets);
  bus->start();
  push_offset(*bus, 0, 1.0);
  ASSERT_TRUE(wait_until([&] {
    const auto st = bus->modbus_status();
    return st.connection_errors >= 3 && st.bus.alarm;
  }));
  const auto st = bus->modbus_status();
  EXPECT_EQ(st.bus.state, drivers::LinkState::kConnecting);
  EXPECT_EQ(st.bus.counters.reconnects, 0U);
  EXPECT_EQ(st.polls, 0U);
  // Back-off: from 20 ms doubling to 100 ms, so about 10 attempts per second, not thousands.
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  EXPECT_LT(bus->modbus_status().connection_errors, 30U);
  const auto t0 = std::chrono::steady_clock::now();
  bus->stop();
  EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::milliseconds(300));
  // The NC appears: a new driver connects and delivers the offset the loop queued.
  NcServer server(ServerConfig{.port = port});
  server.start();
  auto bus2 = make_bus(tcp_header(port) + kEventsAndOffsets);
  bus2->start();
  push_offset(*bus2, 0, 1.0);
  ASSERT_TRUE(wait_until([&] { return holding_i32(server, 200) == 10; }));
  bus2->stop();
}

// Start-up read-back (S1 reconcile): before start() the daemon asks what the NC holds in its
// offset registers; the value comes back in µm through the map's encoding, and start() then
// runs the I/O thread on its own connection.
TEST(ModbusHilSim, OffsetsReadBackBeforeStartWithTheMapsEncoding) {
  NcServer server(ServerConfig{});
  server.update([](Tables& t) {
    t.holding[200] = 0xFFFF;  // int32 -1234 * 0.1 = -123.4 µm
    t.holding[201] = 0xFB2E;
    t.holding[202] = 0x0000;  // -7.25f = 0xC0E80000, low word first
    t.holding[203] = 0xC0E8;
    t.holding[204] = 42;  // int16, scale 1
  });
  server.start();
  auto bus = make_bus(tcp_header(server.port()) + kEventsAndOffsets);
  const auto r0 = bus->read_offset(0);
  const auto r1 = bus->read_offset(1);
  const auto r2 = bus->read_offset(2);
  ASSERT_TRUE(r0.has_value());
  ASSERT_TRUE(r1.has_value());
  ASSERT_TRUE(r2.has_value());
  EXPECT_NEAR(*r0, -123.4, 1e-9);
  EXPECT_DOUBLE_EQ(*r1, -7.25);
  EXPECT_DOUBLE_EQ(*r2, 42.0);
  EXPECT_FALSE(bus->read_offset(7).has_value()) << "register 7 is not mapped";
  // After start() the I/O thread owns the connection: no read-back from other threads.
  bus->start();
  EXPECT_FALSE(bus->read_offset(0).has_value());
  push_offset(*bus, 0, 15.0);
  ASSERT_TRUE(wait_until([&] { return holding_i32(server, 200) == 150; }));
  bus->stop();
}

TEST(ModbusHilSim, ReadBackFromAnUnreachableNcIsNulloptOnceAndStartStillWorks) {
  std::uint16_t port = 0;
  {
    NcServer probe(ServerConfig{});
    probe.start();
    port = probe.port();
  }
  auto bus = make_bus(tcp_header(port) + kEventsAndOffsets);
  EXPECT_FALSE(bus->read_offset(0).has_value());
  // A failed connect is not retried per register (a table of 100 checkpoints would wait 100
  // connect timeouts at start-up).
  EXPECT_FALSE(bus->read_offset(1).has_value());
  NcServer server(ServerConfig{.port = port});
  server.start();
  bus->start();
  push_offset(*bus, 0, 1.0);
  ASSERT_TRUE(wait_until([&] { return holding_i32(server, 200) == 10; }));
  bus->stop();
}

TEST(ModbusHilSim, Rs485ModeOnADeviceWithoutItIsAConnectionErrorNotACrash) {
  PtyPair pty;
  auto bus = make_bus(rtu_header(pty.a(), "rs485 = true") + R"(
[modbus.axis]
x_mm = { table = "input", address = 0 }
)");
  bus->start();
  // A pseudo-terminal has no TIOCSRS485: every connect attempt fails and is counted.
  ASSERT_TRUE(wait_until([&] { return bus->modbus_status().connection_errors >= 2; }));
  const auto st = bus->modbus_status();
  EXPECT_NE(st.last_errno, 0);
  EXPECT_EQ(st.polls, 0U);
  EXPECT_NE(st.bus.state, drivers::LinkState::kUp);
  bus->stop();
}

TEST(ModbusHilSim, RtuOverPtyPairWithFrameTiming) {
  PtyPair pty;
  ServerConfig sc;
  sc.rtu = true;
  sc.device = pty.b();
  sc.unit_id = 1;
  NcServer server(sc);
  server.update([](Tables& t) {
    t.input[0] = 0xFFFF;  // x = -1 * 0.001
    t.input[1] = 0xFFFF;
    t.holding[100] = 3;
  });
  server.start();
  using sim::modbus_nc::kExceptionBase;
  using sim::modbus_nc::kWrongTidAddress;
  const std::string map = std::string(kEventsAndOffsets) + R"(
[[modbus.temperature]]
sensor = 0
table = "input"
address = 65298
[[modbus.temperature]]
sensor = 1
table = "coil"
address = 65312
)";
  static_assert(kExceptionBase + 2 == 65298 && kWrongTidAddress == 65312);
  auto bus = make_bus(rtu_header(pty.a(), "verify_writes = true\ndead_after_failures = 100") + map);
  bus->start();
  Collected got;
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return got.axis.size() >= 2;
  }));
  EXPECT_NEAR(got.axis.back().position_mm[0], -0.001, 1e-12);
  nc_measure(server, 9, 4.0F);
  push_offset(*bus, 0, -1.2);
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return got.tool_measurements.size() == 1 && holding_i32(server, 200) == -12 &&
           bus->modbus_status().bus.counters.offsets_written >= 1;
  }));
  EXPECT_EQ(got.tool_measurements[0].tool, 9);
  const auto st = bus->modbus_status();
  EXPECT_GE(st.exceptions[2], 1U);
  EXPECT_GE(st.bad_responses, 1U);  // an answer from another unit id
  EXPECT_GE(st.bus.counters.offsets_written, 1U);
  // Line noise on answers: CRC errors counted, nothing garbled decoded, the poll goes on.
  pty.corrupt_next(3);
  const std::size_t n = got.axis.size();
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return bus->modbus_status().crc_errors >= 1 && got.axis.size() > n + 3;
  })) << "crc errors "
      << bus->modbus_status().crc_errors;
  for (const auto& a : got.axis) {
    ASSERT_NEAR(a.position_mm[0], -0.001, 1e-12);
  }
  bus->stop();
  EXPECT_TRUE(got.temperatures.empty());
}

}  // namespace
}  // namespace nccomp::test::modbus
