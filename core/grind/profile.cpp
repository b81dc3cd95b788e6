#include "core/grind/profile.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>
#include <system_error>

namespace nccomp::core::grind {
namespace {

std::string where(std::string_view source, std::size_t line) {
  return std::string(source) + ":" + std::to_string(line) + ": ";
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) {
    s.remove_prefix(1);
  }
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r')) {
    s.remove_suffix(1);
  }
  return s;
}

// from_chars rejects a leading '+', which spreadsheets write; accept it explicitly.
bool parse_number(std::string_view field, double& out) {
  if (!field.empty() && field.front() == '+') {
    field.remove_prefix(1);
  }
  if (field.empty()) {
    return false;
  }
  const auto* first = field.data();
  const auto* last = first + field.size();
  const auto [ptr, ec] = std::from_chars(first, last, out);
  return ec == std::errc() && ptr == last;
}

std::string show(std::string_view field) {
  constexpr std::size_t kMax = 40;
  std::string s(field.substr(0, kMax));
  for (char& c : s) {
    if (static_cast<unsigned char>(c) < 0x20 || static_cast<unsigned char>(c) >= 0x7f) {
      c = '?';
    }
  }
  return "'" + s + (field.size() > kMax ? "...'" : "'");
}

}  // namespace

double UniformProfile::interpolate(double z_mm) const noexcept {
  const double x = (z_mm - z0_mm) / spacing_mm;
  if (!(x > 0.0)) {
    return u_mm.front();
  }
  const auto n = u_mm.size();
  if (x >= static_cast<double>(n - 1)) {
    return u_mm.back();
  }
  const auto i = static_cast<std::size_t>(x);
  const double f = x - static_cast<double>(i);
  return u_mm[i] + f * (u_mm[i + 1] - u_mm[i]);
}

ProfileCsvParser::ProfileCsvParser(std::string_view source) : source_(source) {}

void ProfileCsvParser::feed(std::string_view chunk) {
  if (finished_) {
    throw std::logic_error("ProfileCsvParser: feed after finish");
  }
  while (!chunk.empty()) {
    const auto eol = chunk.find('\n');
    if (eol == std::string_view::npos) {
      if (pending_.size() + chunk.size() > kMaxProfileCsvLineBytes) {
        too_long(line_no_ + 1);
      }
      pending_.append(chunk);
      return;
    }
    const auto piece = chunk.substr(0, eol);
    chunk.remove_prefix(eol + 1);
    if (pending_.empty()) {
      line(piece);
    } else {
      if (pending_.size() + piece.size() > kMaxProfileCsvLineBytes) {
        too_long(line_no_ + 1);
      }
      pending_.append(piece);
      const std::string whole = std::move(pending_);
      pending_.clear();
      line(whole);
    }
  }
}

void ProfileCsvParser::too_long(std::size_t line_no) const {
  throw std::invalid_argument(where(source_, line_no) + "line longer than " +
                              std::to_string(kMaxProfileCsvLineBytes) + " characters");
}

void ProfileCsvParser::line(std::string_view text) {
  ++line_no_;
  if (text.size() > kMaxProfileCsvLineBytes) {
    too_long(line_no_);
  }
  const std::size_t line_no = line_no_;
  const auto line = trim(text);
  if (line.empty() || line.front() == '#') {
    return;
  }
  const auto comma = line.find(',');
  if (comma == std::string_view::npos) {
    throw std::invalid_argument(where(source_, line_no) + "expected two fields 'z_mm,u_mm', got " +
                                show(line));
  }
  const auto zf = trim(line.substr(0, comma));
  const auto uf = trim(line.substr(comma + 1));
  if (uf.find(',') != std::string_view::npos) {
    throw std::invalid_argument(where(source_, line_no) +
                                "expected two fields 'z_mm,u_mm', got more: " + show(line));
  }
  if (first_content_ && zf == "z_mm" && uf == "u_mm") {
    first_content_ = false;
    return;
  }
  first_content_ = false;
  double z = 0.0;
  double u = 0.0;
  if (!parse_number(zf, z)) {
    throw std::invalid_argument(where(source_, line_no) + "z_mm is not a number: " + show(zf));
  }
  if (!parse_number(uf, u)) {
    throw std::invalid_argument(where(source_, line_no) + "u_mm is not a number: " + show(uf));
  }
  if (!std::isfinite(z) || !std::isfinite(u)) {
    throw std::invalid_argument(where(source_, line_no) + "value is not finite (NaN or inf)");
  }
  if (!out_.z_mm.empty() && !(z > out_.z_mm.back())) {
    throw std::invalid_argument(where(source_, line_no) + "z_mm must increase strictly: " +
                                std::to_string(z) + " after " + std::to_string(out_.z_mm.back()));
  }
  if (out_.z_mm.size() >= kMaxProfileSamples) {
    throw std::invalid_argument(where(source_, line_no) + "more than " +
                                std::to_string(kMaxProfileSamples) + " samples");
  }
  out_.z_mm.push_back(z);
  out_.u_mm.push_back(u);
  out_.line.push_back(line_no);
}

SampledProfile ProfileCsvParser::finish() {
  if (finished_) {
    throw std::logic_error("ProfileCsvParser: finish twice");
  }
  finished_ = true;
  if (!pending_.empty()) {  // the last line has no line end
    const std::string last = std::move(pending_);
    pending_.clear();
    line(last);
  }
  if (out_.z_mm.size() < 2) {
    throw std::invalid_argument(source_ + ": needs at least 2 samples, got " +
                                std::to_string(out_.z_mm.size()));
  }
  return std::move(out_);
}

SampledProfile parse_profile_csv(std::string_view text, std::string_view source) {
  ProfileCsvParser parser(source);
  parser.feed(text);
  return parser.finish();
}

namespace {

// Index of the first sample that breaks uniformity (n if none) and where it should be.
std::size_t first_nonuniform(const SampledProfile& s, double dz, double& expect_z) {
  const std::size_t n = s.z_mm.size();
  // Uniform: every step equals the first (the operator's view: "line 4 breaks the spacing")
  // and the samples do not drift from the mean grid the computation uses.
  const double step0 = s.z_mm[1] - s.z_mm[0];
  for (std::size_t i = 1; i < n; ++i) {
    if (std::abs(s.z_mm[i] - s.z_mm[i - 1] - step0) > 1e-6 * step0) {
      expect_z = s.z_mm[i - 1] + step0;
      return i;
    }
  }
  for (std::size_t i = 1; i < n; ++i) {
    const double on_grid = s.z_mm.front() + static_cast<double>(i) * dz;
    if (std::abs(s.z_mm[i] - on_grid) > 1e-6 * dz) {
      expect_z = on_grid;
      return i;
    }
  }
  return n;
}

double checked_spacing(const SampledProfile& s, std::string_view source) {
  const std::size_t n = s.z_mm.size();
  if (n < 2 || s.u_mm.size() != n) {
    throw std::invalid_argument(std::string(source) + ": needs at least 2 samples");
  }
  const double span = s.z_mm.back() - s.z_mm.front();
  if (!(span > 0.0)) {
    throw std::invalid_argument(std::string(source) + ": z range is empty");
  }
  return span / static_cast<double>(n - 1);
}

}  // namespace

UniformProfile to_uniform(SampledProfile&& s, double resample_spacing_mm, std::string_view source) {
  const double dz = checked_spacing(s, source);
  double expect_z = 0.0;
  if (first_nonuniform(s, dz, expect_z) == s.z_mm.size()) {
    const double z0 = s.z_mm.front();
    UniformProfile out{z0, dz, std::move(s.u_mm)};
    s = SampledProfile{};  // the z and line arrays are not needed any more
    return out;
  }
  return to_uniform(static_cast<const SampledProfile&>(s), resample_spacing_mm, source);
}

UniformProfile to_uniform(const SampledProfile& s, double resample_spacing_mm,
                          std::string_view source) {
  const std::size_t n = s.z_mm.size();
  const double dz = checked_spacing(s, source);
  const double span = s.z_mm.back() - s.z_mm.front();
  double expect_z = 0.0;
  const std::size_t bad = first_nonuniform(s, dz, expect_z);
  if (bad == n) {
    return UniformProfile{s.z_mm.front(), dz, s.u_mm};
  }
  if (!(resample_spacing_mm > 0.0) || !std::isfinite(resample_spacing_mm)) {
    const std::size_t line = s.line.size() == n ? s.line[bad] : bad + 1;
    throw std::invalid_argument(where(source, line) + "samples are not uniformly spaced (z = " +
                                std::to_string(s.z_mm[bad]) + ", uniform spacing would put it at " +
                                std::to_string(expect_z) + "); give a resampling spacing");
  }
  const double count = std::floor(span / resample_spacing_mm * (1.0 + 1e-12)) + 1.0;
  if (count > static_cast<double>(kMaxProfileSamples)) {
    throw std::invalid_argument(std::string(source) + ": resampling would give more than " +
                                std::to_string(kMaxProfileSamples) + " samples");
  }
  UniformProfile out{s.z_mm.front(), resample_spacing_mm, {}};
  const auto m = static_cast<std::size_t>(count);
  out.u_mm.resize(m);
  std::size_t j = 0;
  for (std::size_t i = 0; i < m; ++i) {
    const double z = out.z_at(static_cast<std::ptrdiff_t>(i));
    while (j + 2 < n && s.z_mm[j + 1] < z) {
      ++j;
    }
    const double f = std::clamp((z - s.z_mm[j]) / (s.z_mm[j + 1] - s.z_mm[j]), 0.0, 1.0);
    out.u_mm[i] = s.u_mm[j] + f * (s.u_mm[j + 1] - s.u_mm[j]);
  }
  return out;
}

Family parse_family(std::string_view name) {
  if (name == "straight") return Family::kStraight;
  if (name == "convex") return Family::kConvexCrown;
  if (name == "concave") return Family::kConcaveCrown;
  if (name == "cvc") return Family::kCvc;
  if (name == "sine") return Family::kSine;
  if (name == "poly") return Family::kPolynomial;
  throw std::invalid_argument("unknown profile family " + show(name) +
                              " (straight, convex, concave, cvc, sine, poly)");
}

UniformProfile generate_profile(const FamilySpec& spec) {
  const auto finite = [](double v, const char* what) {
    if (!std::isfinite(v)) {
      throw std::invalid_argument(std::string("profile family: ") + what + " must be finite");
    }
  };
  finite(spec.z_from_mm, "z_from_mm");
  finite(spec.z_to_mm, "z_to_mm");
  finite(spec.offset_mm, "offset_mm");
  finite(spec.slope, "slope");
  finite(spec.height_mm, "height_mm");
  finite(spec.amplitude_mm, "amplitude_mm");
  finite(spec.phase_rad, "phase");
  for (double c : spec.coef) {
    finite(c, "every coefficient");
  }
  if (!(spec.z_to_mm > spec.z_from_mm)) {
    throw std::invalid_argument("profile family: z_to_mm must be greater than z_from_mm");
  }
  if (!(spec.spacing_mm > 0.0) || !std::isfinite(spec.spacing_mm)) {
    throw std::invalid_argument("profile family: spacing_mm must be > 0");
  }
  const double count =
      std::floor((spec.z_to_mm - spec.z_from_mm) / spec.spacing_mm * (1.0 + 1e-12)) + 1.0;
  if (count > static_cast<double>(kMaxProfileSamples)) {
    throw std::invalid_argument("profile family: more than " + std::to_string(kMaxProfileSamples) +
                                " samples");
  }
  if (count < 2.0) {
    throw std::invalid_argument("profile family: the range holds fewer than 2 samples");
  }
  const double mid = 0.5 * (spec.z_from_mm + spec.z_to_mm);
  const double half = 0.5 * (spec.z_to_mm - spec.z_from_mm);
  const double ref = spec.z_ref_given ? spec.z_ref_mm : mid;
  finite(ref, "z_ref_mm");
  switch (spec.family) {
    case Family::kCvc:
      if (spec.coef.size() != 4) {
        throw std::invalid_argument(
            "profile family cvc: needs exactly 4 coefficients c0..c3, got " +
            std::to_string(spec.coef.size()));
      }
      break;
    case Family::kPolynomial:
      if (spec.coef.empty() || spec.coef.size() > 16) {
        throw std::invalid_argument("profile family poly: needs 1 to 16 coefficients, got " +
                                    std::to_string(spec.coef.size()));
      }
      break;
    case Family::kSine:
      if (!(spec.wavelength_mm > 0.0) || !std::isfinite(spec.wavelength_mm)) {
        throw std::invalid_argument("profile family sine: wavelength_mm must be > 0");
      }
      break;
    default:
      break;
  }
  UniformProfile out{spec.z_from_mm, spec.spacing_mm, {}};
  const auto n = static_cast<std::size_t>(count);
  out.u_mm.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    const double z = out.z_at(static_cast<std::ptrdiff_t>(i));
    const double x = z - ref;
    double u = 0.0;
    switch (spec.family) {
      case Family::kStraight:
        u = spec.offset_mm + spec.slope * x;
        break;
      case Family::kConvexCrown:
      case Family::kConcaveCrown: {
        const double q = (z - mid) / half;
        const double c = spec.height_mm * (1.0 - q * q);
        u = spec.offset_mm + (spec.family == Family::kConvexCrown ? c : -c);
        break;
      }
      case Family::kSine:
        u = spec.offset_mm +
            spec.amplitude_mm *
                std::sin(2.0 * std::numbers::pi * x / spec.wavelength_mm + spec.phase_rad);
        break;
      case Family::kCvc:
      case Family::kPolynomial:
        for (auto k = spec.coef.size(); k-- > 0;) {  // Horner
          u = u * x + spec.coef[k];
        }
        break;
    }
    if (!std::isfinite(u)) {
      throw std::invalid_argument("profile family: value at z = " + std::to_string(z) +
                                  " mm is not finite");
    }
    out.u_mm[i] = u;
  }
  return out;
}

}  // namespace nccomp::core::grind
