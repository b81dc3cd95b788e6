// Any bytes into the profile CSV parser: a profile or std::invalid_argument, never a crash.
// Accepted profiles go on through the uniform-grid step, the slope fit and a small envelope, so
// whatever the parser lets through is something the computation can take.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string_view>

#include "core/grind/envelope.hpp"
#include "core/grind/local_rule.hpp"
#include "core/grind/profile.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  namespace g = nccomp::core::grind;
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  try {
    const auto s = g::parse_profile_csv(text, "fuzz.csv");
    for (std::size_t i = 0; i < s.z_mm.size(); ++i) {
      if (!std::isfinite(s.z_mm[i]) || !std::isfinite(s.u_mm[i]) ||
          (i > 0 && !(s.z_mm[i] > s.z_mm[i - 1]))) {
        __builtin_trap();  // the parser's contract
      }
    }
    const double span = s.z_mm.back() - s.z_mm.front();
    // Resample to at most ~1000 samples so a mutated input cannot ask for gigabytes.
    const auto p = g::to_uniform(s, span / 1000.0, "fuzz.csv");
    if (p.size() > 2000 || !(p.spacing_mm > 0.0)) {
      return 0;
    }
    const auto wheel = g::Wheel::from_arc_height(20.0 * p.spacing_mm, 0.5 * p.spacing_mm);
    const auto d = g::local_derivatives(p, g::FitSpec{});
    (void)g::local_rule_trajectory(p, d, wheel);
    (void)g::exact_trajectory(p, wheel);
  } catch (const std::invalid_argument&) {
  }
  return 0;
}
