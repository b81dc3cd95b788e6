// Any bytes into the profile CSV parser: a profile or std::invalid_argument, never a crash.
// The same bytes fed in three pieces (cut where the first two bytes say) must give the same
// samples or the same error as the whole text: `nccomp grind-path` reads files in chunks.
// Accepted profiles go on through the uniform-grid step, the slope fit, a small envelope and the
// two reports, so whatever the parser lets through is something the computation can take.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <string_view>

#include "core/grind/compare.hpp"
#include "core/grind/envelope.hpp"
#include "core/grind/local_rule.hpp"
#include "core/grind/profile.hpp"

namespace {

namespace g = nccomp::core::grind;

std::string parse_in_pieces(std::string_view text, std::size_t cut1, std::size_t cut2,
                            g::SampledProfile& out) {
  try {
    g::ProfileCsvParser parser("fuzz.csv");
    parser.feed(text.substr(0, cut1));
    parser.feed(text.substr(cut1, cut2 - cut1));
    parser.feed(text.substr(cut2));
    out = parser.finish();
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return {};
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  const std::size_t cut1 = size > 0 ? data[0] % (size + 1) : 0;
  const std::size_t cut2 = size > 1 ? cut1 + data[1] % (size - cut1 + 1) : cut1;
  g::SampledProfile pieces;
  const std::string pieces_error = parse_in_pieces(text, cut1, cut2, pieces);
  g::SampledProfile s;
  std::string whole_error;
  try {
    s = g::parse_profile_csv(text, "fuzz.csv");
  } catch (const std::invalid_argument& e) {
    whole_error = e.what();
  }
  if (whole_error != pieces_error) {
    __builtin_trap();  // chunked reading differs from the whole text
  }
  if (!whole_error.empty()) {
    return 0;
  }
  if (pieces.z_mm != s.z_mm || pieces.u_mm != s.u_mm || pieces.line != s.line) {
    __builtin_trap();
  }
  for (std::size_t i = 0; i < s.z_mm.size(); ++i) {
    if (!std::isfinite(s.z_mm[i]) || !std::isfinite(s.u_mm[i]) ||
        (i > 0 && !(s.z_mm[i] > s.z_mm[i - 1]))) {
      __builtin_trap();  // the parser's contract
    }
  }
  try {
    const double span = s.z_mm.back() - s.z_mm.front();
    // Resample to at most ~1000 samples so a mutated input cannot ask for gigabytes.
    const auto p = g::to_uniform(std::move(s), span / 1000.0, "fuzz.csv");
    if (p.size() > 2000 || !(p.spacing_mm > 0.0)) {
      return 0;
    }
    const auto wheel = g::Wheel::from_arc_height(20.0 * p.spacing_mm, 0.5 * p.spacing_mm);
    const g::LocalRule rule(p, g::FitSpec{}, wheel);
    const auto exact = g::exact_trajectory(p, wheel);
    (void)g::compare_rule_with_envelope(rule, exact, 1e-4);
    (void)g::unreachable_regions(rule, exact, 1e-4);
  } catch (const std::invalid_argument&) {
  }
  return 0;
}
