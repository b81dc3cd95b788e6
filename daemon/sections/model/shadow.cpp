#include "daemon/sections/model/shadow.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <utility>

#include "daemon/sections/model/model_choice.hpp"

namespace nccomp::daemon::sections {

namespace cm = core::model;

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr std::string_view kHistoryHeader = "nccomp_model_shadow 1";
constexpr std::size_t col(cm::Column c) { return static_cast<std::size_t>(c); }

double mean(std::span<const double> v) {
  double s = 0.0;
  for (const double x : v) s += x;
  return v.empty() ? kNaN : s / static_cast<double>(v.size());
}

std::string number_text(double v) { return fmt::format("{:.17g}", v); }

double parse_number(const std::string& s, std::size_t line) {
  std::size_t used = 0;
  double v = 0.0;
  try {
    v = std::stod(s, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != s.size() || s.empty()) {
    throw std::invalid_argument("line " + std::to_string(line) + ": '" + s + "' is not a number");
  }
  return v;
}

}  // namespace

void ModelScore::add_part(double mse_um2, std::uint64_t part_rows) noexcept {
  ++parts;
  rows += part_rows;
  sum_part_mse_um2 += mse_um2;
}

double ModelScore::mse_um2() const noexcept {
  return parts == 0 ? kNaN : sum_part_mse_um2 / static_cast<double>(parts);
}

double ModelScore::rms_um() const noexcept { return std::sqrt(mse_um2()); }

double sign_test_p(int k, int n) noexcept {
  if (k <= 0 || n <= 0) return 1.0;
  if (k > n) return 0.0;
  // Σ_{i≥k} C(n, i) / 2^n in logs: n may be large.
  double p = 0.0;
  for (int i = k; i <= n; ++i) {
    p += std::exp(std::lgamma(n + 1.0) - std::lgamma(i + 1.0) - std::lgamma(n - i + 1.0) -
                  n * std::log(2.0));
  }
  return std::min(1.0, p);
}

PairedTest paired_test(std::span<const double> incumbent_mse_um2,
                       std::span<const double> challenger_mse_um2, const ShadowOptions& options) {
  if (incumbent_mse_um2.size() != challenger_mse_um2.size()) {
    throw std::invalid_argument("paired_test: the two models were scored on different parts");
  }
  PairedTest t;
  t.parts = static_cast<int>(incumbent_mse_um2.size());
  for (std::size_t i = 0; i < incumbent_mse_um2.size(); ++i) {
    const double a = incumbent_mse_um2[i];
    const double b = challenger_mse_um2[i];
    // Rounding alone must not count as evidence: a candidate equal to the live model ties.
    const double tol = 1e-9 * std::max(std::abs(a), std::abs(b)) + 1e-12;
    if (std::abs(a - b) <= tol) {
      ++t.ties;
    } else if (b < a) {
      ++t.challenger_better;
    } else {
      ++t.incumbent_better;
    }
  }
  t.p_value = sign_test_p(t.challenger_better, t.challenger_better + t.incumbent_better);
  t.incumbent_rms_um = std::sqrt(mean(incumbent_mse_um2));
  t.challenger_rms_um = std::sqrt(mean(challenger_mse_um2));
  t.passed = t.challenger_better > 0 && t.p_value <= options.alpha &&
             t.incumbent_rms_um - t.challenger_rms_um >= options.margin_um;
  return t;
}

std::string_view phase_name(ShadowPhase p) noexcept {
  switch (p) {
    case ShadowPhase::kCandidate:
      return "candidate";
    case ShadowPhase::kAnnounced:
      return "announced";
    case ShadowPhase::kWatch:
      return "watch";
    case ShadowPhase::kNone:
      break;
  }
  return "none";
}

std::string describe(const ShadowDecision& d) {
  std::string s = fmt::format("{} {} by {}: live {}, other {}", d.utc, d.action, d.by,
                              d.live_file.empty() ? "none" : d.live_file,
                              d.other_file.empty() ? "none" : d.other_file);
  if (d.test.parts > 0) {
    s += fmt::format(
        "; {} parts: other better on {}, live better on {}, ties {}, p = {:.4g}, rms live "
        "{:.3f} um, other {:.3f} um",
        d.test.parts, d.test.challenger_better, d.test.incumbent_better, d.test.ties,
        d.test.p_value, d.test.incumbent_rms_um, d.test.challenger_rms_um);
  }
  return s;
}

std::string history_to_text(const std::vector<ShadowDecision>& history) {
  std::string s(kHistoryHeader);
  s += '\n';
  for (const ShadowDecision& d : history) {
    for (const std::string* f : {&d.utc, &d.action, &d.by, &d.live_file, &d.other_file}) {
      if (f->find_first_of("\t\n") != std::string::npos) {
        throw std::invalid_argument("a tab or line break in '" + *f + "'");
      }
    }
    s += fmt::format("{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\n", d.utc, d.action, d.by,
                     d.live_file, d.other_file, d.test.parts, d.test.challenger_better,
                     d.test.incumbent_better, d.test.ties, number_text(d.test.p_value),
                     number_text(d.test.incumbent_rms_um), number_text(d.test.challenger_rms_um),
                     d.test.passed ? 1 : 0);
  }
  return s;
}

std::vector<ShadowDecision> history_from_text(std::string_view text) {
  std::vector<ShadowDecision> out;
  std::size_t n = 0;
  while (!text.empty()) {
    const std::size_t nl = text.find('\n');
    const std::string_view line = text.substr(0, nl);
    text = nl == std::string_view::npos ? std::string_view{} : text.substr(nl + 1);
    ++n;
    if (n == 1) {
      if (line != kHistoryHeader) {
        throw std::invalid_argument("line 1: expected '" + std::string(kHistoryHeader) + "'");
      }
      continue;
    }
    if (line.empty()) continue;
    std::vector<std::string> f;
    std::size_t start = 0;
    for (;;) {
      const std::size_t tab = line.find('\t', start);
      f.emplace_back(line.substr(start, tab - start));
      if (tab == std::string_view::npos) break;
      start = tab + 1;
    }
    if (f.size() != 13) {
      throw std::invalid_argument("line " + std::to_string(n) + ": " + std::to_string(f.size()) +
                                  " fields, expected 13");
    }
    ShadowDecision d;
    d.utc = f[0];
    d.action = f[1];
    d.by = f[2];
    d.live_file = f[3];
    d.other_file = f[4];
    d.test.parts = static_cast<int>(parse_number(f[5], n));
    d.test.challenger_better = static_cast<int>(parse_number(f[6], n));
    d.test.incumbent_better = static_cast<int>(parse_number(f[7], n));
    d.test.ties = static_cast<int>(parse_number(f[8], n));
    d.test.p_value = parse_number(f[9], n);
    d.test.incumbent_rms_um = parse_number(f[10], n);
    d.test.challenger_rms_um = parse_number(f[11], n);
    d.test.passed = parse_number(f[12], n) > 0.5;
    out.push_back(std::move(d));
  }
  if (n == 0) throw std::invalid_argument("line 1: empty");
  return out;
}

void Shadow::configure(const ShadowOptions& options, std::vector<std::string> log_context_names) {
  std::lock_guard<std::mutex> lock(mu_);
  options_ = options;
  context_names_ = std::move(log_context_names);
  const auto keep = static_cast<std::size_t>(std::max(1, options_.history_size));
  if (history_.size() > keep) {
    history_.erase(history_.begin(), history_.end() - static_cast<std::ptrdiff_t>(keep));
  }
}

void Shadow::assign(Scored& s, const std::string& file, const std::string& hash, cm::Model model) {
  s.file = file;
  s.hash = hash;
  s.model = std::move(model);
  s.state = s.model.make_state();
  s.score = ModelScore{};
  s.present = true;
}

void Shadow::set_live(const std::string& file, const std::string& hash, cm::Model model) {
  std::lock_guard<std::mutex> lock(mu_);
  if (live_.present && live_.file == file && live_.hash == hash) return;
  if (live_.present) previous_ = std::move(live_);
  assign(live_, file, hash, std::move(model));
  if (phase_ == ShadowPhase::kWatch ||
      (other_.present && other_.file == file && other_.hash == hash)) {
    other_ = Scored{};
    phase_ = ShadowPhase::kNone;
  }
  reset_window();
}

void Shadow::set_candidate(const std::string& file, const std::string& hash, cm::Model model) {
  std::lock_guard<std::mutex> lock(mu_);
  assign(other_, file, hash, std::move(model));
  phase_ = ShadowPhase::kCandidate;
  pending_.reset();
  reset_window();
}

void Shadow::watch_previous() {
  std::lock_guard<std::mutex> lock(mu_);
  if (!previous_.present) return;
  other_ = std::move(previous_);
  previous_ = Scored{};
  other_.state = other_.model.make_state();
  other_.score = ModelScore{};
  phase_ = ShadowPhase::kWatch;
  reset_window();
}

void Shadow::clear() {
  std::lock_guard<std::mutex> lock(mu_);
  other_ = Scored{};
  phase_ = ShadowPhase::kNone;
  pending_.reset();
  reset_window();
}

void Shadow::reset_window() {
  window_live_.clear();
  window_other_.clear();
  window_test_ = PairedTest{};
  // A part in progress was scored partly without the new model: it does not count.
  open_ = false;
  open_rows_ = 0;
  open_live_sq_ = 0.0;
  open_other_sq_ = 0.0;
}

double Shadow::error_um(Scored& m, const cm::Row& row, double target_um) {
  cm::Row r = row;
  const auto& extras = m.model.extra_columns();
  for (std::size_t e = 0; e < extras.size() && cm::kStandardColumns + e < cm::kMaxColumns; ++e) {
    for (std::size_t c = 0; c < context_names_.size() && c < core::kMaxContextValues; ++c) {
      if (context_names_[c] == extras[e]) r[cm::kStandardColumns + e] = ctx_[c];
    }
  }
  return target_um - m.model.evaluate(r, m.state);
}

void Shadow::observe(const core::MeasurementRecord& rec) {
  std::lock_guard<std::mutex> lock(mu_);
  if (!live_.present) return;
  const double target_um = rec.measured_um + rec.applied_um;
  cm::Row row = cm::unknown_row();
  row[col(cm::Column::kTime)] = static_cast<double>(rec.time_ns) * 1e-9;
  row[col(cm::Column::kPart)] = rec.part;
  row[col(cm::Column::kTool)] = rec.tool;
  row[col(cm::Column::kKind)] = static_cast<double>(rec.kind);
  row[col(cm::Column::kPoint)] = rec.point;
  row[col(cm::Column::kX)] = rec.position_mm[0];
  row[col(cm::Column::kY)] = rec.position_mm[1];
  row[col(cm::Column::kZ)] = rec.position_mm[2];
  row[col(cm::Column::kAngle)] = rec.angle_deg;
  row[col(cm::Column::kPath)] = rec.path_mm;
  row[col(cm::Column::kTemp)] = rec.temp_c;
  ctx_ = rec.context;
  const bool scoring_other = other_.present && phase_ != ShadowPhase::kNone;
  // Both models see every row, so that their lag filters advance alike.
  const double e_live = error_um(live_, row, target_um);
  const double e_other = scoring_other ? error_um(other_, row, target_um) : 0.0;
  if (!std::isfinite(e_live) || !std::isfinite(e_other)) {
    ++rows_skipped_;
    return;
  }
  ++rows_scored_;
  if (open_ && (rec.session != open_session_ || rec.part != open_part_)) close_part();
  open_ = true;
  open_session_ = rec.session;
  open_part_ = rec.part;
  ++open_rows_;
  open_live_sq_ += e_live * e_live;
  open_other_sq_ += e_other * e_other;
  if (rec.part == 0) close_part();
}

void Shadow::close_part() {
  if (!open_ || open_rows_ == 0) return;
  const auto rows = static_cast<double>(open_rows_);
  const double live_mse = open_live_sq_ / rows;
  const double other_mse = open_other_sq_ / rows;
  live_.score.add_part(live_mse, open_rows_);
  if (other_.present && phase_ != ShadowPhase::kNone) {
    other_.score.add_part(other_mse, open_rows_);
    window_live_.push_back(live_mse);
    window_other_.push_back(other_mse);
    window_test_ = paired_test(window_live_, window_other_, options_);
    if (static_cast<int>(window_live_.size()) >= options_.min_parts) decide();
  }
  open_ = false;
  open_rows_ = 0;
  open_live_sq_ = 0.0;
  open_other_sq_ = 0.0;
}

void Shadow::decide() {
  if (pending_ || (phase_ != ShadowPhase::kCandidate && phase_ != ShadowPhase::kWatch)) return;
  ShadowDecision d;
  d.utc = utc_now();
  d.by = "shadow rule";
  d.live_file = live_.file;
  d.other_file = other_.file;
  d.test = window_test_;
  if (phase_ == ShadowPhase::kCandidate) {
    if (!d.test.passed) {
      d.action = "rejected";
      phase_ = ShadowPhase::kNone;
    } else if (options_.promote == ShadowPromote::kAuto) {
      d.action = "promoted";  // carried out by the main thread
    } else {
      d.action = "announced";
      phase_ = ShadowPhase::kAnnounced;
    }
  } else {
    d.action = d.test.passed ? "demoted" : "confirmed";
    if (!d.test.passed) phase_ = ShadowPhase::kNone;
  }
  pending_ = std::move(d);
}

std::optional<ShadowDecision> Shadow::take_decision() {
  std::lock_guard<std::mutex> lock(mu_);
  std::optional<ShadowDecision> d = std::move(pending_);
  pending_.reset();
  return d;
}

void Shadow::record(ShadowDecision d) {
  std::lock_guard<std::mutex> lock(mu_);
  history_.push_back(std::move(d));
  const auto keep = static_cast<std::size_t>(std::max(1, options_.history_size));
  if (history_.size() > keep) {
    history_.erase(history_.begin(), history_.end() - static_cast<std::ptrdiff_t>(keep));
  }
}

void Shadow::set_history(std::vector<ShadowDecision> history) {
  std::lock_guard<std::mutex> lock(mu_);
  history_ = std::move(history);
}

std::vector<ShadowDecision> Shadow::history() const {
  std::lock_guard<std::mutex> lock(mu_);
  return history_;
}

ShadowStatus Shadow::status() const {
  std::lock_guard<std::mutex> lock(mu_);
  ShadowStatus s;
  s.options = options_;
  s.phase = phase_;
  s.live_file = live_.file;
  s.live = live_.score;
  if (phase_ != ShadowPhase::kNone) {
    s.other_file = other_.file;
    s.other = other_.score;
  }
  s.window = window_test_;
  s.rows_scored = rows_scored_;
  s.rows_skipped = rows_skipped_;
  s.history = history_;
  return s;
}

ShadowPhase Shadow::phase() const {
  std::lock_guard<std::mutex> lock(mu_);
  return phase_;
}

std::string Shadow::other_file() const {
  std::lock_guard<std::mutex> lock(mu_);
  return phase_ == ShadowPhase::kNone ? std::string() : other_.file;
}

}  // namespace nccomp::daemon::sections
