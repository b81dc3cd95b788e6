// The driver against a raw TCP server that answers with truncated frames, wrong lengths and
// wrong transaction ids: the driver must count them, resynchronise and never decode garbage.
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstdint>
#include <vector>

#include "tests/hil/modbus/hil_common.hpp"

namespace nccomp::test::modbus {
namespace {

/// A function-4 answer for the request `req` carrying `regs`, with the MBAP header of `req`.
std::vector<std::uint8_t> answer(const std::vector<std::uint8_t>& req,
                                 const std::vector<std::uint16_t>& regs) {
  const auto n = static_cast<std::uint8_t>(2 * regs.size());
  std::vector<std::uint8_t> r{req[0], req[1], 0, 0, 0, static_cast<std::uint8_t>(3 + n),
                              req[6], req[7], n};
  for (std::uint16_t v : regs) {
    r.push_back(static_cast<std::uint8_t>(v >> 8U));
    r.push_back(static_cast<std::uint8_t>(v & 0xFFU));
  }
  return r;
}

TEST(ModbusHilRaw, TruncatedWrongLengthWrongTidAreCountedNeverDecoded) {
  std::atomic<int> n{0};
  RawTcpServer raw([&](const std::vector<std::uint8_t>& req) -> std::vector<std::uint8_t> {
    if (req.size() != 12 || req[7] != 4) {
      return {};
    }
    switch (n++) {
      case 0:  // a good answer: x = 1
        return answer(req, {0, 1});
      case 1: {  // truncated: header and half the data, then silence
        auto r = answer(req, {0, 99});
        r.resize(10);
        return r;
      }
      case 2:  // wrong length: three registers for a request of two
        return answer(req, {0, 98, 0});
      case 3: {  // wrong transaction id
        auto r = answer(req, {0, 97});
        r[1] = static_cast<std::uint8_t>(r[1] + 1);
        return r;
      }
      case 4: {  // wrong MBAP length field and a byte count that disagrees with it
        auto r = answer(req, {0, 96});
        r[5] = 200;
        r[8] = 2;
        return r;
      }
      default:  // good again: x = 2
        return answer(req, {0, 2});
    }
  });
  auto bus = make_bus(tcp_header(raw.port(), "dead_after_failures = 100") + R"(
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int32" }
)");
  bus->start();
  Collected got;
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return !got.axis.empty() && got.axis.back().position_mm[0] > 1.5 && got.axis.size() > 3;
  }));
  bus->stop();
  got.drain(*bus);
  for (const auto& s : got.axis) {
    const double x = s.position_mm[0];
    ASSERT_TRUE(std::fabs(x - 1.0) < 1e-12 || std::fabs(x - 2.0) < 1e-12)
        << "decoded garbage " << x;
  }
  const mb::ModbusStatus st = bus->modbus_status();
  EXPECT_GE(st.timeouts, 1U);       // the truncated frame
  EXPECT_GE(st.bad_responses, 2U);  // wrong length, wrong transaction id
  EXPECT_EQ(st.bus.counters.malformed, st.bad_responses + st.crc_errors);
  EXPECT_GE(raw.requests(), 6);
}

TEST(ModbusHilRaw, ConsecutiveGarbageDropsTheConnectionAndReconnects) {
  std::atomic<int> n{0};
  RawTcpServer raw([&](const std::vector<std::uint8_t>& req) -> std::vector<std::uint8_t> {
    if (req.size() != 12) {
      return {};
    }
    auto r = answer(req, {0, 5});
    if (n++ < 6) {
      r[0] = static_cast<std::uint8_t>(r[0] ^ 0x55U);  // wrong transaction id, again and again
    }
    return r;
  });
  auto bus = make_bus(tcp_header(raw.port(), "dead_after_failures = 3") + R"(
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int32" }
)");
  bus->start();
  Collected got;
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return !got.axis.empty();
  }));
  bus->stop();
  const mb::ModbusStatus st = bus->modbus_status();
  EXPECT_GE(st.bus.counters.reconnects, 1U);
  EXPECT_GE(st.bad_responses, 6U);
  EXPECT_DOUBLE_EQ(got.axis.front().position_mm[0], 5.0);
}

}  // namespace
}  // namespace nccomp::test::modbus
