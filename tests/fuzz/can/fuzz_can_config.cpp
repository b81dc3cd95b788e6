// Fuzz target: the [can] config parser and mapping validation (any bytes: parsed or refused with
// DiagnosticsError, never a crash), and the frame decoder on the reference map (any payload).
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>

#include "drivers/can/can_config.hpp"
#include "drivers/can/can_mapping.hpp"

namespace dc = nccomp::drivers::can;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  try {
    dc::CanConfig c = dc::parse_can_config(text, "fuzz.toml");
    // A map that validated must decode any frame on any of its IDs without trouble.
    dc::FrameDecoder dec(c.mapping);
    nccomp::core::Event ev;
    for (const auto& f : c.mapping.rx) {
      const std::size_t n = std::min<std::size_t>(size, f.length_bytes);
      (void)dec.decode(f.id, f.extended, std::span<const std::uint8_t>(data, n), 0, ev);
    }
    std::array<std::uint8_t, dc::kMaxPayloadBytes> p{};
    for (const auto& r : c.mapping.offsets) {
      (void)dc::encode_offset(r, static_cast<double>(size) - 100.0, p);
    }
  } catch (const nccomp::formats::DiagnosticsError&) {
  }
  return 0;
}
