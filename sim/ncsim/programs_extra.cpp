// Programs (c) roll and (d) touch of the virtual NC.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <stdexcept>

#include "sim/ncsim/simulation.hpp"

namespace nccomp::sim::ncsim {

using core::AxisSample;
using core::ProgramEvent;
using core::ProgramEventKind;

namespace {

// ---------------------------------------------------------------------------------------------
// (d) touch cycles and test grinds (S3), docs/ncsim.md "touch".
//
// The machine's error along an axis at a calibration position is E = static + thermal + pitch
// [µm]: the tool (and the probe on it) is displaced by +E, the axis offset o the NC holds moves
// it by +o, so the offset that cancels the error is o = −E (the daemon's calibrator finds −E).
// A touch approaching in direction s triggers where the probe meets the body:
//   machine coordinates: nominal + (−E + s·pretravel + noise) / 1000   (o does not enter)
//   program coordinates: the same − o / 1000                           (machine = program + o)
// A test grind from ±X with the X offset o in force leaves facets d0 ∓ (E + o) deep (the +X facet
// is shallower when the tool sits too far +X); their chords go to the measuring device's export.
// The touch rows' true_drift_um is the trigger shift the machine and the offset cause in the
// reported coordinates: −(E + o) (program) or −E (machine), without pretravel and noise.
class Touch final : public Program {
 public:
  explicit Touch(const SimConfig& c) : c_(c.touch), chord_rng_(c.seed ^ 0x7A1C5EEDULL) {
    if (!c_.facet_export_path.empty()) {
      export_.open(c_.facet_export_path, std::ios::trunc);
      if (!export_) {
        throw std::runtime_error("program.touch.facet_export_path: cannot write " +
                                 c_.facet_export_path);
      }
      export_ << "face,chord_plus_mm,chord_minus_mm,t_s\n" << std::flush;
    }
    if (c_.request_register < 0) {
      queue_set(/*reference=*/true, 0);
      queue_set(false, 0);  // the nominals (cycle 0)
    }
  }
  [[nodiscard]] double max_step_s() const override { return 0.01; }

  bool step(Simulation& sim, double h_s) override {
    AxisSample& a = sim.mutable_axis();
    a.time_ns = sim.now_ns();
    a.cutting = false;
    a.has_normal = false;
    if (!started_) {
      sim.emit(ProgramEvent{sim.now_ns(), ProgramEventKind::kPartStart, 0});
      started_ = true;
    }
    const double t = sim.time_s();
    const bool warm = warm_start_s_ >= 0.0;
    // Fixed plan: done after the last cycle's set. Request mode: the shift lasts cycles ×
    // cycle_interval_s after the warm-up start (the daemon decides when to touch).
    const bool shift_over = c_.request_register < 0
                                ? warm && next_cycle_ > c_.cycles
                                : warm && t >= warm_start_s_ + c_.cycles * c_.cycle_interval_s;
    if ((shift_over && queue_.empty() && grind_end_s_ < 0.0) ||
        (c_.request_register >= 0 && t >= c_.give_up_s)) {
      sim.emit(ProgramEvent{sim.now_ns(), ProgramEventKind::kPartEnd, 0});
      return false;
    }
    if (grind_end_s_ >= 0.0) {
      if (t >= grind_end_s_) {
        finish_grind(sim);
      }
      return true;
    }
    if (!queue_.empty()) {
      wait_s_ += h_s;
      if (wait_s_ >= c_.touch_time_s) {
        wait_s_ = 0.0;
        touch(sim, queue_.front());
        queue_.erase(queue_.begin());
        if (queue_.empty() && set_is_nominal_ && !warm) {
          set_is_nominal_ = false;
          warm_start_s_ = c_.warm_up_after_nominals ? t : 0.0;
          std::fprintf(stderr,
                       "ncsim: touch: nominal set done at t = %.3f s; warm-up from %.3f s\n", t,
                       warm_start_s_);
          next_cycle_ = 1;
        }
      }
      return true;
    }
    if (c_.request_register < 0) {
      // Fixed plan: a set every cycle_interval_s after the warm-up start.
      if (warm && next_cycle_ <= c_.cycles &&
          t >= warm_start_s_ + next_cycle_ * c_.cycle_interval_s) {
        queue_set(false, next_cycle_++);
      }
      return true;
    }
    follow_request(sim);
    return true;
  }

 private:
  struct TouchStep {
    std::int32_t cycle, probe, slot;  // slot 0..3 = X lateral, X axial, Y, Z
  };

  void queue_set(bool reference, std::int32_t cycle) {
    for (std::int32_t slot = 0; slot < 4; ++slot) {
      for (std::int32_t i = 0; i < c_.touches_per_axis; ++i) {
        queue_.push_back({cycle, reference ? 1 : 0, slot});
      }
    }
    set_is_nominal_ = !reference && cycle == 0;
    wait_s_ = 0.0;
  }

  // The daemon's calibrator says what it waits for (core::calib::RequestCode).
  void follow_request(Simulation& sim) {
    const double raw = sim.reg(c_.request_register);
    const auto code = static_cast<std::int32_t>(std::lround(raw));
    const double ox = sim.reg(sim.config().nc.axis_register[0]);
    if (code == 0) {
      handled_ = 0;
      return;
    }
    if (code == 2 || code == 3) {
      // A new grind when the face changed or the daemon put a new Δx on X.
      if (code != handled_ || std::fabs(ox - ground_with_um_) > 1e-6) {
        handled_ = code;
        grind_face_ = code;
        grind_end_s_ = sim.time_s() + c_.grind_time_s;
      }
      return;
    }
    if (code == handled_) {
      return;  // done; the daemon has not yet moved on
    }
    handled_ = code;
    if (code == 1) {
      queue_set(true, 0);
    } else if (code == 4) {
      queue_set(false, 0);
    } else if (code == 5 && warm_start_s_ >= 0.0) {
      queue_set(false, next_cycle_++);
    }
  }

  [[nodiscard]] double static_error_um(std::int32_t slot) const {
    switch (slot) {
      case 0:
        return c_.axis_error_um[0];
      case 1:
        return c_.x_axial_error_um;
      default:
        return c_.axis_error_um[static_cast<std::size_t>(slot - 1)];
    }
  }

  // Machine error along the slot's axis at p [µm]: static + thermal (on the warm-up clock) +
  // pitch.
  double error_um(Simulation& sim, std::int32_t slot, const Vec3& p) const {
    const std::size_t ax = slot <= 1 ? 0 : static_cast<std::size_t>(slot - 1);
    const double thermal_t = c_.warm_up_after_nominals
                                 ? (warm_start_s_ >= 0.0 ? sim.time_s() - warm_start_s_ : 0.0)
                                 : sim.time_s();
    return static_error_um(slot) + sim.model().machine_error_um(p, thermal_t)[ax];
  }

  void touch(Simulation& sim, const TouchStep& t) {
    const bool reference = t.probe == 1;
    const bool axial = t.slot == 1;
    const std::size_t ax = t.slot <= 1 ? 0 : static_cast<std::size_t>(t.slot - 1);
    const Vec3& centre = reference ? c_.reference_center_mm : c_.body_center_mm;
    const double radius = reference
                              ? (axial ? c_.reference_axial_radius_mm : c_.reference_radius_mm)
                              : (axial ? c_.body_axial_radius_mm : c_.body_radius_mm);
    constexpr double dir = 1.0;  // every slot is touched from + (the calibrator's nominals)
    Vec3 p = centre;
    p[ax] -= dir * radius;
    const double e = error_um(sim, t.slot, p);
    const double o = sim.reg(sim.config().nc.axis_register[ax]);
    const double pre =
        reference ? (axial ? c_.reference_axial_pretravel_um : c_.reference_pretravel_um) : 0.0;
    const double shift_um = c_.program_coordinates ? -(e + o) : -e;
    const double noise_um = sim.model().probe_noise_um();
    const double trigger = p[ax] + (shift_um + dir * pre + noise_um) / 1000.0;
    AxisSample& a = sim.mutable_axis();
    Vec3 pos = p;
    pos[ax] = trigger;
    for (std::size_t i = 0; i < 3; ++i) {
      a.position_mm[i] = pos[i];
    }
    core::CalibrationTouch ct{};
    ct.time_ns = sim.now_ns();
    ct.probe = reference ? core::ProbeKind::kReferenceProbe : core::ProbeKind::kMachineProbe;
    ct.axis = static_cast<std::uint8_t>(ax);
    ct.direction = 1;
    ct.variant = axial ? 1 : 0;
    ct.trigger_position_mm = trigger;
    sim.emit(ct);
    sim.mutable_results().touches.push_back(
        {t.cycle, t.probe, static_cast<std::int32_t>(ax), 1, axial ? 1 : 0, trigger, shift_um});
  }

  static double chord_mm(double radius_mm, double depth_mm) {
    if (depth_mm <= 0.0) {
      return 0.0;  // not touched by the wheel: no facet
    }
    const double d = std::min(depth_mm, radius_mm);
    return 2.0 * std::sqrt(2.0 * radius_mm * d - d * d);
  }

  void finish_grind(Simulation& sim) {
    grind_end_s_ = -1.0;
    const double ox = sim.reg(sim.config().nc.axis_register[0]);
    ground_with_um_ = ox;
    const bool end_face = grind_face_ == 3;
    const double e = error_um(sim, end_face ? 1 : 0, c_.body_center_mm) + ox;
    const double d0 = c_.grind_depth_mm;
    const double cp = chord_mm(c_.blank_radius_mm, d0 - e / 1000.0) +
                      c_.chord_noise_um * chord_rng_.gaussian() / 1000.0;
    const double cm = chord_mm(c_.blank_radius_mm, d0 + e / 1000.0) +
                      c_.chord_noise_um * chord_rng_.gaussian() / 1000.0;
    std::fprintf(stderr,
                 "ncsim: touch: %s test grind at t = %.3f s with X offset %+.3f um: error %+.3f "
                 "um, chords %.6f / %.6f mm\n",
                 end_face ? "end-face" : "lateral", sim.time_s(), ox, e, cp, cm);
    if (export_.is_open()) {
      char line[160];
      std::snprintf(line, sizeof line, "%s,%.6f,%.6f,%.3f\n", end_face ? "end-face" : "lateral", cp,
                    cm, sim.time_s());
      export_ << line << std::flush;
    }
  }

  TouchConfig c_;
  Rng chord_rng_;
  std::ofstream export_;
  std::vector<TouchStep> queue_;
  double wait_s_{0.0};
  bool started_{false};
  bool set_is_nominal_{false};
  /// Start of the thermal warm-up (−1: not yet; the nominal set starts it).
  double warm_start_s_{-1.0};
  std::int32_t next_cycle_{1};
  /// Request mode: the code last acted on, the grind in progress and the X offset of the last.
  std::int32_t handled_{0};
  std::int32_t grind_face_{0};
  double grind_end_s_{-1.0};
  double ground_with_um_{std::numeric_limits<double>::quiet_NaN()};
};

// ---------------------------------------------------------------------------------------------
// (c) roll grinding (S2): the wheel's reference point T follows the trajectory along Z; the
// ground radius is the envelope B(z) = min over T of [U_T + g(z − Z_T)] (seeds.md S2, exact),
// with the wheel's wear, the machine's drift and the X axis offset moving U_T.
class Roll final : public Program {
 public:
  explicit Roll(const SimConfig& c) : c_(c.roll), step_mm_(c.step_mm) {
    if (c_.z_mm.size() < 2 || c_.target_z_mm.size() < 2) {
      throw std::invalid_argument("roll: needs a trajectory and a target profile");
    }
    const double w = c_.wheel_width_mm;
    const double h = c_.wheel_height_mm;
    radius_mm_ = h > 0.0 ? h / 2.0 + w * w / (8.0 * h) : std::numeric_limits<double>::infinity();
    z0_ = c_.target_z_mm.front();
    const double z1 = c_.target_z_mm.back();
    cells_ = static_cast<std::size_t>(std::floor((z1 - z0_) / step_mm_)) + 1;
    ground_.assign(cells_, std::numeric_limits<double>::infinity());
    offset_.assign(cells_, 0.0);
    target_ = Curve{c_.target_z_mm, c_.target_u_mm};
    traj_ = Curve{c_.z_mm, c_.u_mm};
    zt_ = c_.z_mm.front();
  }
  [[nodiscard]] double max_step_s() const override {
    return step_mm_ / (c_.feed_mm_per_min / 60.0);
  }

  bool step(Simulation& sim, double h_s) override {
    AxisSample& a = sim.mutable_axis();
    a.time_ns = sim.now_ns();
    a.tool = sim.config().nc.tool;
    if (!started_) {
      sim.emit(ProgramEvent{sim.now_ns(), ProgramEventKind::kPartStart, 1});
      started_ = true;
    }
    const double d = c_.feed_mm_per_min / 60.0 * h_s;
    zt_ = std::min(zt_ + d, c_.z_mm.back());
    path_mm_ += d;
    MachineModel& m = sim.model();
    const NcConfig& nc = sim.config().nc;
    const double ut = traj_.at(zt_);
    const Vec3 p{ut, 0.0, zt_};
    const Vec3 drift = m.machine_error_um(p, sim.time_s());
    const double wear = m.wear_um(path_mm_);
    const double o = sim.reg(nc.axis_register[0]);
    // The wheel's surface recedes with wear and push-off (material left), the X drift and offset
    // move it radially, the Z drift shifts where it grinds.
    const double u_eff = ut + (wear + m.pushoff_um(p, wear) + drift[0] + o) / 1000.0;
    const double z_eff = zt_ + drift[2] / 1000.0;
    const double half = c_.wheel_width_mm / 2.0;
    const auto lo = static_cast<std::ptrdiff_t>(std::ceil((z_eff - half - z0_) / step_mm_));
    const auto hi = static_cast<std::ptrdiff_t>(std::floor((z_eff + half - z0_) / step_mm_));
    for (std::ptrdiff_t i = std::max<std::ptrdiff_t>(lo, 0);
         i <= std::min<std::ptrdiff_t>(hi, static_cast<std::ptrdiff_t>(cells_) - 1); ++i) {
      const double s = z0_ + static_cast<double>(i) * step_mm_ - z_eff;
      const double g = std::isinf(radius_mm_)
                           ? 0.0
                           : radius_mm_ - std::sqrt(std::max(radius_mm_ * radius_mm_ - s * s, 0.0));
      const double b = u_eff + g;
      const auto k = static_cast<std::size_t>(i);
      if (b < ground_[k]) {
        ground_[k] = b;
        offset_[k] = -o;
      }
    }
    for (std::size_t i = 0; i < 3; ++i) {
      a.position_mm[i] = p[i];
    }
    a.position_mm[0] += o / 1000.0;
    a.program_path_mm = path_mm_;
    a.cutting = true;
    a.has_normal = true;
    a.normal = {1.0, 0.0, 0.0};
    if (zt_ >= c_.z_mm.back() - 1e-12) {
      record(sim);
      ++pass_;
      if (pass_ >= c_.passes) {
        sim.emit(ProgramEvent{sim.now_ns(), ProgramEventKind::kPartEnd, 1});
        return false;
      }
      zt_ = c_.z_mm.front();
    }
    return true;
  }

 private:
  void record(Simulation& sim) {
    auto& rows = sim.mutable_results().surface;
    for (std::size_t i = 0; i < cells_; ++i) {
      if (std::isinf(ground_[i])) {
        continue;  // never reached by the wheel
      }
      const double z = z0_ + static_cast<double>(i) * step_mm_;
      rows.push_back(
          {pass_, z, ground_[i], 0.0, z, (ground_[i] - target_.at(z)) * 1000.0, offset_[i]});
    }
  }

  RollConfig c_;
  double step_mm_;
  double radius_mm_{0.0};
  double z0_{0.0};
  std::size_t cells_{0};
  std::vector<double> ground_;
  std::vector<double> offset_;
  Curve target_;
  Curve traj_;
  double zt_{0.0};
  double path_mm_{0.0};
  std::int32_t pass_{0};
  bool started_{false};
};

}  // namespace

std::unique_ptr<Program> make_touch_program(const SimConfig& c) {
  return std::make_unique<Touch>(c);
}
std::unique_ptr<Program> make_roll_program(const SimConfig& c) { return std::make_unique<Roll>(c); }

}  // namespace nccomp::sim::ncsim
