// RTU frame timing on the wire: the pty pair's relay time-stamps every chunk between the driver
// (a) and the project's RTU server (b). A pty has no baud rate, so what is checked is what the
// driver enforces: before every request the line was silent for at least the 3.5-character
// frame gap of the configured line (1.75 ms above 19200 baud), and function-16 offset writes
// never come faster than offset_write_rate_hz, although the loop queues a new value every 5 ms.
//
// Why the relay's stamps give a sound lower bound: the relay reads the last byte of an answer
// before the driver can receive it (so the driver's end of frame is later), and it reads a
// request after the driver sent it (so the request's start is earlier). The measured silence is
// therefore at most the silence the driver kept; scheduling delays only lengthen it.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <string>
#include <thread>
#include <vector>

#include "sim/modbus_nc/nc_server.hpp"
#include "tests/hil/modbus/hil_common.hpp"

namespace nccomp::test::modbus {
namespace {

using sim::modbus_nc::NcServer;
using sim::modbus_nc::ServerConfig;
using sim::modbus_nc::Tables;

/// A request reassembled from the a→b byte stream: when its first byte was on the wire, how long
/// the line had been silent before (in either direction), and its function code.
struct WireRequest {
  std::int64_t start_ns{0};
  std::int64_t silence_ns{-1};  // -1: the first chunk of the recording
  std::uint8_t function{0};
  std::size_t length{0};
};

/// Splits the driver's bytes into RTU request frames (lengths from the function code: 8 bytes
/// for functions 1-6, 9 + byte count for 15 / 16). Fails the test on anything else.
std::vector<WireRequest> requests_on_the_wire(const std::vector<WireChunk>& chunks) {
  std::vector<WireRequest> out;
  std::vector<std::uint8_t> pending;  // bytes of the request being assembled
  std::int64_t previous_chunk_ns = -1;
  // The recording may start inside a request: frames are counted from the first answer on.
  bool synced = false;
  for (const WireChunk& c : chunks) {
    synced = synced || !c.from_a;
    if (c.from_a && synced) {
      for (std::size_t i = 0; i < c.bytes.size(); ++i) {
        if (pending.empty()) {
          // A request starts in this chunk: the silence before it ends with the previous chunk
          // seen on the line, or with this chunk's own earlier bytes (no silence at all).
          WireRequest r;
          r.start_ns = c.t_ns;
          r.silence_ns = i > 0 ? 0 : (previous_chunk_ns < 0 ? -1 : c.t_ns - previous_chunk_ns);
          out.push_back(r);
        }
        pending.push_back(c.bytes[i]);
        std::size_t want = 0;
        if (pending.size() >= 2) {
          const std::uint8_t fc = pending[1];
          if (fc >= 1 && fc <= 6) {
            want = 8;
          } else if (fc == 15 || fc == 16) {
            want = pending.size() >= 7 ? 9U + pending[6] : 0U;
          } else {
            ADD_FAILURE() << "unexpected function code " << int{fc} << " from the driver";
            return out;
          }
        }
        if (want != 0 && pending.size() == want) {
          out.back().function = pending[1];
          out.back().length = want;
          pending.clear();
        }
      }
    }
    previous_chunk_ns = c.t_ns;
  }
  if (!out.empty() && out.back().length == 0) {
    out.pop_back();  // cut off by the end of the recording
  }
  return out;
}

struct Line {
  const char* name;
  int baud;
  const char* parity;
  double poll_hz;
  double write_hz;  // 0: derived from the bus budget
  bool exception_block;
};

void check_line(const Line& line) {
  SCOPED_TRACE(line.name);
  PtyPair pty;
  ServerConfig sc;
  sc.rtu = true;
  sc.device = pty.b();
  NcServer server(sc);
  server.update([](Tables& t) {
    t.input[0] = 0x0001;  // x = 65536 * 0.001 = 65.536 mm
    t.input[1] = 0x0000;
  });
  server.start();
  std::string top = "[modbus]\ntransport = \"rtu\"\ndevice = \"" + pty.a() +
                    "\"\nbaud = " + std::to_string(line.baud) + "\nparity = \"" + line.parity +
                    "\"\npoll_rate_hz = " + std::to_string(line.poll_hz) +
                    "\nresponse_timeout_s = 0.2\nbyte_timeout_s = 0.05\n"
                    "reconnect_min_s = 0.02\nreconnect_max_s = 0.1\n";
  if (line.write_hz > 0.0) {
    top += "offset_write_rate_hz = " + std::to_string(line.write_hz) + "\n";
  }
  std::string map = R"(
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int32", scale = 0.001 }
[[modbus.offset]]
register_index = 0
address = 200
type = "int32"
scale = 0.1
)";
  if (line.exception_block) {
    // Exception 2 every poll: short exception answers are frames too.
    map += "[[modbus.temperature]]\nsensor = 0\ntable = \"input\"\naddress = 65298\n";
  }
  auto bus = make_bus(top + map);
  const mb::ModbusConfig& cfg = bus->config();
  const double gap_s = mb::rtu_frame_gap_s(cfg);
  const double cap_hz = cfg.offset_write_rate_hz;
  ASSERT_LT(cap_hz, line.poll_hz) << "the cap must bind: otherwise writes follow the polls";
  bus->start();
  Collected got;
  ASSERT_TRUE(wait_until([&] {
    got.drain(*bus);
    return got.axis.size() >= 2;
  }));
  pty.record(true);
  // The loop: a new absolute offset every 5 ms for 3 s (latest wins in the driver).
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(3);
  int k = 0;
  while (std::chrono::steady_clock::now() < end) {
    (void)bus->tx().try_push(core::OffsetWrite{0, 0, 0.1 * ++k});
    got.drain(*bus);
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  pty.record(false);
  bus->stop();
  const std::vector<WireRequest> reqs = requests_on_the_wire(pty.recorded());

  // Every request after the first had at least the frame gap of silence before it.
  std::int64_t min_silence_ns = INT64_MAX;
  std::size_t checked = 0;
  for (const WireRequest& r : reqs) {
    if (r.silence_ns < 0) {
      continue;
    }
    ++checked;
    min_silence_ns = std::min(min_silence_ns, r.silence_ns);
    EXPECT_GE(static_cast<double>(r.silence_ns) * 1e-9, gap_s)
        << "function " << int{r.function} << " after " << r.silence_ns << " ns of silence";
  }
  ASSERT_GE(checked, 20U) << "too few requests recorded to say anything";
  std::printf("[%s] %zu requests, shortest silence before one %.3f ms (frame gap %.3f ms)\n",
              line.name, checked, static_cast<double>(min_silence_ns) * 1e-6, gap_s * 1e3);

  // Function-16 writes: never more than the cap allows. The driver schedules write cycles on a
  // grid of 1 / cap without bursting to catch up, so n writes span at least (n - 2) periods.
  std::vector<std::int64_t> writes;
  for (const WireRequest& r : reqs) {
    if (r.function == 16) {
      writes.push_back(r.start_ns);
    }
  }
  ASSERT_GE(writes.size(), 5U) << "the offsets must actually be written";
  const double span_s = static_cast<double>(writes.back() - writes.front()) * 1e-9;
  const double rate_hz = static_cast<double>(writes.size() - 1) / span_s;
  std::printf("[%s] %zu offset writes in %.3f s: %.2f Hz (cap %.2f Hz, polls %.0f Hz)\n", line.name,
              writes.size(), span_s, rate_hz, cap_hz, line.poll_hz);
  EXPECT_LE(static_cast<double>(writes.size()), span_s * cap_hz + 2.0)
      << writes.size() << " writes in " << span_s << " s at a cap of " << cap_hz << " Hz";
  const auto st = bus->modbus_status();
  EXPECT_EQ(st.timeouts, 0U);
  EXPECT_EQ(st.crc_errors, 0U);
  EXPECT_EQ(st.bus.counters.reconnects, 0U);
  EXPECT_EQ(st.exceptions[2] > 0, line.exception_block);
}

TEST(ModbusHilRtuWire, FrameGapAndWriteCapAt115200BaudExplicitCap) {
  // 1.75 ms gap (above 19200 baud); exception answers in between; an explicit 5 Hz cap.
  check_line({"115200 8N1", 115200, "none", 50.0, 5.0, true});
}

TEST(ModbusHilRtuWire, FrameGapAndWriteCapAt9600BaudDerivedCap) {
  // 3.5 characters of 11 bits at 9600 baud = 4.01 ms; the write cap derived from the bus time
  // the 20 Hz polls leave (about 10.9 Hz).
  check_line({"9600 8E1", 9600, "even", 20.0, 0.0, false});
}

}  // namespace
}  // namespace nccomp::test::modbus
