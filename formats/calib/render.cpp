#include "formats/calib/render.hpp"

#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdarg>
#include <cstdio>

namespace nccomp::formats::calib {

namespace {

/// printf into a string (formats/ uses the standard library only, no fmt).
[[gnu::format(printf, 1, 2)]] std::string text(const char* format, ...) {
  std::va_list args;
  va_start(args, format);
  std::va_list again;
  va_copy(again, args);
  const int n = std::vsnprintf(nullptr, 0, format, args);
  va_end(args);
  std::string out(n > 0 ? static_cast<std::size_t>(n) : 0U, '\0');
  if (n > 0) std::vsnprintf(out.data(), out.size() + 1, format, again);
  va_end(again);
  return out;
}

/// A number as short as it reads back exactly, without an exponent where it is moderate
/// ("3600", "0.5", "1000000").
std::string shortest(double v) {
  char buf[400];
  const auto r = std::fabs(v) < 1e15
                     ? std::to_chars(buf, buf + sizeof buf, v, std::chars_format::fixed)
                     : std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, r.ptr);
}

}  // namespace

using core::AlarmCode;
using core::calib::Phase;

const char* axis_name(std::int32_t a) noexcept {
  switch (a) {
    case 0:
      return "X";
    case 1:
      return "Y";
    case 2:
      return "Z";
    default:
      return "-";
  }
}

const char* alarm_name(AlarmCode code) noexcept {
  switch (code) {
    case AlarmCode::kOffsetNonFinite:
      return "offset-non-finite";
    case AlarmCode::kOffsetBeyondAbsoluteLimit:
      return "offset-beyond-absolute-limit";
    case AlarmCode::kOffsetSlewLimited:
      return "offset-slew-limited";
    case AlarmCode::kRecalibrationImplausible:
      return "recalibration-implausible";
    case AlarmCode::kTouchScatter:
      return "touch-scatter";
    case AlarmCode::kRecalibrationDue:
      return "recalibration-due";
    case AlarmCode::kTouchSetIncomplete:
      return "touch-set-incomplete";
    case AlarmCode::kCalibrationOutOfRange:
      return "calibration-out-of-range";
    case AlarmCode::kTouchUnexpected:
      return "touch-unexpected";
    case AlarmCode::kTestGrindNotConverging:
      return "test-grind-not-converging";
    case AlarmCode::kRecalibrationApplied:
      return "recalibration-applied";
    case AlarmCode::kCalibrationComplete:
      return "calibration-complete";
    case AlarmCode::kCalibrationInvalidInput:
      return "calibration-invalid-input";
    default:
      return "other";
  }
}

namespace {

const char* severity_name(core::Severity s) {
  switch (s) {
    case core::Severity::kInfo:
      return "info";
    case core::Severity::kWarning:
      return "WARNING";
    case core::Severity::kAlarm:
      return "ALARM";
  }
  return "?";
}

}  // namespace

std::string hint(const core::calib::CalibSnapshot& s) {
  const auto& p = s.progress;
  const auto progress = [&] {
    return text("X lateral %d/%d, X axial %d/%d, Y %d/%d, Z %d/%d", p.count[0], p.required,
                p.count[1], p.required, p.count[2], p.required, p.count[3], p.required);
  };
  switch (s.state.phase) {
    case Phase::kUncalibrated:
      return "not calibrated: 'begin' starts an initial calibration";
    case Phase::kReferenceTouches:
      return "touch the reference disk with the reference probe (" + progress() + ")";
    case Phase::kTestGrindLateral:
      return text(
          "grind the blank from +X and -X with dx %+.3f um, then 'facets "
          "lateral <c+ mm> <c- mm>'",
          s.state.grind_correction_um);
    case Phase::kTestGrindEndFace:
      return text(
          "grind the end face from +X and -X with dx %+.3f um, then 'facets "
          "end-face <c+ mm> <c- mm>'",
          s.state.grind_correction_um);
    case Phase::kNominalTouches:
      return "touch the test body with the machine probe, X twice (A at 90 deg for axial) (" +
             progress() + ")";
    case Phase::kReady:
      return text(
          "calibrated; machine-probe touches recalibrate (set: %s; interval %s s%s)",
          progress().c_str(), shortest(s.recalibration_interval_s).c_str(),
          s.request == core::calib::RequestCode::kRecalibration ? "; recalibration requested" : "");
  }
  return "";
}

std::string alarm_line(const core::AlarmEvent& a) {
  std::string o =
      text("  %s %d %s", severity_name(a.severity), static_cast<int>(a.code), alarm_name(a.code));
  if (a.code == AlarmCode::kOffsetSlewLimited || a.code == AlarmCode::kOffsetNonFinite ||
      a.code == AlarmCode::kOffsetBeyondAbsoluteLimit) {
    o += text(" register %d: target %+.3f um", a.subject, a.value);
  } else if (a.code == AlarmCode::kRecalibrationDue) {
    o += text(": %.0f s since the last touch set", a.value);
  } else if (a.code == AlarmCode::kTouchSetIncomplete) {
    o += text(": %.0f touches discarded", a.value);
  } else {
    o += text(" axis %s: %+.3f", axis_name(a.subject), a.value);
  }
  if (a.code == AlarmCode::kRecalibrationImplausible || a.code == AlarmCode::kTouchScatter) {
    o += " um, nothing applied";
  }
  o += '\n';
  return o;
}

std::string facet_line(core::calib::Face face, double chord_plus_mm, double chord_minus_mm,
                       const core::calib::FacetResult& r, core::calib::FacetRule rule) {
  std::string o = text("facets %s: c+ %.4f mm, c- %.4f mm -> %s",
                       face == core::calib::Face::kLateral ? "lateral" : "end-face", chord_plus_mm,
                       chord_minus_mm, core::calib::to_string(r.status));
  if (std::isfinite(r.error_um)) {
    o += text(", error %+.3f um (%s rule), grind %d", r.error_um, core::calib::to_string(rule),
              r.grinds);
  }
  if (r.status == core::calib::FacetStatus::kGrindAgain) {
    o += text("; grind again with dx %+.3f um", r.correction_um);
  } else if (r.status == core::calib::FacetStatus::kConverged) {
    o += text("; %s = %+.3f um", face == core::calib::Face::kLateral ? "dxR" : "dxA",
              r.correction_um);
  }
  o += '\n';
  return o;
}

std::string reference_line(const core::calib::CalibrationResult& r) {
  return text(
      "  reference touches: dx lateral %+.3f um, dx axial %+.3f um (pivot D "
      "%+.3f um), dy %+.3f um, dz %+.3f um\n",
      r.dx_touch_lateral_um, r.dx_touch_axial_um, r.dx_touch_axial_um - r.dx_touch_lateral_um,
      r.dy_touch_um, r.dz_touch_um);
}

std::string calibration_line(const core::calib::CalibrationResult& r) {
  return text(
      "  calibration: dxR %+.3f um, dxA %+.3f um, dy %+.3f um, dz %+.3f um; "
      "probe lateral %+.3f um, probe axial %+.3f um, pivot D %+.3f um; grinds "
      "%d + %d\n",
      r.dx_r_um, r.dx_a_um, r.dy_um, r.dz_um, r.probe_lateral_um, r.probe_axial_um, r.pivot_um,
      r.lateral_grinds, r.end_face_grinds);
}

std::string nominals_line(const core::calib::CalibState& s) {
  std::string o = "  nominals stored:";
  for (const auto& n : s.nominals) {
    o += text(" %.4f", n.position_mm);
  }
  o += " mm (X lateral, X axial, Y, Z)\n";
  return o;
}

std::string format_utc(double wall_s) {
  if (!std::isfinite(wall_s)) {
    return "never";
  }
  using namespace std::chrono;
  const sys_seconds t{seconds{static_cast<long long>(wall_s)}};
  const sys_days day = floor<days>(t);
  const year_month_day ymd{day};
  const hh_mm_ss hms{t - day};
  return text("%04d-%02u-%02u %02d:%02d:%02d UTC", static_cast<int>(ymd.year()),
              static_cast<unsigned>(ymd.month()), static_cast<unsigned>(ymd.day()),
              static_cast<int>(hms.hours().count()), static_cast<int>(hms.minutes().count()),
              static_cast<int>(hms.seconds().count()));
}

std::string status_block(const core::calib::CalibSnapshot& s, const std::string& when) {
  const auto& r = s.state.result;
  std::string o = when + " phase " + core::calib::to_string(s.state.phase) + "\n";
  o += text("  calibration: dxR %+.3f dxA %+.3f dy %+.3f dz %+.3f um\n", r.dx_r_um, r.dx_a_um,
            r.dy_um, r.dz_um);
  const char* names[] = {"X lateral", "X axial", "Y", "Z"};
  for (std::size_t k = 0; k < core::calib::kSlotCount; ++k) {
    const auto& n = s.state.nominals[k];
    const auto& m = s.state.models[k];
    if (n.valid == 1) {
      o += text(
          "  %-9s: nominal %.4f mm, last drift %+.3f um (%d sets), predicted %+.3f um, "
          "in force %+.3f um",
          names[k], n.position_mm, m.anchor_drift_um, m.touch_sets, s.predicted_um[k],
          s.correction_um[k]);
      if (std::isfinite(n.temp_c)) {
        o += text(", slope %+.3f um/degC (nominal at %.2f degC)", m.slope_um_per_c, n.temp_c);
      }
      o += '\n';
    }
  }
  for (std::size_t a = 0; a < 3; ++a) {
    o += text("  register %u (%s): target %+.3f um, written %+.3f um\n",
              static_cast<unsigned>(s.registers[a]), axis_name(static_cast<std::int32_t>(a)),
              s.target_um[a], s.written_um[a]);
  }
  return o;
}

}  // namespace nccomp::formats::calib
