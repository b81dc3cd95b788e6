// S1 benchmark: how the per-checkpoint offsets reach the wall, and what learning does with them.
//
// A synthetic boss (120 × 80 mm, chamfered corner), finished layer by layer at 10 m/min with a
// 1 kHz loop; the wall's push-off error e(s, z) grows with the height above the clamp and with
// the distance from the clamp's centre, scales with a hardness field (a 4 HRC gradient across
// the blank plus, per blank, a smooth random part) and has a flexible bump in the middle of the
// long side. The wall left by the finishing pass at path position s is e(s, z) + c(s), where c is
// the radius wear the compensator has the NC apply at that moment (the live register, after the
// limiter, held between writes).
//
// Table 1: offsets = −e at the checkpoints (perfectly learned), applied as the seed's step (the
//          value switches at each checkpoint, as a D-number change in the program does), as step
//          through the default limiter, and creeping (linear, cosine) between checkpoints; with
//          the step each application leaves at the seam (where each level's closed pass meets
//          its own start).
// Table 2: a series of parts with learning (mode A: part n's probe readings → part n+1), probe
//          noise 0.7 µm: RMS wall error per part, step vs creep, and creep through the default
//          limiter (learning against the value the limiter let through).
// Levels are joined by a plunge of one depth step at the seam point at 1 m/min (samples, not
// wall).
// Table 3: learning over 20 blanks with a per-blank hardness scatter: the EWMA weight k, the
//          estimator ([checkpoints.estimator], part noise learned) and its probe-noise limit (the
//          same filter told the true process: q = 0, a running mean), and mode A against mode B
//          (semi-finishing with the paired tool, then finishing).
// Table 4: cost of one step() [ns] (one axis sample) on this machine.
// Table 5: learning a per-checkpoint deviation that drifts from part to part (a random walk of
//          w µm per part at every checkpoint, linear along the wall between checkpoints) read
//          with probe noise 0.7 µm: the EWMA weights, the estimator (part noise learned) and the
//          probe-noise limit (the same filter told the true w and σ), over 4 series of 20 parts.
//
// The source compiles against the compensator before issue 4's level-aware creep too (no API
// of it is used), so the seam figures of both can be measured with the same program.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>
#include <vector>

#include "core/checkpoint/compensator.hpp"
#include "core/checkpoint/plan.hpp"
#include "core/checkpoint/probe.hpp"

namespace {

namespace cp = nccomp::core::checkpoint;
using nccomp::core::AxisSample;
using nccomp::core::Event;
using nccomp::core::LimiterConfig;
using nccomp::core::ProbeMeasurement;
using nccomp::core::ProgramEvent;
using nccomp::core::ProgramEventKind;
using nccomp::core::StepOutput;
using nccomp::core::TimeNs;

constexpr double kFeedMmPerS = 10000.0 / 60.0;
// The level link: a plunge of one depth step at the seam point at 1 m/min (0.6 s for 10 mm).
constexpr double kPlungeMmPerS = 1000.0 / 60.0;
constexpr double kRateHz = 1000.0;
constexpr double kClampZMm = -45.0;
constexpr int kRegister = 19;

cp::PlanConfig boss() {
  cp::PlanConfig c;
  c.contour = {{0, 0}, {120, 0}, {120, 80}, {15, 80}, {0, 65}};
  c.z_start_mm = -3.0;
  c.z_end_mm = -33.0;
  c.depth_step_mm = 10.0;
  c.wall_angle_deg = 3.0;
  c.corner_offset_mm = 8.0;
  c.extra_points_mm = {60.0};
  c.extra_regions = {{230.0, 250.0, 10.0}};
  c.tool_radius_mm = 8.0;
  c.ball_radius_mm = 2.0;
  return c;
}

struct Geometry {
  std::vector<double> s;  // arc length at each vertex (closed)
  std::vector<cp::Point2> p;
  double length{0.0};
  cp::Point2 at(double sv) const {
    std::size_t i = 0;
    while (i + 2 < s.size() && s[i + 1] <= sv) ++i;
    const double u = (sv - s[i]) / (s[i + 1] - s[i]);
    return {p[i].x_mm + u * (p[i + 1].x_mm - p[i].x_mm),
            p[i].y_mm + u * (p[i + 1].y_mm - p[i].y_mm)};
  }
};

Geometry geometry(const cp::PlanConfig& c) {
  Geometry g;
  for (const auto& v : c.contour) g.p.push_back({v.x_mm, v.y_mm});
  g.p.push_back(g.p.front());
  g.s.push_back(0.0);
  for (std::size_t i = 1; i < g.p.size(); ++i) {
    g.s.push_back(g.s.back() +
                  std::hypot(g.p[i].x_mm - g.p[i - 1].x_mm, g.p[i].y_mm - g.p[i - 1].y_mm));
  }
  g.length = g.s.back();
  return g;
}

// Per-blank smooth random hardness: a few sinusoids along the contour [HRC].
struct Blank {
  double a[3]{0, 0, 0};
  double phase[3]{0, 0, 0};
  double hrc(double s, double length) const {
    double h = 0.0;
    for (int k = 0; k < 3; ++k) {
      h += a[k] * std::sin(2.0 * std::numbers::pi * (k + 1) * s / length + phase[k]);
    }
    return h;
  }
};

// A per-checkpoint value at contour position s on level l, linear between the level's
// checkpoints along the pass and through the seam (closed contour), as creep applies offsets.
double between_checkpoints(const cp::Plan& plan, std::size_t l, double s, double length,
                           const std::vector<double>& v) {
  std::size_t first = plan.checkpoints.size();
  std::size_t last = 0;
  for (std::size_t i = 0; i < plan.checkpoints.size(); ++i) {
    if (plan.checkpoints[i].level != static_cast<int>(l)) continue;
    first = std::min(first, i);
    last = i;
  }
  const auto& c = plan.checkpoints;
  if (s < c[first].s_mm || s >= c[last].s_mm) {
    const double span = length - c[last].s_mm + c[first].s_mm;
    const double done = s >= c[last].s_mm ? s - c[last].s_mm : length - c[last].s_mm + s;
    return v[last] + (v[first] - v[last]) * done / span;
  }
  std::size_t k = first;
  while (k + 1 <= last && c[k + 1].s_mm <= s) ++k;
  if (k == last) return v[last];
  return v[k] + (v[k + 1] - v[k]) * (s - c[k].s_mm) / (c[k + 1].s_mm - c[k].s_mm);
}

// Push-off error [µm] at contour position s and height z for a given blank.
double push_off_um(const Geometry& g, double s, double z, const Blank& blank) {
  const cp::Point2 q = g.at(s);
  const double height_mm = z - kClampZMm;  // 12 … 42 mm
  const double dist_mm = std::hypot(q.x_mm - 60.0, q.y_mm - 40.0);
  const double hrc = 38.0 + 4.0 * q.x_mm / 120.0 + blank.hrc(s, g.length);
  // The middle of the long side (s = 60) is thin: extra compliance.
  const double bump = 1.0 + 0.6 * std::exp(-0.5 * std::pow((s - 60.0) / 15.0, 2.0));
  return 0.6 * height_mm * (1.0 + dist_mm / 150.0) * (hrc / 40.0) * bump;
}

struct WallResult {
  double rms_um{0.0};
  double max_um{0.0};
  double max_jump_um{0.0};     // largest change of the applied offset between two samples
  double max_jump_cp_um{0.0};  // … within ±1 mm of a checkpoint
  double max_seam_um{0.0};     // largest |c(end of a level's pass) − c(its start)|: same point
  std::size_t writes{0};
};

// Finishes one part: returns the wall error statistics over every sample of every level, and
// fills wall_at_cp with the wall error at each checkpoint. Each level's pass runs from s = 0 to
// s = L inclusive (the closed contour's start point twice: the seam).
// drift (optional): a further error per checkpoint, linear between checkpoints (Table 5).
WallResult finish(cp::CheckpointCompensator& comp, const cp::Plan& plan, const Geometry& g,
                  const cp::PlanConfig& pc, const Blank& blank, std::vector<double>* wall_at_cp,
                  int part = 1, const std::vector<double>* drift = nullptr) {
  StepOutput out;
  const Event start = ProgramEvent{0, ProgramEventKind::kPartStart, part};
  comp.step(0, {&start, 1}, out);
  WallResult r;
  double applied = std::nan("");
  // Roughing and semi-finishing take time before the finishing tool arrives: 2 s of cycles
  // without samples, in which the live register is pre-positioned to the first pass's start.
  TimeNs t = 0;
  for (int k = 0; k < 2000; ++k) {
    t += static_cast<TimeNs>(1e9 / kRateHz);
    out.clear();
    comp.step(t, {}, out);
    for (const auto& w : out.writes) {
      if (w.register_index == kRegister) applied = w.value_um;
    }
  }
  double sum2 = 0.0;
  std::size_t n = 0;
  const double link = pc.depth_step_mm;
  const auto samples = static_cast<std::size_t>(std::ceil(g.length / (kFeedMmPerS / kRateHz)));
  std::size_t next_cp = 0;
  if (wall_at_cp) wall_at_cp->assign(plan.checkpoints.size(), 0.0);
  for (std::size_t l = 0; l < plan.levels_z_mm.size(); ++l) {
    const double z = plan.levels_z_mm[l];
    const double base = static_cast<double>(l) * (g.length + link);
    double prev_applied = std::nan("");
    double first_applied = std::nan("");
    for (std::size_t k = 0; k <= samples; ++k) {
      const double s = g.length * static_cast<double>(k) / static_cast<double>(samples);
      t += static_cast<TimeNs>(1e9 / kRateHz);
      AxisSample a;
      a.time_ns = t;
      const cp::Point2 q = g.at(s);
      a.position_mm = {q.x_mm, q.y_mm, z, 0, 0, 0};
      a.program_path_mm = base + s;
      a.tool = 12;
      const Event ev = a;
      out.clear();
      comp.step(t, {&ev, 1}, out);
      for (const auto& w : out.writes) {
        if (w.register_index == kRegister) {
          applied = w.value_um;
          ++r.writes;
        }
      }
      const double c = std::isfinite(applied) ? applied : 0.0;
      const double wall =
          push_off_um(g, s, z, blank) + c +
          (drift != nullptr ? between_checkpoints(plan, l, s, g.length, *drift) : 0.0);
      if (k < samples) {  // s = L is the start point again: counted once
        sum2 += wall * wall;
        ++n;
      }
      r.max_um = std::max(r.max_um, std::fabs(wall));
      if (std::isfinite(prev_applied)) {
        const double jump = std::fabs(c - prev_applied);
        r.max_jump_um = std::max(r.max_jump_um, jump);
        for (const cp::Checkpoint& cpt : plan.checkpoints) {
          if (cpt.level == static_cast<int>(l) && std::fabs(cpt.s_mm - s) <= 1.0) {
            r.max_jump_cp_um = std::max(r.max_jump_cp_um, jump);
          }
        }
      } else {
        first_applied = c;
      }
      prev_applied = c;
      while (wall_at_cp && next_cp < plan.checkpoints.size() &&
             plan.checkpoints[next_cp].path_mm <= base + s) {
        (*wall_at_cp)[next_cp] = wall;  // what the probe will find there
        ++next_cp;
      }
    }
    r.max_seam_um = std::max(r.max_seam_um, std::fabs(prev_applied - first_applied));
    if (l + 1 < plan.levels_z_mm.size()) {
      // The plunge to the next level at the seam point (not a wall sample).
      const auto link_samples =
          static_cast<std::size_t>(std::ceil(link / (kPlungeMmPerS / kRateHz)));
      const cp::Point2 q = g.at(0.0);
      for (std::size_t k = 1; k < link_samples; ++k) {
        const double u = static_cast<double>(k) / static_cast<double>(link_samples);
        t += static_cast<TimeNs>(1e9 / kRateHz);
        AxisSample a;
        a.time_ns = t;
        a.position_mm = {q.x_mm, q.y_mm, z - u * link, 0, 0, 0};
        a.program_path_mm = base + g.length + u * link;
        a.tool = 12;
        const Event ev = a;
        out.clear();
        comp.step(t, {&ev, 1}, out);
        for (const auto& w : out.writes) {
          if (w.register_index == kRegister) {
            applied = w.value_um;
            ++r.writes;
          }
        }
      }
    }
  }
  r.rms_um = std::sqrt(sum2 / static_cast<double>(n));
  return r;
}

std::vector<Event> probe_readings(const cp::Plan& plan, const cp::PlanConfig& pc,
                                  const std::vector<double>& wall_cp, int part, std::mt19937& rng,
                                  std::normal_distribution<double>& noise) {
  std::vector<Event> probes;
  for (std::size_t i = 0; i < wall_cp.size(); ++i) {
    ProbeMeasurement pm;
    pm.part = part;
    pm.checkpoint = static_cast<std::int32_t>(i);
    pm.wall_angle_deg = plan.checkpoints[i].alpha_deg;
    pm.ball_radius_mm = pc.ball_radius_mm;
    pm.raw_deviation_um = wall_cp[i] + noise(rng) +
                          cp::probe_delta0_um(pc.ball_radius_mm, plan.checkpoints[i].alpha_deg);
    probes.emplace_back(pm);
  }
  return probes;
}

void feed(cp::CheckpointCompensator& comp, const std::vector<Event>& probes) {
  for (std::size_t i = 0; i < probes.size(); i += 32) {
    StepOutput out;
    const std::size_t n = std::min<std::size_t>(32, probes.size() - i);
    comp.step(0, std::span<const Event>(probes.data() + i, n), out);
  }
}

double rms_of(const std::vector<double>& v) {
  double s2 = 0.0;
  for (double x : v) s2 += x * x;
  return std::sqrt(s2 / static_cast<double>(v.size()));
}

Blank random_blank(std::mt19937& rng, double sigma_hrc) {
  std::normal_distribution<double> hrc(0.0, sigma_hrc);
  std::uniform_real_distribution<double> phase(0.0, 2.0 * std::numbers::pi);
  Blank b;
  for (int k = 0; k < 3; ++k) {
    b.a[k] = hrc(rng);
    b.phase[k] = phase(rng);
  }
  return b;
}

// [checkpoints.estimator] as docs/estimation.md recommends: σ = the probe's repeatability.
cp::CheckpointEstimatorConfig estimator(double sigma_um) {
  cp::CheckpointEstimatorConfig e;
  e.enabled = true;
  e.measurement_sigma_um = sigma_um;
  e.part_noise_um = 1.0;
  e.learn_part_noise = true;
  e.learn_min_parts = 5;
  e.gate_sigmas = 5.0;
  return e;
}

cp::CompensatorConfig config(cp::ApplyMode apply, nccomp::core::ProfileShape shape) {
  cp::CompensatorConfig c;
  c.finishing_tool = 12;
  c.register_base = 20;
  c.active_register = kRegister;
  c.apply = apply;
  c.creep_shape = shape;
  c.trigger = cp::TriggerMode::kPath;
  c.ewma_weight = 3.0;
  c.dead_band_um = 0.5;
  c.probe_repeatability_um = 0.5;
  c.write_threshold_um = 0.05;
  c.plausible_um = 200.0;
  c.outlier_sigma = 4.0;
  return c;
}

LimiterConfig seed_limits() {  // an instantaneous switch: the NC changes the D number
  LimiterConfig l;
  l.max_abs_um = 200.0;
  l.max_step_um = 1000.0;
  l.max_rate_um_per_s = 1e9;
  return l;
}

}  // namespace

int main() {
  const cp::PlanConfig pc = boss();
  const cp::Plan plan = cp::make_plan(pc);
  const Geometry g = geometry(pc);
  const Blank nominal{};
  std::printf(
      "# S1 wall benchmark: %zu checkpoints on %zu levels, contour %.3f mm, 10 m/min, "
      "%.0f Hz\n\n",
      plan.checkpoints.size(), plan.levels_z_mm.size(), g.length, kRateHz);

  // --- Table 1 ---
  std::vector<double> learned(plan.checkpoints.size());
  for (std::size_t i = 0; i < learned.size(); ++i) {
    learned[i] = -push_off_um(g, plan.checkpoints[i].s_mm, plan.checkpoints[i].z_mm, nominal);
  }
  struct Variant {
    const char* name;
    cp::ApplyMode apply;
    nccomp::core::ProfileShape shape;
    LimiterConfig limits;
  };
  const Variant variants[] = {
      {"step (seed: instant switch)", cp::ApplyMode::kStep, nccomp::core::ProfileShape::kLinear,
       seed_limits()},
      {"step through default limiter", cp::ApplyMode::kStep, nccomp::core::ProfileShape::kLinear,
       LimiterConfig{}},
      {"creep linear", cp::ApplyMode::kCreep, nccomp::core::ProfileShape::kLinear, seed_limits()},
      {"creep cosine", cp::ApplyMode::kCreep, nccomp::core::ProfileShape::kCosine, seed_limits()},
      {"creep linear through default limiter", cp::ApplyMode::kCreep,
       nccomp::core::ProfileShape::kLinear, LimiterConfig{}},
  };
  std::printf("## 1. Perfectly learned offsets, one part\n\n");
  std::printf(
      "| application | RMS wall error [um] | max wall error [um] | max offset jump "
      "between samples [um] | at checkpoints [um] | step at the seam [um] | live writes |\n");
  std::printf("| --- | --- | --- | --- | --- | --- | --- |\n");
  {
    cp::CheckpointCompensator none;
    cp::CompensatorConfig c = config(cp::ApplyMode::kStep, nccomp::core::ProfileShape::kLinear);
    none.configure(c, plan.checkpoints, seed_limits());
    const WallResult r = finish(none, plan, g, pc, nominal, nullptr);
    std::printf("| none (uncompensated) | %.2f | %.2f | %.3f | %.3f | %.3f | %zu |\n", r.rms_um,
                r.max_um, r.max_jump_um, r.max_jump_cp_um, r.max_seam_um, r.writes);
  }
  for (const Variant& v : variants) {
    cp::CheckpointCompensator comp;
    comp.configure(config(v.apply, v.shape), plan.checkpoints, v.limits);
    cp::CheckpointState st;
    comp.export_state(st);
    for (std::size_t i = 0; i < learned.size(); ++i) st.points[i].offset_um = learned[i];
    comp.import_state(st);
    const WallResult r = finish(comp, plan, g, pc, nominal, nullptr);
    std::printf("| %s | %.2f | %.2f | %.3f | %.3f | %.3f | %zu |\n", v.name, r.rms_um, r.max_um,
                r.max_jump_um, r.max_jump_cp_um, r.max_seam_um, r.writes);
  }

  // --- Table 2 ---
  std::printf(
      "\n## 2. Series of parts, learning mode A (k = 3), probe noise 0.7 um, "
      "per-blank hardness scatter\n\n");
  std::printf(
      "| part | step: RMS wall [um] | step: RMS at checkpoints [um] | creep: RMS wall [um] "
      "| creep: RMS at checkpoints [um] | creep: seam [um] | creep, default limiter: RMS wall "
      "[um] | creep, default limiter: RMS at checkpoints [um] | step, default limiter: RMS wall "
      "[um] | step, default limiter: RMS at checkpoints [um] |\n");
  std::printf("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n");
  {
    cp::CheckpointCompensator comps[4];
    comps[0].configure(config(cp::ApplyMode::kStep, nccomp::core::ProfileShape::kLinear),
                       plan.checkpoints, seed_limits());
    comps[1].configure(config(cp::ApplyMode::kCreep, nccomp::core::ProfileShape::kLinear),
                       plan.checkpoints, seed_limits());
    comps[2].configure(config(cp::ApplyMode::kCreep, nccomp::core::ProfileShape::kLinear),
                       plan.checkpoints, LimiterConfig{});
    comps[3].configure(config(cp::ApplyMode::kStep, nccomp::core::ProfileShape::kLinear),
                       plan.checkpoints, LimiterConfig{});
    std::mt19937 rng(2026);
    std::normal_distribution<double> noise(0.0, 0.7);
    for (int part = 1; part <= 10; ++part) {
      const Blank b = random_blank(rng, 0.7);
      double rms_cp[4] = {0, 0, 0, 0};
      WallResult res[4];
      for (int m = 0; m < 4; ++m) {
        std::vector<double> wall_cp;
        res[m] = finish(comps[m], plan, g, pc, b, &wall_cp, part);
        rms_cp[m] = rms_of(wall_cp);
        feed(comps[m], probe_readings(plan, pc, wall_cp, part, rng, noise));
      }
      std::printf("| %d | %.2f | %.2f | %.2f | %.2f | %.3f | %.2f | %.2f | %.2f | %.2f |\n", part,
                  res[0].rms_um, rms_cp[0], res[1].rms_um, rms_cp[1], res[1].max_seam_um,
                  res[2].rms_um, rms_cp[2], res[3].rms_um, rms_cp[3]);
    }
  }

  // --- Table 3 ---
  // 20 blanks; each has its own smooth hardness pattern (3 harmonics along the contour of
  // σ_blank HRC each) on top of the common 4 HRC gradient. Creep, seed limits, probe noise 0.7.
  std::printf(
      "\n## 3. Learning over 20 blanks with a per-blank hardness scatter (creep): RMS wall "
      "error of parts 6-20 [um]\n\n");
  std::printf(
      "| hardness scatter per blank [HRC per harmonic] | mode A k = 1 | mode A k = 3 | "
      "mode A k = 6 | mode B (paired semi-finishing tool) | mode A estimator | probe-noise limit "
      "(filter, q = 0) | estimator / limit |\n");
  std::printf("| --- | --- | --- | --- | --- | --- | --- | --- |\n");
  for (const double sigma : {0.7, 1.5, 2.5}) {
    double result[6] = {0, 0, 0, 0, 0, 0};
    const double ks[3] = {1.0, 3.0, 6.0};
    for (int m = 0; m < 6; ++m) {
      cp::CompensatorConfig c = config(cp::ApplyMode::kCreep, nccomp::core::ProfileShape::kLinear);
      if (m < 3) {
        c.ewma_weight = ks[m];
      } else if (m == 3) {
        c.learning_mode = cp::LearningMode::kSemiFinishing;
        c.semi_finishing_tool = 11;
      } else {
        c.estimator = estimator(0.7);
        // The limit knows the process: the blanks scatter around a fixed error, nothing carries
        // over from one blank to the next (q = 0).
        if (m == 5) {
          c.estimator.learn_part_noise = false;
          c.estimator.part_noise_um = 0.0;
        }
      }
      c.outlier_sigma = 6.0;
      cp::CheckpointCompensator comp;
      comp.configure(c, plan.checkpoints, seed_limits());
      // The same blanks and noise for every column.
      std::mt19937 rng(77);
      std::normal_distribution<double> noise(0.0, 0.7);
      std::normal_distribution<double> pair(0.0, 0.3);
      std::vector<double> rms_parts;
      for (int part = 1; part <= 20; ++part) {
        const Blank b = random_blank(rng, sigma);
        std::vector<double> pair_err(plan.checkpoints.size());
        for (double& x : pair_err) x = pair(rng);
        if (m == 3) {
          // Semi-finishing with the paired tool (same push-off up to 0.3 µm, no checkpoint
          // offsets), probed, learned and written before finishing this blank.
          StepOutput out;
          const Event start = ProgramEvent{0, ProgramEventKind::kPartStart, part};
          comp.step(0, {&start, 1}, out);
          std::vector<double> semi(plan.checkpoints.size());
          for (std::size_t i = 0; i < semi.size(); ++i) {
            semi[i] =
                push_off_um(g, plan.checkpoints[i].s_mm, plan.checkpoints[i].z_mm, b) + pair_err[i];
          }
          feed(comp, probe_readings(plan, pc, semi, part, rng, noise));
        } else {
          for (std::size_t i = 0; i < pair_err.size(); ++i) (void)noise(rng);  // same draws
        }
        std::vector<double> wall_cp;
        const WallResult r = finish(comp, plan, g, pc, b, &wall_cp, part);
        if (m != 3) {
          feed(comp, probe_readings(plan, pc, wall_cp, part, rng, noise));
        } else {
          for (std::size_t i = 0; i < wall_cp.size(); ++i) (void)noise(rng);  // same draws
        }
        if (part > 5) rms_parts.push_back(r.rms_um);
      }
      result[m] = rms_of(rms_parts);
    }
    std::printf("| %.1f | %.2f | %.2f | %.2f | %.2f | %.2f | %.2f | %.2f |\n", sigma, result[0],
                result[1], result[2], result[3], result[4], result[5], result[4] / result[5]);
  }

  // --- Table 4 ---
  std::printf(
      "\n## 4. Cost of one step() with one axis sample\n\n| trigger | apply | ns per step |\n"
      "| --- | --- | --- |\n");
  for (const auto trig : {cp::TriggerMode::kPath, cp::TriggerMode::kPosition}) {
    for (const auto apply : {cp::ApplyMode::kStep, cp::ApplyMode::kCreep}) {
      cp::CheckpointCompensator comp;
      cp::CompensatorConfig c = config(apply, nccomp::core::ProfileShape::kLinear);
      c.trigger = trig;
      comp.configure(c, plan.checkpoints, seed_limits());
      StepOutput out;
      const Event start = ProgramEvent{0, ProgramEventKind::kPartStart, 1};
      comp.step(0, {&start, 1}, out);
      std::vector<Event> samples;
      const double ds = kFeedMmPerS / kRateHz;
      for (std::size_t l = 0; l < plan.levels_z_mm.size(); ++l) {
        for (double s = 0.0; s < g.length; s += ds) {
          AxisSample a;
          const cp::Point2 q = g.at(s);
          a.position_mm = {q.x_mm, q.y_mm, plan.levels_z_mm[l], 0, 0, 0};
          a.program_path_mm = static_cast<double>(l) * (g.length + pc.depth_step_mm) + s;
          a.tool = 12;
          samples.emplace_back(a);
        }
      }
      const auto t0 = std::chrono::steady_clock::now();
      for (std::size_t k = 0; k < samples.size(); ++k) {
        out.clear();
        comp.step(static_cast<TimeNs>(k) * 1'000'000, {&samples[k], 1}, out);
      }
      const auto t1 = std::chrono::steady_clock::now();
      const double ns = std::chrono::duration<double, std::nano>(t1 - t0).count() /
                        static_cast<double>(samples.size());
      std::printf("| %s | %s | %.0f |\n", cp::trigger_mode_name(trig), cp::apply_mode_name(apply),
                  ns);
    }
  }

  // --- Table 5 ---
  // Per series: the nominal blank, a random walk of w µm per part at every checkpoint (the
  // same walks and probe draws for every column), probe noise 0.7 µm, creep, seed limits.
  std::printf(
      "\n## 5. A per-checkpoint deviation drifting from part to part (random walk of w per "
      "part), probe noise 0.7 um: RMS wall error of parts 6-20 over 4 series [um] (at the "
      "checkpoints in brackets)\n\n");
  std::printf(
      "| w [um per part] | mode A k = 1 | mode A k = 3 | mode A k = 6 | mode A estimator | "
      "probe-noise limit (filter, true w and sigma) | estimator / limit: wall | at checkpoints "
      "|\n");
  std::printf("| --- | --- | --- | --- | --- | --- | --- | --- |\n");
  constexpr double kProbeSigma = 0.7;
  for (const double w : {0.25, 0.5, 1.0, 2.0}) {
    double wall2[5] = {0, 0, 0, 0, 0};
    double cp2[5] = {0, 0, 0, 0, 0};
    std::size_t parts = 0;
    for (int series = 0; series < 4; ++series) {
      for (int m = 0; m < 5; ++m) {
        cp::CompensatorConfig c =
            config(cp::ApplyMode::kCreep, nccomp::core::ProfileShape::kLinear);
        c.outlier_sigma = 6.0;
        const double ks[3] = {1.0, 3.0, 6.0};
        if (m < 3) {
          c.ewma_weight = ks[m];
        } else {
          c.estimator = estimator(kProbeSigma);
          if (m == 4) {  // the limit: told the true process
            c.estimator.learn_part_noise = false;
            c.estimator.part_noise_um = w;
          }
        }
        cp::CheckpointCompensator comp;
        comp.configure(c, plan.checkpoints, seed_limits());
        std::mt19937 rng(500 + static_cast<unsigned>(series));
        std::normal_distribution<double> noise(0.0, kProbeSigma);
        std::normal_distribution<double> step(0.0, w);
        std::vector<double> drift(plan.checkpoints.size(), 0.0);
        for (int part = 1; part <= 20; ++part) {
          for (double& d : drift) d += step(rng);
          std::vector<double> wall_cp;
          const WallResult r = finish(comp, plan, g, pc, nominal, &wall_cp, part, &drift);
          feed(comp, probe_readings(plan, pc, wall_cp, part, rng, noise));
          if (part > 5) {
            wall2[m] += r.rms_um * r.rms_um;
            const double rc = rms_of(wall_cp);
            cp2[m] += rc * rc;
            if (m == 0) ++parts;
          }
        }
      }
    }
    double wall[5];
    double at_cp[5];
    for (int m = 0; m < 5; ++m) {
      wall[m] = std::sqrt(wall2[m] / static_cast<double>(parts));
      at_cp[m] = std::sqrt(cp2[m] / static_cast<double>(parts));
    }
    std::printf(
        "| %.2f | %.2f (%.2f) | %.2f (%.2f) | %.2f (%.2f) | %.2f (%.2f) | %.2f (%.2f) | %.2f | "
        "%.2f |\n",
        w, wall[0], at_cp[0], wall[1], at_cp[1], wall[2], at_cp[2], wall[3], at_cp[3], wall[4],
        at_cp[4], wall[3] / wall[4], at_cp[3] / at_cp[4]);
  }
  return 0;
}
