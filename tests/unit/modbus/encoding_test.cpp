#include "drivers/modbus/encoding.hpp"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <limits>

namespace nccomp::drivers::modbus {
namespace {

Encoding enc(ValueType t, WordOrder w = WordOrder::kHighFirst, ByteOrder b = ByteOrder::kBigEndian,
             double scale = 1.0, double offset = 0.0) {
  return Encoding{t, w, b, scale, offset};
}

TEST(ModbusEncoding, Int16SignAndByteSwap) {
  // GIVEN 0xFF38 on the wire (-200 as int16)
  const std::array<std::uint16_t, 1> r{0xFF38};
  EXPECT_DOUBLE_EQ(decode(r, enc(ValueType::kInt16)), -200.0);
  EXPECT_DOUBLE_EQ(decode(r, enc(ValueType::kUint16)), 65336.0);
  // WHEN the device swaps the bytes THEN 0x38FF is read
  EXPECT_DOUBLE_EQ(decode(r, enc(ValueType::kUint16, WordOrder::kHighFirst, ByteOrder::kSwapped)),
                   14591.0);
}

TEST(ModbusEncoding, Int32AllFourOrders) {
  // 0x12345678 as ABCD, CDAB, BADC, DCBA.
  const double v = 305419896.0;
  EXPECT_DOUBLE_EQ(decode(std::array<std::uint16_t, 2>{0x1234, 0x5678}, enc(ValueType::kInt32)), v);
  EXPECT_DOUBLE_EQ(decode(std::array<std::uint16_t, 2>{0x5678, 0x1234},
                          enc(ValueType::kInt32, WordOrder::kLowFirst)),
                   v);
  EXPECT_DOUBLE_EQ(decode(std::array<std::uint16_t, 2>{0x3412, 0x7856},
                          enc(ValueType::kInt32, WordOrder::kHighFirst, ByteOrder::kSwapped)),
                   v);
  EXPECT_DOUBLE_EQ(decode(std::array<std::uint16_t, 2>{0x7856, 0x3412},
                          enc(ValueType::kInt32, WordOrder::kLowFirst, ByteOrder::kSwapped)),
                   v);
}

TEST(ModbusEncoding, Int32NegativeAndUint32Max) {
  EXPECT_DOUBLE_EQ(decode(std::array<std::uint16_t, 2>{0xFFFF, 0xFFFE}, enc(ValueType::kInt32)),
                   -2.0);
  EXPECT_DOUBLE_EQ(decode(std::array<std::uint16_t, 2>{0xFFFF, 0xFFFF}, enc(ValueType::kUint32)),
                   4294967295.0);
}

TEST(ModbusEncoding, Float32KnownPattern) {
  // 1.5f = 0x3FC00000; -0.1f = 0xBDCCCCCD
  EXPECT_DOUBLE_EQ(decode(std::array<std::uint16_t, 2>{0x3FC0, 0x0000}, enc(ValueType::kFloat32)),
                   1.5);
  EXPECT_DOUBLE_EQ(decode(std::array<std::uint16_t, 2>{0x0000, 0x3FC0},
                          enc(ValueType::kFloat32, WordOrder::kLowFirst)),
                   1.5);
  EXPECT_NEAR(decode(std::array<std::uint16_t, 2>{0xBDCC, 0xCCCD}, enc(ValueType::kFloat32)), -0.1,
              1e-8);
  EXPECT_TRUE(
      std::isnan(decode(std::array<std::uint16_t, 2>{0x7FC0, 0x0000}, enc(ValueType::kFloat32))));
}

TEST(ModbusEncoding, ScaleAndOffset) {
  const std::array<std::uint16_t, 2> r{0x0000, 0x3039};  // 12345
  EXPECT_DOUBLE_EQ(
      decode(r, enc(ValueType::kInt32, WordOrder::kHighFirst, ByteOrder::kBigEndian, 0.001, -10.0)),
      12.345 - 10.0);
}

TEST(ModbusEncoding, RoundTripEveryTypeAndOrder) {
  for (ValueType t : {ValueType::kInt16, ValueType::kUint16, ValueType::kInt32, ValueType::kUint32,
                      ValueType::kFloat32}) {
    for (WordOrder w : {WordOrder::kHighFirst, WordOrder::kLowFirst}) {
      for (ByteOrder b : {ByteOrder::kBigEndian, ByteOrder::kSwapped}) {
        const Encoding e = enc(t, w, b, 0.1, 5.0);
        const double v = t == ValueType::kUint16 || t == ValueType::kUint32 ? 1234.5 : -1234.5;
        std::array<std::uint16_t, 2> r{};
        ASSERT_EQ(encode(v, e, r), EncodeResult::kOk);
        EXPECT_NEAR(decode(r, e), v, 1e-4) << static_cast<int>(t);
      }
    }
  }
}

TEST(ModbusEncoding, EncodeRoundsToNearestCount) {
  std::array<std::uint16_t, 2> r{};
  const Encoding e = enc(ValueType::kInt32, WordOrder::kHighFirst, ByteOrder::kBigEndian, 0.1);
  ASSERT_EQ(encode(12.34, e, r), EncodeResult::kOk);  // 123.4 counts -> 123
  EXPECT_EQ(r[0], 0);
  EXPECT_EQ(r[1], 123);
  ASSERT_EQ(encode(-0.06, e, r), EncodeResult::kOk);  // -0.6 -> -1
  EXPECT_EQ(r[0], 0xFFFF);
  EXPECT_EQ(r[1], 0xFFFF);
}

TEST(ModbusEncoding, EncodeRefusesNaNInfAndOutOfRangeWithoutTouchingRegisters) {
  std::array<std::uint16_t, 2> r{0xAAAA, 0xBBBB};
  EXPECT_EQ(encode(std::numeric_limits<double>::quiet_NaN(), enc(ValueType::kInt32), r),
            EncodeResult::kNotFinite);
  EXPECT_EQ(encode(std::numeric_limits<double>::infinity(), enc(ValueType::kFloat32), r),
            EncodeResult::kNotFinite);
  EXPECT_EQ(encode(32768.0, enc(ValueType::kInt16), r), EncodeResult::kOutOfRange);
  EXPECT_EQ(encode(-32769.0, enc(ValueType::kInt16), r), EncodeResult::kOutOfRange);
  EXPECT_EQ(encode(-1.0, enc(ValueType::kUint16), r), EncodeResult::kOutOfRange);
  EXPECT_EQ(encode(65536.0, enc(ValueType::kUint16), r), EncodeResult::kOutOfRange);
  EXPECT_EQ(encode(2147483648.0, enc(ValueType::kInt32), r), EncodeResult::kOutOfRange);
  EXPECT_EQ(encode(4294967296.0, enc(ValueType::kUint32), r), EncodeResult::kOutOfRange);
  EXPECT_EQ(encode(1e39, enc(ValueType::kFloat32), r), EncodeResult::kOutOfRange);
  EXPECT_EQ(r[0], 0xAAAA);
  EXPECT_EQ(r[1], 0xBBBB);
  // The edges themselves are accepted.
  EXPECT_EQ(encode(32767.0, enc(ValueType::kInt16), r), EncodeResult::kOk);
  EXPECT_EQ(r[0], 0x7FFF);
  EXPECT_EQ(encode(-32768.0, enc(ValueType::kInt16), r), EncodeResult::kOk);
  EXPECT_EQ(r[0], 0x8000);
}

}  // namespace
}  // namespace nccomp::drivers::modbus
