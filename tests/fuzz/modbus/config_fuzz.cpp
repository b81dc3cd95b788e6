// Any bytes as a [modbus] config: either a validated config or a DiagnosticsError, nothing else.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string_view>

#include "drivers/modbus/config.hpp"
#include "formats/toml/diagnostics.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  try {
    const auto c = nccomp::drivers::modbus::parse_modbus_config(text, "fuzz.toml");
    // A config that passed validation keeps its promises.
    for (const auto& b : c.blocks) {
      if (b.count == 0 || static_cast<std::uint32_t>(b.start) + b.count > 65536U) {
        std::abort();
      }
    }
    if (!(c.offset_write_rate_hz > 0.0) || !(c.poll_rate_hz > 0.0)) {
      std::abort();
    }
    for (const auto& g : c.groups) {
      for (const auto& f : g.fields) {
        if (f.mapped && !(f.min <= f.max)) {
          std::abort();
        }
      }
    }
    for (const auto& t : c.temperatures) {
      if (!(t.value.min <= t.value.max)) {
        std::abort();
      }
    }
  } catch (const nccomp::formats::DiagnosticsError&) {
  }
  return 0;
}
