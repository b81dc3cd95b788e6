// Fuzz target: nccompd's bus sections ([modbus], [can]) through the daemon's loader — the
// drivers' parsers on the loader's tables, the register cross-check, and the bus objects built
// (not started) from what was accepted. Any bytes end in a config or diagnostics, never a crash.
#include <cstddef>
#include <cstdint>
#include <exception>
#include <string_view>

#include "daemon/config/builtin_sections.hpp"
#include "daemon/config/config.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  namespace cfg = nccomp::daemon::config;
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  auto r = cfg::load_string(text, "fuzz.toml", "/nonexistent-nccomp-fuzz");
  if (!r.config) {
    for (const auto& d : r.diagnostics.items()) {
      (void)nccomp::formats::format(d);
    }
    return 0;
  }
  for (const auto* p : cfg::section_parsers()) {
    if (p->provides_bus() && r.config->has(p->name())) {
      try {
        auto bus = p->make_bus(*r.config);
        if (bus) {
          (void)bus->status();
        }
      } catch (const std::exception&) {
        // A bus may refuse what the parser let through only with a clear exception.
      }
    }
  }
  return 0;
}
