#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <map>
#include <sstream>
#include <stdexcept>
#include <string>

#include "core/calib/drift_estimator.hpp"
#include "core/calib/state.hpp"

namespace nccomp::core::calib {

namespace {

constexpr std::string_view kHeader = "nccomp_calib_state";

const char* state_problem_v1(const CalibState& s) noexcept;

// One walk over every field, shared by writer and reader, so they cannot drift apart.
template <typename State, typename F>
void visit_fields(State& s, std::int64_t version, F&& f) {
  f(std::string("phase"), s.phase);
  auto& r = s.result;
  f(std::string("result.dx_touch_lateral_um"), r.dx_touch_lateral_um);
  f(std::string("result.dx_touch_axial_um"), r.dx_touch_axial_um);
  f(std::string("result.dy_touch_um"), r.dy_touch_um);
  f(std::string("result.dz_touch_um"), r.dz_touch_um);
  f(std::string("result.dx_r_um"), r.dx_r_um);
  f(std::string("result.dx_a_um"), r.dx_a_um);
  f(std::string("result.dy_um"), r.dy_um);
  f(std::string("result.dz_um"), r.dz_um);
  f(std::string("result.probe_lateral_um"), r.probe_lateral_um);
  f(std::string("result.probe_axial_um"), r.probe_axial_um);
  f(std::string("result.pivot_um"), r.pivot_um);
  f(std::string("result.lateral_grinds"), r.lateral_grinds);
  f(std::string("result.end_face_grinds"), r.end_face_grinds);
  f(std::string("result.time_s"), r.time_s);
  f(std::string("grind_correction_um"), s.grind_correction_um);
  f(std::string("grinds"), s.grinds);
  for (std::size_t i = 0; i < kSlotCount; ++i) {
    const std::string n = "nominal." + std::to_string(i) + ".";
    auto& nom = s.nominals[i];
    f(n + "valid", nom.valid);
    f(n + "direction", nom.direction);
    f(n + "position_mm", nom.position_mm);
    f(n + "time_s", nom.time_s);
    f(n + "temp_c", nom.temp_c);
  }
  for (std::size_t i = 0; i < kSlotCount; ++i) {
    const std::string n = "model." + std::to_string(i) + ".";
    auto& m = s.models[i];
    f(n + "anchored", m.anchored);
    f(n + "touch_sets", m.touch_sets);
    f(n + "anchor_time_s", m.anchor_time_s);
    f(n + "anchor_drift_um", m.anchor_drift_um);
    f(n + "anchor_temp_c", m.anchor_temp_c);
    f(n + "asymptote_um", m.asymptote_um);
    f(n + "slope_um_per_c", m.slope_um_per_c);
    f(n + "sum_w", m.sum_w);
    f(n + "sum_t", m.sum_t);
    f(n + "sum_d", m.sum_d);
    f(n + "sum_tt", m.sum_tt);
    f(n + "sum_td", m.sum_td);
  }
  for (std::size_t i = 0; i < kSlotCount; ++i) {
    const std::string n = "creep." + std::to_string(i) + ".";
    f(n + "start_time_s", s.creeps[i].start_time_s);
    f(n + "offset_um", s.creeps[i].offset_um);
  }
  f(std::string("history_count"), s.history_count);
  f(std::string("history_next"), s.history_next);
  for (std::size_t i = 0; i < kHistorySize; ++i) {
    const std::string n = "history." + std::to_string(i) + ".";
    auto& h = s.history[i];
    f(n + "time_s", h.time_s);
    f(n + "temp_c", h.temp_c);
    for (std::size_t k = 0; k < kSlotCount; ++k) {
      f(n + "drift_um." + std::to_string(k), h.drift_um[k]);
    }
  }
  f(std::string("last_set_time_s"), s.last_set_time_s);
  if (version < 2) {
    return;
  }
  for (std::size_t i = 0; i < kSlotCount; ++i) {
    const std::string n = "estimate." + std::to_string(i) + ".";
    auto& e = s.estimates[i];
    f(n + "valid", e.valid);
    f(n + "time_s", e.time_s);
    for (std::size_t k = 0; k < e.x.size(); ++k) {
      f(n + "x." + std::to_string(k), e.x[k]);
    }
    for (std::size_t k = 0; k < e.p.size(); ++k) {
      f(n + "p." + std::to_string(k), e.p[k]);
    }
  }
  auto& h = s.shifts;
  f(std::string("shifts.count"), h.shifts);
  f(std::string("shifts.current_knots"), h.current_knots);
  f(std::string("shifts.last_since_s"), h.last_since_s);
  for (std::size_t k = 0; k < kSlotCount; ++k) {
    f("shifts.last_drift_um." + std::to_string(k), h.last_drift_um[k]);
  }
  for (std::size_t j = 0; j < kPriorKnots; ++j) {
    const std::string n = "shifts.knot." + std::to_string(j) + ".";
    f(n + "weight", h.weight[j]);
    for (std::size_t k = 0; k < kSlotCount; ++k) {
      f(n + "sum_um." + std::to_string(k), h.sum_um[k][j]);
      f(n + "current_um." + std::to_string(k), h.current_um[k][j]);
    }
  }
  if (version < 3) {
    return;
  }
  f(std::string("shifts.increment_weight"), h.increment_weight);
  for (std::size_t k = 0; k < kSlotCount; ++k) {
    f("shifts.increment_sq_sum_um2." + std::to_string(k), h.increment_sq_sum_um2[k]);
  }
}

std::string format_double(double v) {
  if (std::isnan(v)) {
    return "nan";
  }
  char buf[64];
  const auto res = std::to_chars(buf, buf + sizeof buf, v);  // shortest round-trip form
  return std::string(buf, res.ptr);
}

[[noreturn]] void fail(std::size_t line, const std::string& key, const std::string& why) {
  std::ostringstream s;
  s << "calibration state, line " << line;
  if (!key.empty()) {
    s << ", key " << key;
  }
  s << ": " << why;
  throw std::invalid_argument(s.str());
}

double parse_double(std::string_view v, std::size_t line, const std::string& key) {
  if (v == "nan") {
    return kNaN;
  }
  double out = 0.0;
  const auto res = std::from_chars(v.data(), v.data() + v.size(), out);
  if (res.ec != std::errc() || res.ptr != v.data() + v.size() || !std::isfinite(out)) {
    fail(line, key, "not a finite number or nan: '" + std::string(v) + "'");
  }
  return out;
}

std::int64_t parse_int(std::string_view v, std::size_t line, const std::string& key) {
  std::int64_t out = 0;
  const auto res = std::from_chars(v.data(), v.data() + v.size(), out);
  if (res.ec != std::errc() || res.ptr != v.data() + v.size()) {
    fail(line, key, "not an integer: '" + std::string(v) + "'");
  }
  return out;
}

}  // namespace

const char* to_string(Phase phase) noexcept {
  switch (phase) {
    case Phase::kUncalibrated:
      return "uncalibrated";
    case Phase::kReferenceTouches:
      return "reference-touches";
    case Phase::kTestGrindLateral:
      return "test-grind-lateral";
    case Phase::kTestGrindEndFace:
      return "test-grind-end-face";
    case Phase::kNominalTouches:
      return "nominal-touches";
    case Phase::kReady:
      return "ready";
  }
  return "?";
}

void shift_times(CalibState& s, double delta_s) noexcept {
  s.result.time_s += delta_s;
  for (auto& n : s.nominals) {
    n.time_s += delta_s;
  }
  for (auto& m : s.models) {
    m.anchor_time_s += delta_s;
  }
  for (auto& c : s.creeps) {
    c.start_time_s += delta_s;
  }
  for (auto& h : s.history) {
    h.time_s += delta_s;
  }
  s.last_set_time_s += delta_s;
  for (auto& e : s.estimates) {
    e.time_s += delta_s;
  }
}

void convert_from_v1(CalibState& s) noexcept {
  s.version = CalibState::kVersion;
  s.estimates = {};
  s.shifts = {};
  // Version 1 kept the drift of the touch sets since the nominals in the history only.
  const double t0 = s.nominals[0].time_s;
  if (s.phase != Phase::kReady || !std::isfinite(t0)) {
    return;
  }
  const auto n = static_cast<std::size_t>(std::clamp(s.history_count, 0, 64));
  for (std::size_t i = 0; i < n; ++i) {
    const auto first = static_cast<std::size_t>(
        (s.history_next - s.history_count + static_cast<std::int32_t>(kHistorySize)) %
        static_cast<std::int32_t>(kHistorySize));
    const auto& h = s.history[(first + i) % kHistorySize];
    if (std::isfinite(h.time_s) && h.time_s > t0) {
      add_shift_point(s.shifts, h.time_s - t0, h.drift_um);
    }
  }
}

void convert_from_v2(CalibState& s) noexcept {
  s.version = CalibState::kVersion;
  s.shifts.increment_sq_sum_um2 = {};
  s.shifts.increment_weight = 0.0;
}

std::string to_text(const CalibState& state) {
  std::ostringstream out;
  out << kHeader << ' ' << CalibState::kVersion << '\n';
  visit_fields(state, CalibState::kVersion, [&](const std::string& key, const auto& v) {
    using T = std::decay_t<decltype(v)>;
    out << key << ' ';
    if constexpr (std::is_same_v<T, Phase>) {
      out << static_cast<int>(v);
    } else if constexpr (std::is_same_v<T, double>) {
      out << format_double(v);
    } else {
      out << v;
    }
    out << '\n';
  });
  return out.str();
}

CalibState from_text(std::string_view text) {
  std::map<std::string, std::pair<std::string, std::size_t>> values;
  std::size_t line_no = 0;
  bool header = false;
  std::int64_t version = 0;
  while (!text.empty()) {
    const auto nl = text.find('\n');
    std::string_view line = text.substr(0, nl);
    text = nl == std::string_view::npos ? std::string_view{} : text.substr(nl + 1);
    ++line_no;
    if (!line.empty() && line.back() == '\r') {
      line.remove_suffix(1);
    }
    if (line.empty() || line.front() == '#') {
      continue;
    }
    const auto sp = line.find(' ');
    if (sp == std::string_view::npos) {
      fail(line_no, "", "expected 'key value'");
    }
    const std::string key(line.substr(0, sp));
    const std::string_view value = line.substr(sp + 1);
    if (!header) {
      if (key != kHeader) {
        fail(line_no, key, "not a calibration state (expected header 'nccomp_calib_state')");
      }
      version = parse_int(value, line_no, key);
      if (version < 1 || version > CalibState::kVersion) {
        fail(line_no, key, "unsupported version '" + std::string(value) + "'");
      }
      header = true;
      continue;
    }
    if (!values.emplace(key, std::make_pair(std::string(value), line_no)).second) {
      fail(line_no, key, "duplicate key");
    }
  }
  if (!header) {
    fail(line_no, "", "empty (no header)");
  }
  CalibState s;
  std::size_t used = 0;
  visit_fields(s, version, [&](const std::string& key, auto& v) {
    using T = std::decay_t<decltype(v)>;
    const auto it = values.find(key);
    if (it == values.end()) {
      fail(line_no, key, "missing");
    }
    ++used;
    const auto& [text_value, line] = it->second;
    if constexpr (std::is_same_v<T, double>) {
      v = parse_double(text_value, line, key);
    } else {
      const std::int64_t i = parse_int(text_value, line, key);
      if (i < -1000000 || i > 1000000) {
        fail(line, key, "out of range");
      }
      if constexpr (std::is_same_v<T, Phase>) {
        if (i < 0 || i > static_cast<int>(Phase::kReady)) {
          fail(line, key, "unknown phase");
        }
        v = static_cast<Phase>(i);
      } else {
        v = static_cast<T>(i);
      }
    }
  });
  if (used != values.size()) {
    for (const auto& [key, value] : values) {
      bool known = false;
      const std::string& name = key;  // clang 14 cannot capture a structured binding
      visit_fields(s, version,
                   [&](const std::string& k, const auto&) { known = known || k == name; });
      if (!known) {
        fail(value.second, key, "unknown key");
      }
    }
  }
  if (version == 1) {
    if (state_problem_v1(s) == nullptr) {
      convert_from_v1(s);
    }
  } else if (version == 2) {
    convert_from_v2(s);
  }
  validate(s);
  return s;
}

namespace {

// The checks of the version-1 fields.
const char* state_problem_v1(const CalibState& s) noexcept {
  if (static_cast<int>(s.phase) > static_cast<int>(Phase::kReady)) {
    return "phase: unknown";
  }
  if (s.history_count < 0 || s.history_count > static_cast<std::int32_t>(kHistorySize)) {
    return "history_count: must be 0..64";
  }
  if (s.history_next < 0 || s.history_next >= static_cast<std::int32_t>(kHistorySize)) {
    return "history_next: must be 0..63";
  }
  if (s.grinds < 0 || s.result.lateral_grinds < 0 || s.result.end_face_grinds < 0) {
    return "grinds: must be >= 0";
  }
  const bool calibrated = s.phase == Phase::kNominalTouches || s.phase == Phase::kReady;
  if (calibrated && !(std::isfinite(s.result.dx_r_um) && std::isfinite(s.result.dy_um) &&
                      std::isfinite(s.result.dz_um))) {
    return "result: a calibrated state needs finite dx_r_um, dy_um, dz_um";
  }
  if ((s.phase == Phase::kTestGrindLateral || s.phase == Phase::kTestGrindEndFace) &&
      !std::isfinite(s.grind_correction_um)) {
    return "grind_correction_um: a test grind in progress needs a finite correction";
  }
  for (std::size_t i = 0; i < kSlotCount; ++i) {
    const auto& n = s.nominals[i];
    if (n.valid != 0 && n.valid != 1) {
      return "nominal.N.valid: must be 0 or 1";
    }
    if (n.direction != 1 && n.direction != -1) {
      return "nominal.N.direction: must be 1 or -1";
    }
    if (s.phase == Phase::kReady &&
        !(n.valid == 1 && std::isfinite(n.position_mm) && std::isfinite(n.time_s))) {
      return "nominal.N: phase ready needs a valid nominal with position and time";
    }
    const auto& m = s.models[i];
    if (m.anchored != 0 && m.anchored != 1) {
      return "model.N.anchored: must be 0 or 1";
    }
    if (m.anchored == 1) {
      if (!(std::isfinite(m.anchor_time_s) && std::isfinite(m.anchor_drift_um) &&
            std::isfinite(m.asymptote_um) && std::isfinite(m.slope_um_per_c))) {
        return "model.N: an anchored model needs finite anchor, asymptote and slope";
      }
      if (!(std::isfinite(s.creeps[i].start_time_s) && std::isfinite(s.creeps[i].offset_um))) {
        return "creep.N: an anchored model needs a finite creep";
      }
    }
    if (!(std::isfinite(m.sum_w) && std::isfinite(m.sum_t) && std::isfinite(m.sum_d) &&
          std::isfinite(m.sum_tt) && std::isfinite(m.sum_td) && m.sum_w >= 0.0)) {
      return "model.N: fit sums must be finite (sum_w >= 0)";
    }
  }
  return nullptr;
}

}  // namespace

const char* state_problem(const CalibState& s) noexcept {
  if (s.version != CalibState::kVersion) {
    return "version: unsupported";
  }
  if (const char* p = state_problem_v1(s)) {
    return p;
  }
  for (const auto& e : s.estimates) {
    if (e.valid != 0 && e.valid != 1) {
      return "estimate.N.valid: must be 0 or 1";
    }
    if (e.valid == 1) {
      bool finite = std::isfinite(e.time_s);
      for (const double v : e.x) finite = finite && std::isfinite(v);
      for (const double v : e.p) finite = finite && std::isfinite(v);
      if (!finite) {
        return "estimate.N: a valid estimate needs finite time, state and covariance";
      }
      for (std::size_t k = 0; k < e.x.size(); ++k) {
        if (e.p[k * e.x.size() + k] < 0.0) {
          return "estimate.N.p: negative variance";
        }
      }
    }
  }
  const auto& h = s.shifts;
  if (h.shifts < 0 || h.current_knots < 0 ||
      h.current_knots > static_cast<std::int32_t>(kPriorKnots)) {
    return "shifts: count must be >= 0, current_knots 0..24";
  }
  bool finite = std::isfinite(h.last_since_s) && h.last_since_s >= 0.0;
  for (const double v : h.last_drift_um) finite = finite && std::isfinite(v);
  for (std::size_t j = 0; j < kPriorKnots; ++j) {
    finite = finite && std::isfinite(h.weight[j]) && h.weight[j] >= 0.0;
    for (std::size_t k = 0; k < kSlotCount; ++k) {
      finite = finite && std::isfinite(h.sum_um[k][j]) && std::isfinite(h.current_um[k][j]);
    }
  }
  if (!finite) {
    return "shifts: weights (>= 0), sums, drifts and last_since_s (>= 0) must be finite";
  }
  bool increments = std::isfinite(h.increment_weight) && h.increment_weight >= 0.0;
  for (const double v : h.increment_sq_sum_um2) {
    increments = increments && std::isfinite(v) && v >= 0.0;
  }
  if (!increments) {
    return "shifts.increment_*: must be finite and >= 0";
  }
  return nullptr;
}

void validate(const CalibState& s) {
  if (const char* problem = state_problem(s)) {
    throw std::invalid_argument(std::string("calibration state, key ") + problem);
  }
}

}  // namespace nccomp::core::calib
