// The driver against an independent peer: pymodbus' server (python3-pymodbus 3.0), over TCP and
// over RTU on a pseudo-terminal pair. The peer's register values are set on its command line and,
// for events, written by the test's own libmodbus client.
#include <gtest/gtest.h>
#include <modbus/modbus.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "tests/hil/modbus/hil_common.hpp"

namespace nccomp::test::modbus {
namespace {

// ir 0..1 = int32 -250000 (0xFFFC2F70) * 0.0001 = -25 mm; ir 2..3 = float32 12.75 (0x414C0000)
// low word first; ir 4 = int16 swapped bytes 0x0C00 -> 12 = tool; co 3 = cutting.
const char* const kInit = "ir=0:65532,1:12144,2:0,3:16716,4:3072;co=3:1";

const char* const kMap = R"(
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int32", scale = 0.0001 }
y_mm = { table = "input", address = 2, type = "float32", word_order = "low_first" }
tool = { table = "input", address = 4, type = "int16", byte_order = "swapped" }
cutting = { table = "coil", address = 3 }
[modbus.tool_change]
sequence = { table = "holding", address = 10, type = "uint32" }
tool = { table = "holding", address = 12, type = "uint16" }
sister = { table = "holding", address = 13, type = "uint16" }
[[modbus.offset]]
register_index = 0
address = 100
type = "int32"
scale = 0.1
[[modbus.offset]]
register_index = 1
address = 102
type = "float32"
byte_order = "swapped"
)";

std::uint16_t start_tcp_peer(PeerProcess& p, std::uint16_t port = 0) {
  const std::string line =
      p.start({"/usr/bin/python3", NCCOMP_MODBUS_PEER, "tcp", std::to_string(port), kInit});
  if (line.rfind("PORT ", 0) != 0) {
    ADD_FAILURE() << "pymodbus peer did not start: '" << line << "'";
    return 0;
  }
  return static_cast<std::uint16_t>(std::stoi(line.substr(5)));
}

/// The test's own client, playing the NC's PLC program that writes event registers.
class Client {
 public:
  explicit Client(std::uint16_t port) : ctx_(modbus_new_tcp("127.0.0.1", port)) {
    if (modbus_connect(ctx_) != 0) {
      ADD_FAILURE() << "client connect: " << modbus_strerror(errno);
    }
  }
  ~Client() {
    modbus_close(ctx_);
    modbus_free(ctx_);
  }
  Client(const Client&) = delete;
  Client& operator=(const Client&) = delete;
  void write(int address, std::vector<std::uint16_t> v) {
    ASSERT_EQ(modbus_write_registers(ctx_, address, static_cast<int>(v.size()), v.data()),
              static_cast<int>(v.size()));
  }
  std::vector<std::uint16_t> read(int address, int n) {
    std::vector<std::uint16_t> v(static_cast<std::size_t>(n));
    EXPECT_EQ(modbus_read_registers(ctx_, address, n, v.data()), n);
    return v;
  }

 private:
  modbus_t* ctx_;
};

TEST(ModbusHilPymodbus, TcpValuesEventsOffsetsAndPeerKilledMidRun) {
  PeerProcess peer;
  const std::uint16_t port = start_tcp_peer(peer);
  ASSERT_NE(port, 0);
  auto bus = make_bus(tcp_header(port, "verify_writes = true") + kMap);
  bus->start();
  Collected got;
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return got.axis.size() >= 2;
  }));
  const core::AxisSample& s = got.axis.back();
  EXPECT_NEAR(s.position_mm[0], -25.0, 1e-12);
  EXPECT_DOUBLE_EQ(s.position_mm[1], 12.75);
  EXPECT_EQ(s.tool, 12);
  EXPECT_TRUE(s.cutting);

  {
    Client nc(port);
    // A tool change: values and the uint32 counter (0 -> 65536: across the word boundary) in one
    // function-16 request, as an NC program would write them.
    nc.write(10, {0x0001, 0x0000, 17, 1});
    ASSERT_TRUE(wait_until([&] {
      got.drain(*bus);
      return got.tool_changes.size() == 1;
    }));
    EXPECT_EQ(got.tool_changes[0].tool, 17);
    EXPECT_TRUE(got.tool_changes[0].sister);
    EXPECT_EQ(bus->modbus_status().events_lost, 65535U);  // 0 -> 65536 is a jump of 65536

    push_offset(*bus, 0, -3.4);
    push_offset(*bus, 1, 0.5);  // 0x3F000000 with swapped bytes: 0x003F 0x0000
    ASSERT_TRUE(wait_until([&] {
      const auto st = bus->modbus_status();
      return st.offsets_pending == 0 && st.bus.counters.offsets_written >= 2;
    }));
    const auto r = nc.read(100, 4);
    EXPECT_EQ(r[0], 0xFFFF);
    EXPECT_EQ(r[1], static_cast<std::uint16_t>(-34 & 0xFFFF));
    EXPECT_EQ(r[2], 0x003F);
    EXPECT_EQ(r[3], 0x0000);
  }

  // Kill the peer (SIGKILL: no FIN handshake logic of its own) and restart it with fresh,
  // zeroed holding registers: the driver must reconnect and write the offsets again.
  const std::uint64_t written = bus->status().counters.offsets_written;
  peer.kill_now();
  ASSERT_TRUE(wait_until([&] { return bus->status().state == drivers::LinkState::kDown; }));
  PeerProcess peer2;
  ASSERT_EQ(start_tcp_peer(peer2, port), port);
  ASSERT_TRUE(wait_until([&] { return bus->status().state == drivers::LinkState::kUp; }));
  ASSERT_TRUE(wait_until([&] { return bus->status().counters.offsets_written >= written + 2; }));
  Client nc2(port);
  const auto r = nc2.read(100, 4);
  EXPECT_EQ(r[1], static_cast<std::uint16_t>(-34 & 0xFFFF));
  EXPECT_EQ(r[2], 0x003F);
  EXPECT_GE(bus->status().counters.reconnects, 1U);
  bus->stop();
}

TEST(ModbusHilPymodbus, RtuOverPtyPair) {
  PtyPair pty;
  PeerProcess peer;
  ASSERT_EQ(peer.start({"/usr/bin/python3", NCCOMP_MODBUS_PEER, "rtu", pty.b(), kInit}), "READY");
  // Address 2000 is beyond the peer's 1024 registers: an illegal-address exception each poll.
  auto bus = make_bus(rtu_header(pty.a(), "verify_writes = true") + kMap + R"(
[[modbus.temperature]]
sensor = 0
table = "input"
address = 2000
)");
  bus->start();
  Collected got;
  ASSERT_TRUE(wait_until(
      [&] {
        got.drain(*bus);
        return got.axis.size() >= 2;
      },
      10.0));
  EXPECT_NEAR(got.axis.back().position_mm[0], -25.0, 1e-12);
  EXPECT_DOUBLE_EQ(got.axis.back().position_mm[1], 12.75);
  EXPECT_EQ(got.axis.back().tool, 12);
  push_offset(*bus, 0, 8.8);
  ASSERT_TRUE(wait_until(
      [&] {
        const auto st = bus->modbus_status();
        return st.offsets_pending == 0 && st.bus.counters.offsets_written >= 1;
      },
      10.0));
  const auto st = bus->modbus_status();
  EXPECT_GE(st.exceptions[2], 1U);
  EXPECT_EQ(st.verify_mismatches, 0U);  // read back from pymodbus equal to what was written
  EXPECT_EQ(st.bus.counters.reconnects, 0U);
  bus->stop();
}

// Every remaining register type and encoding, and bad values, from the independent server:
// discrete inputs, uint16 and uint32 (values that would be negative as signed), a NaN float and
// an absurd but finite float (beyond the map's max) written into the peer mid-run, an
// out-of-range integer, and offsets that are not representable.
// ir 10 = Y uint16 65000 * 0.001 = 65 mm (int16 would be -0.536); ir 11..12 = Z uint32
// 3000000000 (0xB2D05E00) * 1e-6 = 3000 mm (int32 would be negative); di 5 = cutting; hr 20..21 =
// float32 12.5 (0x41480000); hr 22 = tool 3.
const char* const kTypesInit = "ir=10:65000,11:45776,12:24064;di=5:1;hr=20:16712,21:0,22:3";

const char* const kTypesMap = R"(
[modbus.axis]
x_mm = { table = "holding", address = 20, type = "float32", min = -1000, max = 1000 }
tool = { table = "holding", address = 22, type = "int16" }
y_mm = { table = "input", address = 10, type = "uint16", scale = 0.001 }
z_mm = { table = "input", address = 11, type = "uint32", scale = 0.000001 }
cutting = { table = "discrete_input", address = 5 }
[[modbus.offset]]
register_index = 0
address = 100
type = "int16"
)";

TEST(ModbusHilPymodbus, TcpUnsignedDiscreteInputsNaNAndOutOfRangeValues) {
  PeerProcess peer;
  const std::string line =
      peer.start({"/usr/bin/python3", NCCOMP_MODBUS_PEER, "tcp", "0", kTypesInit});
  ASSERT_EQ(line.rfind("PORT ", 0), 0U) << line;
  const auto port = static_cast<std::uint16_t>(std::stoi(line.substr(5)));
  auto bus = make_bus(tcp_header(port) + kTypesMap);
  bus->start();
  Collected got;
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return got.axis.size() >= 2;
  }));
  const core::AxisSample s = got.axis.back();
  EXPECT_DOUBLE_EQ(s.position_mm[0], 12.5);
  EXPECT_NEAR(s.position_mm[1], 65.0, 1e-9);
  EXPECT_NEAR(s.position_mm[2], 3000.0, 1e-6);
  EXPECT_EQ(s.tool, 3);
  EXPECT_TRUE(s.cutting);
  EXPECT_EQ(bus->modbus_status().values_invalid, 0U);

  Client nc(port);
  // Once the counter moved, the bad value is what every poll reads: three more polls count it
  // and deliver no sample.
  const auto expect_counted = [&](auto counter, const char* what) {
    const std::uint64_t before = counter(bus->modbus_status());
    ASSERT_TRUE(wait_until([&] { return counter(bus->modbus_status()) > before; })) << what;
    got.drain(*bus);
    const std::size_t n = got.axis.size();
    const std::uint64_t now = counter(bus->modbus_status());
    ASSERT_TRUE(wait_until([&] { return counter(bus->modbus_status()) >= now + 3; })) << what;
    got.drain(*bus);
    EXPECT_EQ(got.axis.size(), n) << what << ": samples kept coming";
  };
  // NaN (0x7FC00000) in X: dropped, counted invalid.
  nc.write(20, {0x7FC0, 0x0000});
  expect_counted([](const mb::ModbusStatus& st) { return st.values_invalid; }, "NaN");
  // 1e30 mm (0x7149F2CA): finite, beyond max = 1000: dropped, counted out of range.
  nc.write(20, {0x7149, 0xF2CA});
  expect_counted([](const mb::ModbusStatus& st) { return st.values_out_of_range; }, "1e30");
  // A negative tool number: not a valid tool, counted invalid.
  nc.write(20, {0x4148, 0x0000});
  nc.write(22, {0xFFFD});
  expect_counted([](const mb::ModbusStatus& st) { return st.values_invalid; }, "tool -3");
  // Plausible again: samples come back, with the values the peer holds now.
  nc.write(22, {4});
  const std::size_t n = got.axis.size();
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return got.axis.size() >= n + 3;
  }));
  for (const auto& a : got.axis) {
    ASSERT_TRUE(std::isfinite(a.position_mm[0]));
    ASSERT_LE(std::fabs(a.position_mm[0]), 1000.0);
    ASSERT_GE(a.tool, 0);
  }
  EXPECT_EQ(got.axis.back().tool, 4);

  // Offsets the int16 register cannot hold: refused, never clamped; the peer keeps its value.
  push_offset(*bus, 0, 12.0);
  ASSERT_TRUE(wait_until([&] { return nc.read(100, 1)[0] == 12; }));
  push_offset(*bus, 0, core::kNaN);
  push_offset(*bus, 0, 40000.0);  // the latest wins: 40000 does not fit int16
  ASSERT_TRUE(wait_until([&] { return bus->modbus_status().offsets_rejected >= 1; }));
  EXPECT_TRUE(bus->status().alarm);
  EXPECT_EQ(nc.read(100, 1)[0], 12);
  push_offset(*bus, 0, -7.0);
  ASSERT_TRUE(wait_until([&] { return nc.read(100, 1)[0] == 0xFFF9; }));
  ASSERT_TRUE(wait_until([&] { return !bus->status().alarm; }));
  EXPECT_EQ(bus->modbus_status().bus.counters.reconnects, 0U);
  bus->stop();
}

/// The peer's holding registers from its SIGUSR1 dump file.
std::vector<std::uint16_t> dumped_holding(PeerProcess& peer, const std::string& path) {
  std::remove(path.c_str());
  peer.signal(SIGUSR1);
  std::string text;
  wait_until([&] {
    std::ifstream in(path);
    return static_cast<bool>(std::getline(in, text)) && text.rfind("hr ", 0) == 0;
  });
  std::vector<std::uint16_t> v;
  std::stringstream s(text.size() > 3 ? text.substr(3) : "");
  std::string item;
  while (std::getline(s, item, ',')) {
    v.push_back(static_cast<std::uint16_t>(std::stoul(item)));
  }
  return v;
}

TEST(ModbusHilPymodbus, RtuPeerKilledAndRestartedGetsEveryOffsetAgain) {
  PtyPair pty;
  const std::string dump =
      ::testing::TempDir() + "pymodbus_rtu_dump_" + std::to_string(::getpid()) + ".txt";
  PeerProcess peer;
  ASSERT_EQ(peer.start({"/usr/bin/python3", NCCOMP_MODBUS_PEER, "rtu", pty.b(), kInit, dump}),
            "READY");
  auto bus = make_bus(rtu_header(pty.a(), "verify_writes = true") + kMap);
  bus->start();
  Collected got;
  ASSERT_TRUE(wait_until(
      [&] {
        got.drain(*bus);
        return got.axis.size() >= 2;
      },
      10.0));
  EXPECT_NEAR(got.axis.back().position_mm[0], -25.0, 1e-12);
  push_offset(*bus, 0, -3.4);  // int32 0.1 µm: -34
  push_offset(*bus, 1, 0.5);   // float32 swapped bytes: 0x003F 0x0000
  ASSERT_TRUE(wait_until(
      [&] {
        const auto st = bus->modbus_status();
        return st.offsets_pending == 0 && st.bus.counters.offsets_written >= 2;
      },
      10.0));
  auto hr = dumped_holding(peer, dump);
  ASSERT_GE(hr.size(), 104U);
  EXPECT_EQ(hr[100], 0xFFFF);
  EXPECT_EQ(hr[101], static_cast<std::uint16_t>(-34 & 0xFFFF));
  EXPECT_EQ(hr[102], 0x003F);
  EXPECT_EQ(hr[103], 0x0000);

  // The peer dies (SIGKILL): silence on the line. The driver times out, declares the line dead
  // after dead_after_failures and reopens it; meanwhile the loop moves offset 0 on.
  const std::uint64_t written = bus->status().counters.offsets_written;
  peer.kill_now();
  ASSERT_TRUE(wait_until(
      [&] {
        const auto st = bus->modbus_status();
        return st.timeouts >= 3 && st.bus.counters.reconnects >= 1;
      },
      10.0));
  push_offset(*bus, 0, 7.7);
  ASSERT_TRUE(wait_until([&] { return bus->status().alarm; }, 10.0));
  EXPECT_EQ(bus->modbus_status().offsets_pending, 2U);  // both: re-marked by the reconnect

  // A new peer with zeroed holding registers and X moved to +25 mm (0x0003D090 * 0.0001).
  PeerProcess peer2;
  ASSERT_EQ(peer2.start({"/usr/bin/python3", NCCOMP_MODBUS_PEER, "rtu", pty.b(),
                         "ir=0:3,1:53392,2:0,3:16716,4:3072;co=3:1", dump}),
            "READY");
  ASSERT_TRUE(wait_until(
      [&] {
        got.drain(*bus);
        const auto st = bus->modbus_status();
        return st.offsets_pending == 0 && !got.axis.empty() &&
               std::fabs(got.axis.back().position_mm[0] - 25.0) < 1e-9;
      },
      10.0));
  ASSERT_TRUE(wait_until([&] { return !bus->status().alarm; }, 10.0));
  const auto st = bus->modbus_status();
  // Both offsets written again (the unchanged one too: the new peer had lost it), read back
  // equal by the driver and, here, seen in the peer's own table.
  EXPECT_GE(st.bus.counters.offsets_written, written + 2);
  EXPECT_EQ(st.verify_mismatches, 0U);
  hr = dumped_holding(peer2, dump);
  ASSERT_GE(hr.size(), 104U);
  EXPECT_EQ(hr[100], 0x0000);
  EXPECT_EQ(hr[101], 77);
  EXPECT_EQ(hr[102], 0x003F);
  EXPECT_EQ(hr[103], 0x0000);
  bus->stop();
  std::remove(dump.c_str());
}

}  // namespace
}  // namespace nccomp::test::modbus
