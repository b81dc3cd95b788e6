// Fuzz target: the daemon's config loader (TOML syntax, every built-in section, cross-checks,
// engine construction). Any bytes must end in a config or in diagnostics, never in a crash.
#include <cstddef>
#include <cstdint>
#include <exception>
#include <string_view>

#include "daemon/config/builtin_sections.hpp"
#include "daemon/config/config.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  namespace cfg = nccomp::daemon::config;
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  // A base directory that does not exist: includes fail with a diagnostic, nothing is read.
  auto r = cfg::load_string(text, "fuzz.toml", "/nonexistent-nccomp-fuzz");
  if (r.config) {
    try {
      auto engine = cfg::build_engine(*r.config);
      (void)engine->register_count();
    } catch (const std::exception&) {
      // The engine's own validation (e.g. a rate limit the limiter refuses) is a valid outcome.
    }
  } else {
    for (const auto& d : r.diagnostics.items()) {
      (void)nccomp::formats::format(d);
    }
  }
  return 0;
}
