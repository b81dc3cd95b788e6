#include "drivers/modbus/encoding.hpp"

#include <bit>
#include <cmath>
#include <limits>

namespace nccomp::drivers::modbus {
namespace {

std::uint16_t swap_bytes(std::uint16_t v) noexcept {
  return static_cast<std::uint16_t>(((v & 0x00FFU) << 8U) | ((v & 0xFF00U) >> 8U));
}

std::uint16_t wire_to_host(std::uint16_t v, ByteOrder order) noexcept {
  return order == ByteOrder::kSwapped ? swap_bytes(v) : v;
}

std::uint32_t join(std::span<const std::uint16_t> regs, const Encoding& enc) noexcept {
  const std::uint16_t r0 = wire_to_host(regs[0], enc.byte_order);
  const std::uint16_t r1 = wire_to_host(regs[1], enc.byte_order);
  const std::uint32_t hi = enc.word_order == WordOrder::kHighFirst ? r0 : r1;
  const std::uint32_t lo = enc.word_order == WordOrder::kHighFirst ? r1 : r0;
  return (hi << 16U) | lo;
}

void split(std::uint32_t v, const Encoding& enc, std::span<std::uint16_t> regs) noexcept {
  const auto hi = static_cast<std::uint16_t>(v >> 16U);
  const auto lo = static_cast<std::uint16_t>(v & 0xFFFFU);
  const std::uint16_t first = enc.word_order == WordOrder::kHighFirst ? hi : lo;
  const std::uint16_t second = enc.word_order == WordOrder::kHighFirst ? lo : hi;
  regs[0] = wire_to_host(first, enc.byte_order);
  regs[1] = wire_to_host(second, enc.byte_order);
}

}  // namespace

double decode_raw(std::span<const std::uint16_t> regs, const Encoding& enc) noexcept {
  switch (enc.type) {
    case ValueType::kBool:
      return regs[0] != 0 ? 1.0 : 0.0;
    case ValueType::kInt16:
      return static_cast<double>(static_cast<std::int16_t>(wire_to_host(regs[0], enc.byte_order)));
    case ValueType::kUint16:
      return static_cast<double>(wire_to_host(regs[0], enc.byte_order));
    case ValueType::kInt32:
      return static_cast<double>(static_cast<std::int32_t>(join(regs, enc)));
    case ValueType::kUint32:
      return static_cast<double>(join(regs, enc));
    case ValueType::kFloat32:
      return static_cast<double>(std::bit_cast<float>(join(regs, enc)));
  }
  return std::numeric_limits<double>::quiet_NaN();
}

double decode(std::span<const std::uint16_t> regs, const Encoding& enc) noexcept {
  return decode_raw(regs, enc) * enc.scale + enc.offset;
}

EncodeResult encode(double value, const Encoding& enc, std::span<std::uint16_t> regs) noexcept {
  if (!std::isfinite(value)) {
    return EncodeResult::kNotFinite;
  }
  const double raw = (value - enc.offset) / enc.scale;
  if (!std::isfinite(raw)) {
    return EncodeResult::kOutOfRange;
  }
  if (enc.type == ValueType::kFloat32) {
    if (std::fabs(raw) > static_cast<double>(std::numeric_limits<float>::max())) {
      return EncodeResult::kOutOfRange;
    }
    split(std::bit_cast<std::uint32_t>(static_cast<float>(raw)), enc, regs);
    return EncodeResult::kOk;
  }
  const double r = std::nearbyint(raw);
  double lo = 0.0;
  double hi = 1.0;
  switch (enc.type) {
    case ValueType::kInt16:
      lo = std::numeric_limits<std::int16_t>::min();
      hi = std::numeric_limits<std::int16_t>::max();
      break;
    case ValueType::kUint16:
      hi = std::numeric_limits<std::uint16_t>::max();
      break;
    case ValueType::kInt32:
      lo = std::numeric_limits<std::int32_t>::min();
      hi = std::numeric_limits<std::int32_t>::max();
      break;
    case ValueType::kUint32:
      hi = std::numeric_limits<std::uint32_t>::max();
      break;
    case ValueType::kBool:
    case ValueType::kFloat32:
      break;
  }
  if (r < lo || r > hi) {
    return EncodeResult::kOutOfRange;
  }
  switch (enc.type) {
    case ValueType::kBool:
      regs[0] = r > 0.5 ? 1 : 0;
      break;
    case ValueType::kInt16:
      regs[0] =
          wire_to_host(static_cast<std::uint16_t>(static_cast<std::int16_t>(r)), enc.byte_order);
      break;
    case ValueType::kUint16:
      regs[0] = wire_to_host(static_cast<std::uint16_t>(r), enc.byte_order);
      break;
    case ValueType::kInt32:
      split(static_cast<std::uint32_t>(static_cast<std::int32_t>(r)), enc, regs);
      break;
    case ValueType::kUint32:
      split(static_cast<std::uint32_t>(r), enc, regs);
      break;
    case ValueType::kFloat32:
      break;
  }
  return EncodeResult::kOk;
}

}  // namespace nccomp::drivers::modbus
