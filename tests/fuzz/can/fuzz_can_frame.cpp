// Fuzz target: frames from the bus. The first 4 bytes pick the ID, the rest is the payload;
// decoded against the reference NC map. Any bytes: rejected with a reason or decoded to finite
// values, never a crash.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <span>

#include "drivers/can/can_config.hpp"
#include "drivers/can/can_mapping.hpp"

namespace dc = nccomp::drivers::can;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const std::unique_ptr<dc::CanConfig> config = [] {
    return std::make_unique<dc::CanConfig>(
        dc::load_can_config(std::string(NCCOMP_SOURCE_DIR) + "/config/reference-nc-can.toml"));
  }();
  static dc::FrameDecoder decoder(config->mapping);
  if (size < 2) {
    return 0;
  }
  // Steer the ID to the mapped ones most of the time.
  const auto& rx = config->mapping.rx;
  const std::uint32_t id = (data[0] & 0x80) != 0 ? (data[1] | (data[0] & 0x07U) << 8)
                                                 : rx[data[1] % rx.size()].id;
  const std::size_t n = std::min<std::size_t>(size - 2, dc::kMaxPayloadBytes);
  nccomp::core::Event ev;
  const auto r = decoder.decode(id, false, std::span<const std::uint8_t>(data + 2, n), 1, ev);
  if (r.emitted) {
    for (const auto& f : rx) {
      for (const auto& s : f.signals) {
        const auto v = dc::field_value(ev, s.field);
        if (v && !std::isfinite(*v) && s.field != dc::Field::kProgramPathMm) {
          std::abort();  // a decoded event must never carry a non-finite mapped value
        }
      }
    }
  }
  return 0;
}
