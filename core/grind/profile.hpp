// The target roll profile P of S2: samples u(z) (mm), parsed from CSV text or generated from a
// family (straight, convex / concave parabolic crown, CVC cubic, sine, any polynomial).
// core/ is pure: the CSV parser takes the text and a name for the messages; the caller reads
// the file. Nothing here is real-time.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

namespace nccomp::core::grind {

/// Samples on a uniform grid z_i = z0_mm + i·spacing_mm.
struct UniformProfile {
  double z0_mm{0.0};
  double spacing_mm{0.0};
  std::vector<double> u_mm;

  [[nodiscard]] std::size_t size() const noexcept { return u_mm.size(); }
  [[nodiscard]] double z_at(std::ptrdiff_t i) const noexcept {
    return z0_mm + static_cast<double>(i) * spacing_mm;
  }
  [[nodiscard]] double z_last_mm() const noexcept {
    return z_at(static_cast<std::ptrdiff_t>(u_mm.size()) - 1);
  }
  /// Linear interpolation inside [z0, z_last]; the end value outside. Precondition: size ≥ 1.
  [[nodiscard]] double interpolate(double z_mm) const noexcept;
};

/// Samples as read, possibly non-uniform. `line` is the 1-based source line of each sample.
struct SampledProfile {
  std::vector<double> z_mm;
  std::vector<double> u_mm;
  std::vector<std::size_t> line;
};

/// Upper bound on samples accepted from any source (memory: 8 bytes per sample and array).
inline constexpr std::size_t kMaxProfileSamples = 200'000'000;

/// Longest CSV line accepted (a line without line ends cannot grow without bound).
inline constexpr std::size_t kMaxProfileCsvLineBytes = 4096;

/// Parses `z_mm,u_mm` CSV text. An optional header line `z_mm,u_mm`, blank lines, lines starting
/// with '#' and CR line ends are accepted. Every value must be a finite number; z strictly
/// increasing; at least 2 samples; lines of at most kMaxProfileCsvLineBytes. Throws
/// std::invalid_argument "<source>:<line>: <what>".
SampledProfile parse_profile_csv(std::string_view text, std::string_view source);

/// The same parser fed piece by piece (lines may be split anywhere between pieces), so that a
/// caller can read a file in chunks instead of holding all of its text: the result and the
/// errors are those of parse_profile_csv on the concatenated text.
class ProfileCsvParser {
 public:
  explicit ProfileCsvParser(std::string_view source);
  void feed(std::string_view chunk);
  /// The samples (throws if fewer than 2). Call once, after the last feed.
  SampledProfile finish();

 private:
  void line(std::string_view text);
  [[noreturn]] void too_long(std::size_t line_no) const;
  std::string source_;
  std::string pending_;  ///< an unfinished line from the previous pieces
  std::size_t line_no_{0};
  bool first_content_{true};
  bool finished_{false};
  SampledProfile out_;
};

/// A uniform profile from samples: if they are uniform (within 1e-6 of the spacing) they are
/// taken as they are; otherwise they are linearly resampled at `resample_spacing_mm` if > 0, or
/// std::invalid_argument names the first line that breaks uniformity.
UniformProfile to_uniform(const SampledProfile& samples, double resample_spacing_mm,
                          std::string_view source);
/// The same, taking the samples: uniform samples' u array is moved, not copied, and z and the
/// line numbers are freed (`samples` is left empty).
UniformProfile to_uniform(SampledProfile&& samples, double resample_spacing_mm,
                          std::string_view source);

enum class Family { kStraight, kConvexCrown, kConcaveCrown, kCvc, kSine, kPolynomial };

/// A profile family over [z_from_mm, z_to_mm] sampled every spacing_mm (the last sample is the
/// last grid point ≤ z_to). x = z − z_ref_mm (z_ref defaults to the middle of the range: NaN).
///  straight:  u = offset + slope·x
///  convex:    u = offset + height·(1 − (2(z − z_mid)/L)²)   (crown `height` in the middle)
///  concave:   u = offset − height·(1 − (2(z − z_mid)/L)²)   (valley `height` deep)
///  cvc:       u = Σ_{k≤3} coef[k]·x^k                        (exactly 4 coefficients)
///  sine:      u = offset + amplitude·sin(2π·x/wavelength + phase)
///  poly:      u = Σ coef[k]·x^k
struct FamilySpec {
  Family family{Family::kStraight};
  double z_from_mm{0.0};
  double z_to_mm{0.0};
  double spacing_mm{0.0};
  double z_ref_mm{0.0};
  bool z_ref_given{false};
  double offset_mm{0.0};
  double slope{0.0};
  double height_mm{0.0};
  double amplitude_mm{0.0};
  double wavelength_mm{0.0};
  double phase_rad{0.0};
  std::vector<double> coef;
};

/// Parses a family name: straight, convex, concave, cvc, sine, poly. Throws std::invalid_argument.
Family parse_family(std::string_view name);

/// Generates the family's samples. Throws std::invalid_argument naming the bad parameter.
UniformProfile generate_profile(const FamilySpec& spec);

}  // namespace nccomp::core::grind
