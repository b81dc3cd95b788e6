// The driver against an independent peer: pymodbus' server (python3-pymodbus 3.0), over TCP and
// over RTU on a pseudo-terminal pair. The peer's register values are set on its command line and,
// for events, written by the test's own libmodbus client.
#include <gtest/gtest.h>
#include <modbus/modbus.h>

#include <cstdint>
#include <string>

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

}  // namespace
}  // namespace nccomp::test::modbus
