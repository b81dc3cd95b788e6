// Arbitrary register contents through the poll decoder of the reference NC profile: every event
// that comes out must be finite and in range (the codes' ranges and the map's min / max on the
// axes); nothing may crash or trip a sanitizer.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <variant>
#include <vector>

#include "drivers/modbus/config.hpp"
#include "drivers/modbus/decoder.hpp"

namespace mb = nccomp::drivers::modbus;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const mb::ModbusConfig config = mb::load_modbus_config(NCCOMP_REFERENCE_PROFILE);
  mb::PollDecoder dec(config);
  std::vector<std::uint8_t> ok(config.blocks.size(), 1);
  std::size_t pos = 0;
  // Several polls, so that sequence counters move between them.
  for (int poll = 0; poll < 4; ++poll) {
    for (std::size_t b = 0; b < dec.block_count(); ++b) {
      for (std::uint16_t& r : dec.block(b)) {
        if (pos + 1 < size) {
          r = static_cast<std::uint16_t>((data[pos] << 8) | data[pos + 1]);
          pos += 2;
        }
      }
      ok[b] = (pos < size && (data[pos % size] & 0x80U) != 0) ? 0 : 1;
    }
    for (const auto& e : dec.decode(poll, ok)) {
      if (const auto* a = std::get_if<nccomp::core::AxisSample>(&e)) {
        const auto& axis = config.groups[static_cast<std::size_t>(mb::Group::kAxis)];
        for (std::size_t i = 0; i < a->axis_count; ++i) {
          if (!std::isfinite(a->position_mm[i]) || a->position_mm[i] < axis.fields[i].min ||
              a->position_mm[i] > axis.fields[i].max) {
            std::abort();
          }
        }
      } else if (const auto* t = std::get_if<nccomp::core::CalibrationTouch>(&e)) {
        if (t->axis > 2 || (t->direction != 1 && t->direction != -1)) {
          std::abort();
        }
      } else if (const auto* p = std::get_if<nccomp::core::ProgramEvent>(&e)) {
        if (static_cast<int>(p->kind) > 3) {
          std::abort();
        }
      }
    }
  }
  return 0;
}
