// Programs (c) roll and (d) touch of the virtual NC.
#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "sim/ncsim/simulation.hpp"

namespace nccomp::sim::ncsim {

using core::AxisSample;
using core::ProgramEvent;
using core::ProgramEventKind;

namespace {

// ---------------------------------------------------------------------------------------------
// (d) touch cycles (S3): the reference probe on the reference disk (initial calibration), then
// the machine probe on the test body now (nominals) and every cycle_interval_s while the machine
// warms up. Each touch reports the axis position at the trigger, in program coordinates: the
// machine's drift d and the NC's axis offset o both move the probe, so the trigger comes
// (d + o) early.
class Touch final : public Program {
 public:
  explicit Touch(const SimConfig& c) : c_(c.touch) {
    // Initial: reference probe on the disk, X lateral and axial, Y, Z (from +).
    plan_.push_back({0, 1, 0, 1, 0});
    plan_.push_back({0, 1, 0, 1, 1});
    plan_.push_back({0, 1, 1, 1, 0});
    plan_.push_back({0, 1, 2, 1, 0});
    for (std::int32_t cycle = 0; cycle <= c_.cycles; ++cycle) {
      for (const auto& [axis, dir] : {std::pair{0, 1}, std::pair{0, -1}, std::pair{1, 1},
                                      std::pair{1, -1}, std::pair{2, 1}}) {
        plan_.push_back({cycle, 0, axis, dir, 0});
      }
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
    if (next_ >= plan_.size()) {
      sim.emit(ProgramEvent{sim.now_ns(), ProgramEventKind::kPartEnd, 0});
      return false;
    }
    const TouchStep& t = plan_[next_];
    // Recalibration cycles start every cycle_interval_s (cycle 0 right away).
    const double cycle_start = static_cast<double>(t.cycle) * c_.cycle_interval_s;
    wait_s_ += h_s;
    if (sim.time_s() < cycle_start || wait_s_ < c_.touch_time_s) {
      return true;
    }
    wait_s_ = 0.0;
    const bool reference = t.probe == 1;
    const Vec3& centre = reference ? c_.reference_center_mm : c_.body_center_mm;
    const double radius = reference ? c_.reference_radius_mm : c_.body_radius_mm;
    const auto ax = static_cast<std::size_t>(t.axis);
    Vec3 p = centre;
    p[ax] -= static_cast<double>(t.direction) * radius;
    MachineModel& m = sim.model();
    const Vec3 d = m.machine_error_um(p, sim.time_s());
    const NcConfig& nc = sim.config().nc;
    const double o = sim.reg(nc.axis_register[ax]);
    // The drift along the approach moves the trigger; across it, it does not.
    const double shift_um = -(d[ax] + o);
    const double noise_um = m.probe_noise_um();
    const double trigger = p[ax] + (shift_um + noise_um) / 1000.0;
    Vec3 pos = p;
    pos[ax] = trigger;
    for (std::size_t i = 0; i < 3; ++i) {
      a.position_mm[i] = pos[i];
    }
    core::CalibrationTouch ct{};
    ct.time_ns = sim.now_ns();
    ct.probe = reference ? core::ProbeKind::kReferenceProbe : core::ProbeKind::kMachineProbe;
    ct.axis = static_cast<std::uint8_t>(t.axis);
    ct.direction = static_cast<std::int8_t>(t.direction);
    ct.variant = static_cast<std::uint8_t>(t.variant);
    ct.trigger_position_mm = trigger;
    sim.emit(ct);
    sim.mutable_results().touches.push_back(
        {t.cycle, t.probe, t.axis, t.direction, t.variant, trigger, shift_um});
    ++next_;
    return true;
  }

 private:
  struct TouchStep {
    std::int32_t cycle, probe, axis, direction, variant;
  };
  TouchConfig c_;
  std::vector<TouchStep> plan_;
  std::size_t next_{0};
  double wait_s_{0.0};
  bool started_{false};
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
