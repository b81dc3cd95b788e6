// Unit tests of the CAN signal codec, the mapping validation and the TOML parser (no sockets).
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <limits>
#include <sstream>
#include <string>

#include "drivers/can/can_bus.hpp"
#include "drivers/can/can_config.hpp"
#include "drivers/can/can_mapping.hpp"
#include "drivers/input_watch.hpp"
#include "tests/support/alloc_counter.hpp"

namespace nccomp::drivers::can {
namespace {

std::string reference_path() {
  return std::string(NCCOMP_SOURCE_DIR) + "/config/reference-nc-can.toml";
}

// The error message of parsing text, or "" if it parsed.
std::string parse_error(const std::string& text) {
  try {
    (void)parse_can_config(text, "test.toml");
  } catch (const formats::DiagnosticsError& e) {
    return e.what();
  }
  return "";
}

const std::string kHead = "[can]\ninterface = \"vcan0\"\n";

TEST(CanCodec, LittleEndianSixteenBitsLandLowByteFirst) {
  // GIVEN a 16-bit Intel signal at bit 8 WHEN 0x1234 is inserted THEN bytes 1,2 = 34 12.
  SignalLayout l{8, 16, ByteOrder::kLittleEndian, ValueType::kUnsigned, 1.0, 0.0};
  std::array<std::uint8_t, 4> d{};
  insert_raw(l, 0x1234, d);
  EXPECT_EQ(d[0], 0x00);
  EXPECT_EQ(d[1], 0x34);
  EXPECT_EQ(d[2], 0x12);
  EXPECT_EQ(d[3], 0x00);
  EXPECT_EQ(extract_raw(l, d), 0x1234U);
}

TEST(CanCodec, BigEndianMotorolaStartBitIsTheMsb) {
  // DBC Motorola: start bit 7 = MSB of byte 0, 16 bits → byte 0 is the high byte.
  SignalLayout l{7, 16, ByteOrder::kBigEndian, ValueType::kUnsigned, 1.0, 0.0};
  std::array<std::uint8_t, 8> d{};
  insert_raw(l, 0x1234, d);
  EXPECT_EQ(d[0], 0x12);
  EXPECT_EQ(d[1], 0x34);
  EXPECT_EQ(extract_raw(l, d), 0x1234U);
  // A 12-bit Motorola signal starting mid-byte: bit 3 of byte 0 down, then byte 1.
  SignalLayout m{3, 12, ByteOrder::kBigEndian, ValueType::kUnsigned, 1.0, 0.0};
  std::array<std::uint8_t, 8> e{};
  insert_raw(m, 0xABC, e);
  EXPECT_EQ(e[0], 0x0A);
  EXPECT_EQ(e[1], 0xBC);
  EXPECT_EQ(extract_raw(m, e), 0xABCU);
}

TEST(CanCodec, SignedValuesAreSignExtendedAndScaled) {
  SignalLayout l{0, 12, ByteOrder::kLittleEndian, ValueType::kSigned, 0.5, 10.0};
  EXPECT_DOUBLE_EQ(raw_to_physical(l, 0xFFF), -1.0 * 0.5 + 10.0);
  EXPECT_DOUBLE_EQ(raw_to_physical(l, 0x800), -2048.0 * 0.5 + 10.0);
  EXPECT_DOUBLE_EQ(raw_to_physical(l, 0x7FF), 2047.0 * 0.5 + 10.0);
  EXPECT_EQ(physical_to_raw(l, 9.5).value(), 0xFFFU);
  EXPECT_FALSE(physical_to_raw(l, 2048.0 * 0.5 + 10.0).has_value());  // one past the max
  EXPECT_TRUE(physical_to_raw(l, -2048.0 * 0.5 + 10.0).has_value());
  EXPECT_FALSE(physical_to_raw(l, -2049.0 * 0.5 + 10.0).has_value());
}

TEST(CanCodec, UnsignedRangeAndNonFiniteRefused) {
  SignalLayout l{0, 8, ByteOrder::kLittleEndian, ValueType::kUnsigned, 1.0, 0.0};
  EXPECT_EQ(physical_to_raw(l, 255.0).value(), 255U);
  EXPECT_FALSE(physical_to_raw(l, 256.0).has_value());
  EXPECT_FALSE(physical_to_raw(l, -1.0).has_value());
  EXPECT_FALSE(physical_to_raw(l, core::kNaN).has_value());
  EXPECT_FALSE(physical_to_raw(l, std::numeric_limits<double>::infinity()).has_value());
}

TEST(CanCodec, Float32RoundTripsAndNaNDecodesAsNaN) {
  SignalLayout l{0, 32, ByteOrder::kLittleEndian, ValueType::kFloat, 1.0, 0.0};
  const auto raw = physical_to_raw(l, -12.25);
  ASSERT_TRUE(raw.has_value());
  EXPECT_EQ(*raw, std::bit_cast<std::uint32_t>(-12.25F));
  EXPECT_DOUBLE_EQ(raw_to_physical(l, *raw), -12.25);
  EXPECT_TRUE(std::isnan(raw_to_physical(l, 0x7FC00000U)));
}

TEST(CanCodec, OverflowingLayoutHasNoPositions) {
  std::array<std::uint16_t, 64> pos{};
  EXPECT_EQ(
      signal_bit_positions({60, 8, ByteOrder::kLittleEndian, ValueType::kUnsigned, 1, 0}, 64, pos),
      0U);
  EXPECT_EQ(
      signal_bit_positions({56, 8, ByteOrder::kLittleEndian, ValueType::kUnsigned, 1, 0}, 64, pos),
      8U);
  // Motorola from bit 56 (byte 7's LSB) with 2 bits walks to byte 8: overflow in 8 bytes.
  EXPECT_EQ(
      signal_bit_positions({56, 2, ByteOrder::kBigEndian, ValueType::kUnsigned, 1, 0}, 64, pos),
      0U);
}

TEST(CanConfig, ReferenceProfileParses) {
  const CanConfig c = load_can_config(reference_path());
  EXPECT_EQ(c.interface, "vcan0");
  EXPECT_EQ(c.mapping.rx.size(), 11U);
  EXPECT_EQ(c.mapping.offsets.size(), 4U);
  EXPECT_EQ(c.mapping.axis_count, 3);
  EXPECT_DOUBLE_EQ(c.ack_timeout_s, 0.05);
  EXPECT_EQ(c.ack_retries, 3U);
  ASSERT_TRUE(c.mapping.offsets[0].ack.has_value());
  EXPECT_EQ(c.mapping.offsets[0].ack->id, 0x380U);
  EXPECT_FALSE(c.mapping.offsets[3].ack.has_value());
}

TEST(CanConfig, AlarmAfterSecondsParsedDefaultedAndRangeChecked) {
  EXPECT_DOUBLE_EQ(load_can_config(reference_path()).alarm_after_s, 1.0);
  EXPECT_DOUBLE_EQ(parse_can_config(kHead, "test.toml").alarm_after_s, 1.0);  // default
  EXPECT_DOUBLE_EQ(parse_can_config(kHead + "alarm_after_s = 0.25\n", "test.toml").alarm_after_s,
                   0.25);
  const std::string e = parse_error(kHead + "alarm_after_s = -1\n");
  EXPECT_NE(e.find("test.toml:3:17: can.alarm_after_s: must be a number in [0, 3600], got -1"),
            std::string::npos)
      << e;
}

// The recovery back-off's cap and reset time: 5 s and max(10 s, cap) by default; a reset time
// below the cap is refused with its key.
TEST(CanConfig, ReconnectBackOffKeysParsedDefaultedAndChecked) {
  const CanConfig d = parse_can_config(kHead, "test.toml");
  EXPECT_DOUBLE_EQ(d.reconnect_max_s, 5.0);
  EXPECT_DOUBLE_EQ(d.reconnect_reset_after_s, 10.0);
  const CanConfig c =
      parse_can_config(kHead + "reconnect_max_s = 2\nreconnect_reset_after_s = 4\n", "test.toml");
  EXPECT_DOUBLE_EQ(c.reconnect_max_s, 2.0);
  EXPECT_DOUBLE_EQ(c.reconnect_reset_after_s, 4.0);
  EXPECT_DOUBLE_EQ(
      parse_can_config(kHead + "reconnect_max_s = 30\n", "test.toml").reconnect_reset_after_s,
      30.0);
  const std::string e = parse_error(kHead + "reconnect_max_s = 30\nreconnect_reset_after_s = 20\n");
  EXPECT_NE(e.find("test.toml:4:27: can.reconnect_reset_after_s: smaller than reconnect_max_s"),
            std::string::npos)
      << e;
}

TEST(CanConfig, DegradedAlarmAfterSecondsParsedDefaultedAndRangeChecked) {
  EXPECT_DOUBLE_EQ(load_can_config(reference_path()).degraded_alarm_after_s, 5.0);
  EXPECT_DOUBLE_EQ(parse_can_config(kHead, "test.toml").degraded_alarm_after_s, 5.0);
  EXPECT_DOUBLE_EQ(parse_can_config(kHead + "degraded_alarm_after_s = 0.5\n", "test.toml")
                       .degraded_alarm_after_s,
                   0.5);
  const std::string e = parse_error(kHead + "degraded_alarm_after_s = 0\n");
  EXPECT_NE(
      e.find("test.toml:3:26: can.degraded_alarm_after_s: must be a number in [0.01, 3600], got 0"),
      std::string::npos)
      << e;
}

// The stale-input rule both drivers use (drivers/input_watch.hpp), after 2 s. GIVEN a watch
// started at 0, WHEN the link stays healthy but no valid axis sample comes (all NaN), THEN the
// input is stale after 2 s, not before; WHEN samples come again it is not; WHEN the link stays
// degraded (never healthy) while samples keep coming, THEN it is stale again after 2 s; without
// axis signals in the map only the link counts; start() grants a fresh 2 s.
TEST(InputWatch, StaleAfterTheDegradedTimeWithoutAHealthyLinkOrAValidAxisSample) {
  constexpr core::TimeNs kS = 1'000'000'000;
  InputWatch w(2 * kS, true);
  w.start(0);
  for (core::TimeNs t = 0; t <= 2 * kS; t += kS / 10) {
    w.link_ok(t);
    EXPECT_FALSE(w.stale(t)) << t;
  }
  w.link_ok(2 * kS + 1);
  EXPECT_TRUE(w.stale(2 * kS + 1));
  w.axis_ok(3 * kS);
  w.link_ok(3 * kS);
  EXPECT_FALSE(w.stale(3 * kS));
  w.axis_ok(5 * kS);
  EXPECT_FALSE(w.stale(5 * kS));
  w.axis_ok(5 * kS + 1);
  EXPECT_TRUE(w.stale(5 * kS + 1));  // the link last healthy at 3 s
  InputWatch no_axis(2 * kS, false);
  no_axis.start(0);
  no_axis.link_ok(10 * kS);
  EXPECT_FALSE(no_axis.stale(11 * kS));
  EXPECT_TRUE(no_axis.stale(12 * kS + 1));
  no_axis.start(20 * kS);
  EXPECT_FALSE(no_axis.stale(22 * kS));
}

TEST(CanConfig, FdReferenceMapParses) {
  // The CAN FD example (the HIL test decodes its 32-byte axis frame on an MTU-72 vcan0).
  const CanConfig c =
      load_can_config(std::string(NCCOMP_SOURCE_DIR) + "/config/reference-nc-can-fd.toml");
  EXPECT_TRUE(c.mapping.fd);
  ASSERT_EQ(c.mapping.rx.size(), 2U);
  EXPECT_EQ(c.mapping.rx[0].id, 0x100U);
  EXPECT_EQ(c.mapping.rx[0].length_bytes, 32);
  EXPECT_EQ(c.mapping.rx[0].signals.size(), 9U);
  EXPECT_EQ(c.mapping.rx[1].length_bytes, 4);  // a classic frame on the same FD socket
  ASSERT_EQ(c.mapping.offsets.size(), 1U);
  EXPECT_EQ(c.mapping.offsets[0].length_bytes, 12);
}

TEST(CanConfig, OverlapRefusedWithKeyPathAndLine) {
  const std::string text =
      kHead +
      "[[can.rx]]\nid = 0x10\nevent = \"tool_change\"\n"
      "[[can.rx.signal]]\nname = \"tool\"\nstart_bit = 0\nlength_bits = 16\n"
      "[[can.rx.signal]]\nname = \"sister\"\nstart_bit = 15\nlength_bits = 1\n";
  const std::string e = parse_error(text);
  EXPECT_NE(e.find("test.toml:12:13: can.rx[0].signal[1].start_bit: overlaps another signal"),
            std::string::npos)
      << e;
}

TEST(CanConfig, FrameOverflowRefused) {
  const std::string text = kHead +
                           "[[can.rx]]\nid = 0x10\nlength_bytes = 2\nevent = \"tool_change\"\n"
                           "[[can.rx.signal]]\nname = \"tool\"\nstart_bit = 8\nlength_bits = 16\n";
  const std::string e = parse_error(text);
  EXPECT_NE(e.find("can.rx[0].signal[0].start_bit: signal (start_bit 8, length_bits 16) "
                   "overflows the 2-byte frame"),
            std::string::npos)
      << e;
}

TEST(CanConfig, UnknownSignalNameRefusedListingKnownOnes) {
  const std::string text = kHead +
                           "[[can.rx]]\nid = 0x10\nevent = \"tool_change\"\n"
                           "[[can.rx.signal]]\nname = \"tool_number\"\nstart_bit = 0\n"
                           "length_bits = 16\n";
  const std::string e = parse_error(text);
  EXPECT_NE(e.find("test.toml:7:8: can.rx[0].signal[0].name: unknown signal 'tool_number' for "
                   "event tool_change (known: tool, sister)"),
            std::string::npos)
      << e;
}

TEST(CanConfig, UnknownKeyRefused) {
  const std::string e = parse_error(kHead + "ack_timout_s = 0.1\n");
  EXPECT_NE(e.find("test.toml:3:16: can.ack_timout_s: unknown key"), std::string::npos) << e;
}

TEST(CanConfig, DuplicateIdsAndRegistersRefused) {
  const std::string frame =
      "[[can.rx]]\nid = 0x10\nevent = \"temperature\"\n"
      "[[can.rx.signal]]\nname = \"sensor\"\nstart_bit = 0\nlength_bits = 8\n";
  const std::string frame2 =
      "[[can.rx]]\nid = 0x10\nevent = \"tool_change\"\n"
      "[[can.rx.signal]]\nname = \"tool\"\nstart_bit = 0\nlength_bits = 8\n";
  EXPECT_NE(parse_error(kHead + frame + frame2).find("can.rx[1].id: frame ID 0x10 is mapped twice"),
            std::string::npos);
  const std::string off =
      "[[can.offset]]\nregister = 0\nid = 0x10\n[can.offset.value]\n"
      "start_bit = 0\nlength_bits = 32\ntype = \"signed\"\n";
  EXPECT_NE(
      parse_error(kHead + frame + off).find("can.offset[0].id: frame ID 0x10 is already used"),
      std::string::npos);
}

TEST(CanConfig, FdLengthsNeedFdAndValidLengths) {
  const std::string frame =
      "[[can.rx]]\nid = 0x10\nlength_bytes = 12\nevent = \"temperature\"\n"
      "[[can.rx.signal]]\nname = \"sensor\"\nstart_bit = 0\nlength_bits = 8\n";
  EXPECT_NE(parse_error(kHead + frame).find("can.rx[0].length_bytes: 12 exceeds 8 bytes"),
            std::string::npos);
  EXPECT_EQ(parse_error(kHead + "fd = true\n" + frame), "");
  std::string bad = frame;
  bad.replace(bad.find("12"), 2, "10");
  EXPECT_NE(parse_error(kHead + "fd = true\n" + bad).find("10 is not a CAN FD payload length"),
            std::string::npos);
}

TEST(CanConfig, BadValuesNameTheirKey) {
  EXPECT_NE(parse_error("[can]\n").find("test.toml:1:1: can.interface: missing required key"),
            std::string::npos);
  EXPECT_NE(parse_error(kHead + "rx_ring_events = 1000\n")
                .find("can.rx_ring_events: must be a power of two"),
            std::string::npos);
  EXPECT_NE(parse_error(kHead + "restart = \"never\"\n").find("can.restart: must be"),
            std::string::npos);
  EXPECT_NE(
      parse_error(kHead + "[[can.rx]]\nid = 0x800\nevent = \"temperature\"\n"
                          "[[can.rx.signal]]\nname = \"sensor\"\nstart_bit = 0\nlength_bits = 8\n")
          .find("can.rx[0].id: 0x800 exceeds the 11-bit ID range"),
      std::string::npos);
  EXPECT_NE(parse_error(kHead + "[[can.rx]]\nid = 1\nevent = \"spindle\"\n")
                .find("can.rx[0].event: must be one of \"axis_sample\", \"tool_measurement\", "
                      "\"probe_measurement\", \"calibration_touch\", \"tool_change\", "
                      "\"program_event\", \"temperature\", got \"spindle\""),
            std::string::npos);
  EXPECT_NE(parse_error("[can\n").find("test.toml:1:"), std::string::npos);
  EXPECT_NE(parse_error(kHead + "[[can.rx]]\nid = 1\nevent = \"temperature\"\n"
                                "[[can.rx.signal]]\nname = \"temperature_c\"\nstart_bit = 0\n"
                                "length_bits = 16\ntype = \"float\"\n")
                .find("a float signal is 32 or 64 bits"),
            std::string::npos);
}

// GIVEN a map with mistakes of every kind (a value out of range, a bad choice inside a frame, an
// unknown key, two signals sharing a bit, a standard ID beyond 11 bits), WHEN it is read, THEN
// each is reported at its key's file:line:column, not only the first.
TEST(CanConfig, EveryErrorOfAMapIsReportedNotOnlyTheFirst) {
  const std::string text =
      "[can]\ninterface = \"vcan0\"\nack_retries = 200\nack_timout_s = 0.1\n"
      "[[can.rx]]\nid = 0x10\nevent = \"tool_change\"\n"
      "[[can.rx.signal]]\nname = \"tool\"\nstart_bit = 0\nlength_bits = 16\ntype = \"int\"\n"
      "[[can.rx]]\nid = 0x20\nevent = \"temperature\"\n"
      "[[can.rx.signal]]\nname = \"sensor\"\nstart_bit = 0\nlength_bits = 8\n"
      "[[can.rx.signal]]\nname = \"temperature_c\"\nstart_bit = 4\nlength_bits = 16\n"
      "[[can.offset]]\nregister = 0\nid = 0x900\n"
      "[can.offset.value]\nstart_bit = 0\nlength_bits = 32\ntype = \"signed\"\n";
  try {
    (void)parse_can_config(text, "t.toml");
    FAIL() << "accepted";
  } catch (const formats::DiagnosticsError& e) {
    EXPECT_EQ(std::string(e.what()),
              "t.toml:3:15: can.ack_retries: must be an integer in [0, 100], got 200\n"
              "t.toml:12:8: can.rx[0].signal[0].type: must be one of \"unsigned\", \"signed\", "
              "\"float\", got \"int\"\n"
              "t.toml:4:16: can.ack_timout_s: unknown key\n"
              "t.toml:22:13: can.rx[1].signal[1].start_bit: overlaps another signal of the frame "
              "at bit 4\n"
              "t.toml:26:6: can.offset[0].id: 0x900 exceeds the 11-bit ID range (max 0x7FF)");
  }
  const toml::table root = toml::parse(std::string_view(text), std::string_view("t.toml"));
  formats::Diagnostics diag;
  EXPECT_FALSE(read_can_table(*root["can"].as_table(), "t.toml", diag));
  ASSERT_EQ(diag.items().size(), 5U) << diag.to_string();
  EXPECT_EQ(diag.items()[3].where.key_path, "can.rx[1].signal[1].start_bit");
  EXPECT_EQ(diag.items()[3].where.file, "t.toml");
  EXPECT_EQ(diag.items()[3].where.line, 22);
  EXPECT_EQ(diag.items()[3].where.column, 13);
}

// GIVEN a map built in code (no TOML positions), WHEN it is validated, THEN every problem is
// reported with the element's own place and the key path below it.
TEST(CanConfig, ValidatingAMapBuiltInCodeReportsEveryProblemAtItsElement) {
  CanMapping m;
  m.file = "built.toml";
  RxFrame f;
  f.id = 0x800;  // beyond 11 bits
  f.event = EventKind::kToolChange;
  f.origin = {"", 5, 1, "can.rx[0]"};
  RxSignal s;
  s.name = "tool_number";
  s.origin = {"", 8, 1, "can.rx[0].signal[0]"};
  f.signals.push_back(s);
  m.rx.push_back(f);
  formats::Diagnostics diag;
  EXPECT_FALSE(validate_mapping(m, diag));
  EXPECT_EQ(diag.to_string(),
            "built.toml:5:1: can.rx[0].id: 0x800 exceeds the 11-bit ID range (max 0x7FF)\n"
            "built.toml:8:1: can.rx[0].signal[0].name: unknown signal 'tool_number' for event "
            "tool_change (known: tool, sister)\n");
}

class DecoderTest : public ::testing::Test {
 protected:
  DecoderTest() : config_(load_can_config(reference_path())), decoder_(config_.mapping) {}

  FrameDecoder::Result feed(std::uint32_t id, std::initializer_list<std::uint8_t> bytes,
                            core::TimeNs t = 1000) {
    std::array<std::uint8_t, 64> d{};
    std::size_t n = 0;
    for (auto b : bytes) {
      d[n++] = b;
    }
    return decoder_.decode(id, false, std::span<const std::uint8_t>(d.data(), n), t, out_);
  }

  CanConfig config_;
  FrameDecoder decoder_;
  core::Event out_;
};

TEST_F(DecoderTest, AxisSampleAssembledFromFourFramesEmittedByTheLast) {
  // X = 123.4567 mm = 1234567 counts; Y = -1 mm = -10000 counts.
  EXPECT_FALSE(feed(0x100, {0x87, 0xD6, 0x12, 0x00, 0xF0, 0xD8, 0xFF, 0xFF}).emitted);
  // Path 2.5 m = 2500000 µm counts; normal (0.6, 0, ) = 6000.
  EXPECT_FALSE(feed(0x101, {0xA0, 0x25, 0x26, 0x00, 0x70, 0x17, 0x00, 0x00}).emitted);
  EXPECT_FALSE(feed(0x103, {0x40, 0x1F}).emitted);  // normal_z 0.8 = 8000
  // Z = 10 mm = 100000 counts, tool 7, cutting.
  const auto r = feed(0x102, {0xA0, 0x86, 0x01, 0x00, 0x07, 0x00, 0x01, 0x00}, 5000);
  ASSERT_TRUE(r.emitted);
  ASSERT_TRUE(std::holds_alternative<core::AxisSample>(out_));
  const auto& s = std::get<core::AxisSample>(out_);
  EXPECT_EQ(s.time_ns, 5000);
  EXPECT_EQ(s.axis_count, 3);
  EXPECT_NEAR(s.position_mm[0], 123.4567, 1e-9);
  EXPECT_NEAR(s.position_mm[1], -1.0, 1e-9);
  EXPECT_NEAR(s.position_mm[2], 10.0, 1e-9);
  EXPECT_NEAR(s.program_path_mm, 2500.0, 1e-9);
  EXPECT_TRUE(s.has_normal);
  EXPECT_NEAR(s.normal[0], 0.6, 1e-12);
  EXPECT_NEAR(s.normal[1], 0.0, 1e-12);
  EXPECT_NEAR(s.normal[2], 0.8, 1e-12);
  EXPECT_EQ(s.tool, 7);
  EXPECT_TRUE(s.cutting);
}

TEST_F(DecoderTest, RejectsWrongLengthOutOfRangeAndNaNWithoutChangingState) {
  EXPECT_EQ(feed(0x102, {0xA0, 0x86, 0x01}).reject, RejectReason::kWrongLength);
  EXPECT_EQ(feed(0x7FF, {0x00}).reject, RejectReason::kUnknownId);
  // temperature 200 °C = 20000 counts > max 150.
  EXPECT_EQ(feed(0x160, {0x01, 0x00, 0x20, 0x4E}).reject, RejectReason::kOutOfRange);
  // program event kind 4 (only 0..3 exist).
  EXPECT_EQ(feed(0x150, {0x04, 0, 0, 0, 1, 0, 0, 0}).reject, RejectReason::kOutOfRange);
  // Calibration touch: axis 2, direction +1 is fine; axis 3 does not exist; direction 0 neither.
  EXPECT_EQ(feed(0x130, {0x04 | 0x08, 0, 0, 0, 0, 0, 0, 0}).reject, RejectReason::kNone);
  EXPECT_EQ(feed(0x130, {0x07 | 0x08, 0, 0, 0, 0, 0, 0, 0}).reject, RejectReason::kOutOfRange);
  EXPECT_EQ(feed(0x130, {0x04, 0, 0, 0, 0, 0, 0, 0}).reject, RejectReason::kOutOfRange);
  // NaN deviation in the float signal.
  EXPECT_EQ(feed(0x121, {0x00, 0x00, 0xC0, 0x7F, 0, 0, 0, 0}).reject, RejectReason::kNotFinite);
  // After all that, a good temperature frame decodes to exactly its own values.
  const auto r = feed(0x160, {0x02, 0x00, 0xD2, 0x04});  // 12.34 °C
  ASSERT_TRUE(r.emitted);
  const auto& t = std::get<core::TemperatureSample>(out_);
  EXPECT_EQ(t.sensor, 2);
  EXPECT_NEAR(t.temperature_c, 12.34, 1e-9);
}

// Pins: a frame is validated as a whole before any of its signals is applied. The rejected
// frames below feed the axis sample without emitting it, and the frame that emits it (0x102)
// carries none of their signals, so a value applied from a rejected frame would show in the
// emitted sample. Each rejected frame has valid signals before and after the bad one.
TEST_F(DecoderTest, RejectedFrameLeavesLatestValuesAlone) {
  // X 123.4567 mm, Y -1 mm; path 2500 mm, normal (0.6, 0, 0.8).
  ASSERT_EQ(feed(0x100, {0x87, 0xD6, 0x12, 0x00, 0xF0, 0xD8, 0xFF, 0xFF}).reject,
            RejectReason::kNone);
  ASSERT_EQ(feed(0x101, {0xA0, 0x25, 0x26, 0x00, 0x70, 0x17, 0x00, 0x00}).reject,
            RejectReason::kNone);
  ASSERT_EQ(feed(0x103, {0x40, 0x1F}).reject, RejectReason::kNone);
  // X 50 mm (valid), Y 6000 mm (beyond max 5000).
  EXPECT_EQ(feed(0x100, {0x20, 0xA1, 0x07, 0x00, 0x00, 0x87, 0x93, 0x03}).reject,
            RejectReason::kOutOfRange);
  // X 6000 mm (beyond max 5000), Y 2 mm (valid).
  EXPECT_EQ(feed(0x100, {0x00, 0x87, 0x93, 0x03, 0x20, 0x4E, 0x00, 0x00}).reject,
            RejectReason::kOutOfRange);
  // Path 3000 mm and normal_x 0.8 (valid), normal_y 1.5 (beyond max 1).
  EXPECT_EQ(feed(0x101, {0xC0, 0xC6, 0x2D, 0x00, 0x40, 0x1F, 0x98, 0x3A}).reject,
            RejectReason::kOutOfRange);
  // Z 10 mm, tool 7, cutting: emits the sample with the values of the accepted frames only.
  const auto r = feed(0x102, {0xA0, 0x86, 0x01, 0x00, 0x07, 0x00, 0x01, 0x00}, 6000);
  ASSERT_TRUE(r.emitted);
  const auto& s = std::get<core::AxisSample>(out_);
  EXPECT_NEAR(s.position_mm[0], 123.4567, 1e-9);
  EXPECT_NEAR(s.position_mm[1], -1.0, 1e-9);
  EXPECT_NEAR(s.position_mm[2], 10.0, 1e-9);
  EXPECT_NEAR(s.program_path_mm, 2500.0, 1e-9);
  EXPECT_NEAR(s.normal[0], 0.6, 1e-12);
  EXPECT_NEAR(s.normal[1], 0.0, 1e-12);
  EXPECT_NEAR(s.normal[2], 0.8, 1e-12);
}

TEST_F(DecoderTest, ProbeMeasurementCompletedByTheNextGoodFrameAfterARejectedOne) {
  ASSERT_FALSE(
      feed(0x120, {0x05, 0, 0, 0, 0x03, 0x00, 0xB8, 0x0B}).emitted);  // part 5, cp 3, r 3 mm
  // A bad second part frame: angle 100° > 90 → rejected; the next good one completes.
  EXPECT_EQ(feed(0x121, {0x00, 0x00, 0x20, 0x41, 0x10, 0x27, 0, 0}).reject,
            RejectReason::kOutOfRange);
  const float dev = -7.5F;
  const auto b = std::bit_cast<std::array<std::uint8_t, 4>>(dev);
  const auto r = feed(0x121, {b[0], b[1], b[2], b[3], 0xA0, 0x0F, 0, 0});  // 40.00°
  ASSERT_TRUE(r.emitted);
  const auto& p = std::get<core::ProbeMeasurement>(out_);
  EXPECT_EQ(p.part, 5);
  EXPECT_EQ(p.checkpoint, 3);
  EXPECT_NEAR(p.ball_radius_mm, 3.0, 1e-12);
  EXPECT_NEAR(p.raw_deviation_um, -7.5, 1e-12);
  EXPECT_NEAR(p.wall_angle_deg, 40.0, 1e-9);
}

// Issue 17, finding 4, over CAN. GIVEN the reference map, WHEN a measurement's frame is rejected
// (a wear beyond max = 5000 µm, a NaN deviation, a touch on axis 3, a frame of the wrong length),
// THEN the measurement is not lost in silence: the frame is counted as rejected (its reason) and
// the measurement is emitted faulted (kOutOfRange / kInvalid) with every value 0, by the rejected
// frame if it completes the event, else by the frame that does; identity fields the rejected
// frame carried are unknown (tool 0, checkpoint -1), never an earlier measurement's; the next
// intact measurement is an ordinary one. Allocation-free.
TEST_F(DecoderTest, ARejectedMeasurementFrameEmitsAFaultedMeasurement) {
  // Tool 3, wear 6000 µm = 600000 counts (> max 5000).
  auto r = feed(0x110, {0x03, 0x00, 0x00, 0x00, 0xC0, 0x27, 0x09, 0x00});
  EXPECT_EQ(r.reject, RejectReason::kOutOfRange);
  ASSERT_TRUE(r.emitted);
  auto m = std::get<core::ToolMeasurement>(out_);
  EXPECT_EQ(m.fault, core::InputFault::kOutOfRange);
  EXPECT_EQ(m.tool, 0);  // carried by the rejected frame: unknown
  EXPECT_EQ(m.wear_um[0], 0.0);
  EXPECT_EQ(m.time_ns, 1000);
  // Tool 3, 12.34 µm: an ordinary measurement again.
  r = feed(0x110, {0x03, 0x00, 0x00, 0x00, 0xD2, 0x04, 0x00, 0x00});
  ASSERT_TRUE(r.emitted);
  m = std::get<core::ToolMeasurement>(out_);
  EXPECT_EQ(m.fault, core::InputFault::kNone);
  EXPECT_EQ(m.tool, 3);
  EXPECT_NEAR(m.wear_um[0], 12.34, 1e-9);

  // Probe: part 5, checkpoint 3, r 3 mm, then a NaN deviation in the completing frame.
  ASSERT_FALSE(feed(0x120, {0x05, 0, 0, 0, 0x03, 0x00, 0xB8, 0x0B}).emitted);
  r = feed(0x121, {0x00, 0x00, 0xC0, 0x7F, 0xA0, 0x0F, 0, 0});
  EXPECT_EQ(r.reject, RejectReason::kNotFinite);
  ASSERT_TRUE(r.emitted);
  auto p = std::get<core::ProbeMeasurement>(out_);
  EXPECT_EQ(p.fault, core::InputFault::kInvalid);
  EXPECT_EQ(p.checkpoint, 3);
  EXPECT_EQ(p.part, 5);
  EXPECT_EQ(p.raw_deviation_um, 0.0);
  EXPECT_EQ(p.ball_radius_mm, 0.0);
  // A first frame of the wrong length: the completing frame delivers the measurement faulted,
  // with its checkpoint unknown (not the 3 of the measurement before).
  EXPECT_EQ(feed(0x120, {0x06, 0, 0}).reject, RejectReason::kWrongLength);
  const float dev = -7.5F;
  const auto b = std::bit_cast<std::array<std::uint8_t, 4>>(dev);
  r = feed(0x121, {b[0], b[1], b[2], b[3], 0xA0, 0x0F, 0, 0});
  EXPECT_EQ(r.reject, RejectReason::kNone);
  ASSERT_TRUE(r.emitted);
  p = std::get<core::ProbeMeasurement>(out_);
  EXPECT_EQ(p.fault, core::InputFault::kInvalid);
  EXPECT_EQ(p.checkpoint, -1);
  EXPECT_EQ(p.raw_deviation_um, 0.0);
  // Both frames intact: an ordinary measurement.
  ASSERT_FALSE(feed(0x120, {0x07, 0, 0, 0, 0x04, 0x00, 0xB8, 0x0B}).emitted);
  ASSERT_TRUE(feed(0x121, {b[0], b[1], b[2], b[3], 0xA0, 0x0F, 0, 0}).emitted);
  p = std::get<core::ProbeMeasurement>(out_);
  EXPECT_EQ(p.fault, core::InputFault::kNone);
  EXPECT_EQ(p.checkpoint, 4);
  EXPECT_NEAR(p.raw_deviation_um, -7.5, 1e-12);

  // Touch on axis 3 (none such): faulted, allocation-free.
  test::AllocationScope scope;
  r = feed(0x130, {0x07 | 0x08, 0, 0, 0, 0x10, 0, 0, 0});
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_EQ(r.reject, RejectReason::kOutOfRange);
  ASSERT_TRUE(r.emitted);
  const auto& t = std::get<core::CalibrationTouch>(out_);
  EXPECT_EQ(t.fault, core::InputFault::kOutOfRange);
  EXPECT_EQ(t.trigger_position_mm, 0.0);
  EXPECT_EQ(t.direction, 1);

  // Other events are dropped as before: a temperature beyond max emits nothing.
  r = feed(0x160, {0x01, 0x00, 0x20, 0x4E});
  EXPECT_EQ(r.reject, RejectReason::kOutOfRange);
  EXPECT_FALSE(r.emitted);
}

TEST_F(DecoderTest, BigEndianTriggerPosition) {
  // -12.5 mm = -125000 counts = 0xFFFE17B8, big-endian in bytes 4..7; axis Z(2), dir -1, probe 1.
  const std::uint8_t flags = 0x01 | (2 << 1) | (0x3 << 3);
  const auto r = feed(0x130, {flags, 0, 0, 0, 0xFF, 0xFE, 0x17, 0xB8});
  ASSERT_TRUE(r.emitted);
  const auto& c = std::get<core::CalibrationTouch>(out_);
  EXPECT_EQ(c.probe, core::ProbeKind::kReferenceProbe);
  EXPECT_EQ(c.axis, 2);
  EXPECT_EQ(c.direction, -1);
  EXPECT_NEAR(c.trigger_position_mm, -12.5, 1e-9);
}

TEST_F(DecoderTest, DecodeAndEncodeAllocateNothing) {
  std::array<std::uint8_t, 64> d{0x02, 0x00, 0xD2, 0x04};
  std::array<std::uint8_t, kMaxPayloadBytes> payload{};
  test::AllocationScope scope;
  for (int i = 0; i < 100; ++i) {
    (void)decoder_.decode(0x160, false, std::span<const std::uint8_t>(d.data(), 4), i, out_);
    (void)encode_offset(config_.mapping.offsets[0], 12.3 * i, payload);
  }
  EXPECT_EQ(scope.count(), 0U);
}

// An integral field (tool, checkpoint, kind, ...) whose scaled value is not an integer is refused,
// never rounded to a neighbour's number: a map with a wrong scale, or garbage from the NC.
TEST(CanDecoderIntegral, AFractionalToolNumberIsRefusedNotRounded) {
  const CanConfig c = parse_can_config(kHead +
                                           "[[can.rx]]\nid = 0x140\nlength_bytes = 2\n"
                                           "event = \"tool_change\"\n[[can.rx.signal]]\n"
                                           "name = \"tool\"\nstart_bit = 0\nlength_bits = 16\n"
                                           "scale = 0.5\n",
                                       "test.toml");
  FrameDecoder dec(c.mapping);
  core::Event out;
  const auto feed = [&](std::uint16_t raw) {
    const std::array<std::uint8_t, 2> d{static_cast<std::uint8_t>(raw & 0xFFU),
                                        static_cast<std::uint8_t>(raw >> 8U)};
    return dec.decode(0x140, false, d, 1000, out);
  };
  // 14 counts = tool 7
  auto r = feed(14);
  ASSERT_TRUE(r.emitted);
  EXPECT_EQ(std::get<core::ToolChange>(out).tool, 7);
  // 15 counts = 7.5: refused; the latest tool stays 7
  r = feed(15);
  EXPECT_EQ(r.reject, RejectReason::kOutOfRange);
  EXPECT_FALSE(r.emitted);
  EXPECT_EQ(std::get<core::ToolChange>(out).tool, 7);
}

TEST(CanEncode, OffsetWriteBytesAndRangeRefusal) {
  const CanConfig c = load_can_config(reference_path());
  std::array<std::uint8_t, kMaxPayloadBytes> p{};
  // -12.3 µm at 0.1 µm per count = -123 = 0xFFFFFF85.
  ASSERT_TRUE(encode_offset(c.mapping.offsets[0], -12.3, p));
  EXPECT_EQ(p[0], 0x85);
  EXPECT_EQ(p[1], 0xFF);
  EXPECT_EQ(p[2], 0xFF);
  EXPECT_EQ(p[3], 0xFF);
  EXPECT_FALSE(encode_offset(c.mapping.offsets[0], 1e12, p));
  EXPECT_FALSE(encode_offset(c.mapping.offsets[0], core::kNaN, p));
}

}  // namespace
}  // namespace nccomp::drivers::can

namespace nccomp::drivers::can {
namespace {

TEST(CanBusLifecycle, StartOnMissingInterfaceThrowsNamingItAndStaysStopped) {
  // GIVEN the reference map on an interface that does not exist (or a kernel without CAN)
  CanConfig c = load_can_config(reference_path());
  c.interface = "nccompnone0";
  CanBus bus(std::move(c));
  // WHEN started THEN it refuses with a message naming the cause, and nothing runs.
  try {
    bus.start();
    FAIL() << "start() succeeded on a missing interface";
  } catch (const std::runtime_error& e) {
    const std::string what = e.what();
    EXPECT_TRUE(what.find("can: nccompnone0: no such interface") != std::string::npos ||
                what.find("can: socket(PF_CAN, CAN_RAW) failed") != std::string::npos)
        << what;
  }
  EXPECT_EQ(bus.status().state, LinkState::kStopped);
  EXPECT_EQ(bus.rx().capacity(), 4096U);
  EXPECT_EQ(bus.tx().capacity(), 256U);
  bus.stop();  // idempotent, no thread to join
}

TEST(CanBusLifecycle, ExtraCountersHaveFixedUniqueSnakeCaseNames) {
  // GIVEN a bus that never started
  CanBus bus(load_can_config(reference_path()));
  // WHEN its driver counters are read THEN every CanCounters field is there, named, zero.
  std::array<BusCounterValue, kMaxBusExtraCounters> out{};
  const std::size_t n = bus.extra_counters(out);
  ASSERT_EQ(n, kCanCounterNames.size());
  ASSERT_LE(n, kMaxBusExtraCounters);
  for (std::size_t i = 0; i < n; ++i) {
    const std::string name = out[i].name;
    EXPECT_EQ(name, kCanCounterNames[i]);
    EXPECT_EQ(out[i].value, 0U) << name;
    EXPECT_EQ(name.find_first_not_of("abcdefghijklmnopqrstuvwxyz_"), std::string::npos) << name;
    for (std::size_t j = 0; j < i; ++j) {
      EXPECT_NE(name, std::string(out[j].name)) << "twice";
    }
  }
  // The ones the operator needs first (issue 7 / the status gaps of the audit).
  for (const char* want :
       {"bus_off", "error_passive", "error_warning", "bus_recoveries", "interface_down",
        "link_alarms", "rx_overflow", "enobufs", "enobufs_retries", "ack_timeouts", "ack_retries",
        "resent_after_recovery", "rejected_wrong_length", "rejected_out_of_range",
        "rejected_not_finite"}) {
    EXPECT_NE(std::find(kCanCounterNames.begin(), kCanCounterNames.end(), std::string_view(want)),
              kCanCounterNames.end())
        << want;
  }
  // A short span gets the first entries only.
  std::array<BusCounterValue, 3> few{};
  EXPECT_EQ(bus.extra_counters(few), 3U);
  EXPECT_STREQ(few[2].name, "error_passive");
}

}  // namespace
}  // namespace nccomp::drivers::can
