// Register encodings of Modbus values: 16- and 32-bit integers and IEEE-754 floats with a
// configurable word order (which register holds the high half) and byte order (whether the two
// bytes of each register are swapped), plus scale and offset to engineering units.
//
// Modbus itself only defines 16-bit big-endian registers; everything wider is a vendor
// convention, which is why the order is data (config) and not code.
//
// Real-time behaviour: all functions are pure, noexcept and allocation-free.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>

namespace nccomp::drivers::modbus {

/// The four Modbus data tables.
enum class Table : std::uint8_t { kCoil = 0, kDiscreteInput = 1, kHolding = 2, kInput = 3 };
inline constexpr std::size_t kTableCount = 4;

/// kBool is the only type of coils and discrete inputs (one bit each).
enum class ValueType : std::uint8_t { kBool, kInt16, kUint16, kInt32, kUint32, kFloat32 };

/// kHighFirst: the first register holds the high 16 bits ("ABCD", the Modbus convention).
enum class WordOrder : std::uint8_t { kHighFirst, kLowFirst };
/// kBigEndian: each register as sent on the wire; kSwapped: the two bytes of every register
/// exchanged ("BADC" / "DCBA" devices).
enum class ByteOrder : std::uint8_t { kBigEndian, kSwapped };

struct Encoding {
  ValueType type{ValueType::kInt16};
  WordOrder word_order{WordOrder::kHighFirst};
  ByteOrder byte_order{ByteOrder::kBigEndian};
  /// Engineering value = raw * scale + offset (units of the signal, e.g. mm per count).
  double scale{1.0};
  double offset{0.0};
};

/// Registers (or bits) one value of this type occupies.
constexpr std::uint16_t width(ValueType t) noexcept {
  return (t == ValueType::kInt32 || t == ValueType::kUint32 || t == ValueType::kFloat32) ? 2 : 1;
}
constexpr bool is_bit_table(Table t) noexcept {
  return t == Table::kCoil || t == Table::kDiscreteInput;
}

/// Raw value (before scale/offset) from width(type) registers. Real-time safe.
/// For kBool, regs[0] != 0.
double decode_raw(std::span<const std::uint16_t> regs, const Encoding& enc) noexcept;

/// Engineering value: decode_raw * scale + offset. NaN / inf pass through (the caller decides).
double decode(std::span<const std::uint16_t> regs, const Encoding& enc) noexcept;

/// Why an encode was refused.
enum class EncodeResult : std::uint8_t { kOk, kNotFinite, kOutOfRange };

/// Engineering value → registers: raw = (value - offset) / scale, rounded to nearest for
/// integer types, refused (registers untouched) if not finite or outside the type's range.
/// Real-time safe.
EncodeResult encode(double value, const Encoding& enc, std::span<std::uint16_t> regs) noexcept;

}  // namespace nccomp::drivers::modbus
