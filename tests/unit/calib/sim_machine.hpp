// A simulated grinding machine with known errors for the S3 tests and benchmarks: the truth
// against which the calibrator is judged. Shared by tests/unit/calib and bench/calib.
//
// Model (the model is described here; docs/calibration.md describes the method it checks):
// - static axis errors E_x (lateral), E_xa (axial, along the stylus), E_y, E_z [µm];
// - the reference probe triggers late by its pretravel p_lat / p_ax in the approach direction,
//   the same in every lateral direction;
// - a test grind with X correction Δ applied leaves facets of depth d0 ± (E − Δ) on a cylinder
//   of radius ρ; the operator measures their chords with chord noise;
// - the machine probe touches the test body at nominal + drift(t), with touch noise; the drift
//   per slot (X lateral, X axial, Y, Z) is a function of time supplied by the test;
// - positions are machine coordinates (independent of the axis offsets), or with
//   set_program_frame(true) program coordinates: machine position − the axis offset in force
//   (offset_um, which the test keeps equal to what the NC holds: the last register write).
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <functional>
#include <random>
#include <span>
#include <utility>

#include "core/calib/calibrator.hpp"
#include "core/calib/config.hpp"
#include "core/calib/facet.hpp"
#include "core/calib/state.hpp"
#include "core/common/types.hpp"

namespace nccomp::test::calib {

using core::CalibrationTouch;
using core::ProbeKind;
using core::TimeNs;
using core::calib::CalibrationConfig;
using core::calib::kSlotCount;

struct MachineErrors {
  double ex_um{0.0};
  double exa_um{0.0};
  double ey_um{0.0};
  double ez_um{0.0};
  double pretravel_lateral_um{0.0};
  double pretravel_axial_um{0.0};
};

class SimMachine {
 public:
  using DriftFn = std::function<std::array<double, kSlotCount>(double t_s)>;

  SimMachine(const CalibrationConfig& config, MachineErrors errors, double touch_noise_um,
             double chord_noise_um, double nominal_depth_mm, std::uint64_t seed)
      : config_(config),
        errors_(errors),
        touch_noise_um_(touch_noise_um),
        chord_noise_um_(chord_noise_um),
        depth_mm_(nominal_depth_mm),
        rng_(seed) {}

  void set_drift(DriftFn drift) { drift_ = std::move(drift); }
  void set_program_frame(bool on) { program_frame_ = on; }
  /// The axis offsets X, Y, Z the NC holds [µm] (program frame only).
  std::array<double, 3> offset_um{};

  /// Reference-probe touch of the reference disk; slot 0..3 = X lateral, X axial, Y, Z.
  CalibrationTouch reference_touch(std::size_t slot, std::int8_t direction, TimeNs t_ns) {
    const std::array<double, kSlotCount> centre{config_.reference_x_lateral_mm,
                                                config_.reference_x_axial_mm,
                                                config_.reference_y_mm, config_.reference_z_mm};
    const std::array<double, kSlotCount> error{errors_.ex_um, errors_.exa_um, errors_.ey_um,
                                               errors_.ez_um};
    const double contact =
        slot == 1 ? config_.reference_axial_contact_mm : config_.reference_contact_mm;
    const double pretravel = slot == 1 ? errors_.pretravel_axial_um : errors_.pretravel_lateral_um;
    const double trigger_um = error[slot] + direction * pretravel + noise(touch_noise_um_);
    return make_touch(ProbeKind::kReferenceProbe, slot, direction,
                      centre[slot] - direction * contact + trigger_um / 1000.0 - frame_mm(slot),
                      t_ns);
  }

  /// Machine-probe touch of the test body at time t.
  CalibrationTouch machine_touch(std::size_t slot, std::int8_t direction, TimeNs t_ns) {
    const std::array<double, kSlotCount> body{120.0, 80.0, -40.0, 15.0};
    const double drift_um = drift_ ? drift_(core::seconds(t_ns))[slot] : 0.0;
    return make_touch(ProbeKind::kMachineProbe, slot, direction,
                      body[slot] - direction * 2.0 + (drift_um + noise(touch_noise_um_)) / 1000.0 -
                          frame_mm(slot),
                      t_ns);
  }

  /// Test grind with correction_um applied on X; returns the chords {c+, c−} [mm].
  std::pair<double, double> test_grind(bool end_face, double correction_um) {
    const double e_mm = ((end_face ? errors_.exa_um : errors_.ex_um) - correction_um) / 1000.0;
    const double rho = config_.blank_radius_mm;
    return {core::calib::chord_from_depth_mm(rho, depth_mm_ + e_mm) + noise(chord_noise_um_) / 1e3,
            core::calib::chord_from_depth_mm(rho, depth_mm_ - e_mm) + noise(chord_noise_um_) / 1e3};
  }

  [[nodiscard]] std::array<double, kSlotCount> drift_um(double t_s) const {
    return drift_ ? drift_(t_s) : std::array<double, kSlotCount>{};
  }
  [[nodiscard]] const MachineErrors& errors() const { return errors_; }

 private:
  static CalibrationTouch make_touch(ProbeKind probe, std::size_t slot, std::int8_t direction,
                                     double position_mm, TimeNs t_ns) {
    CalibrationTouch t;
    t.time_ns = t_ns;
    t.probe = probe;
    t.axis = static_cast<std::uint8_t>(slot <= 1 ? 0 : slot - 1);
    t.variant = static_cast<std::uint8_t>(slot == 1 ? 1 : 0);
    t.direction = direction;
    t.trigger_position_mm = position_mm;
    return t;
  }
  /// Program coordinates read the offset of the touched axis less.
  [[nodiscard]] double frame_mm(std::size_t slot) const {
    return program_frame_ ? offset_um[slot <= 1 ? 0 : slot - 1] / 1000.0 : 0.0;
  }
  double noise(double sigma) {
    return sigma > 0.0 ? std::normal_distribution<double>(0.0, sigma)(rng_) : 0.0;
  }

  CalibrationConfig config_;
  MachineErrors errors_;
  double touch_noise_um_;
  double chord_noise_um_;
  double depth_mm_;
  std::mt19937_64 rng_;
  DriftFn drift_;
  bool program_frame_{false};
};

/// Drives a whole initial calibration (reference touches, test grinds, nominal touches) of c on
/// machine m, one touch per 1 s step from now_ns on; returns false if it did not reach ready.
inline bool run_initial_calibration(core::calib::Calibrator& c, SimMachine& m, TimeNs& now_ns,
                                    core::StepOutput& out) {
  using core::calib::Face;
  using core::calib::Phase;
  const auto one_step = [&](const CalibrationTouch& t) {
    const core::Event e = t;
    out.clear();
    c.step(now_ns, std::span<const core::Event>(&e, 1), out);
    now_ns += core::from_seconds(1.0);
  };
  c.begin_calibration(now_ns, out);
  const int n = c.config().touches_per_axis;
  for (std::size_t slot = 0; slot < kSlotCount; ++slot) {
    for (int i = 0; i < n; ++i) {
      one_step(m.reference_touch(slot, 1, now_ns));
    }
  }
  for (const bool end_face : {false, true}) {
    const Phase want = end_face ? Phase::kTestGrindEndFace : Phase::kTestGrindLateral;
    while (c.phase() == want) {
      const auto [plus, minus] = m.test_grind(end_face, c.grind_correction_um());
      out.clear();
      const auto r =
          c.enter_facets(end_face ? Face::kEndFace : Face::kLateral, plus, minus, now_ns, out);
      now_ns += core::from_seconds(600.0);  // a test grind and its measurement take a while
      if (r.status != core::calib::FacetStatus::kGrindAgain &&
          r.status != core::calib::FacetStatus::kConverged) {
        // No facet to measure (error deeper than the nominal depth) or given up.
        return false;
      }
    }
  }
  for (std::size_t slot = 0; slot < kSlotCount; ++slot) {
    for (int i = 0; i < n; ++i) {
      one_step(m.machine_touch(slot, 1, now_ns));
    }
  }
  return c.phase() == Phase::kReady;
}

/// One recalibration touch set (all slots, touches_per_axis each) at now_ns, in one step.
inline void run_touch_set(core::calib::Calibrator& c, SimMachine& m, TimeNs now_ns,
                          core::StepOutput& out) {
  std::array<core::Event, kSlotCount * 8> events{};
  std::size_t k = 0;
  const int n = c.config().touches_per_axis;
  for (std::size_t slot = 0; slot < kSlotCount; ++slot) {
    for (int i = 0; i < n; ++i) {
      events[k++] = m.machine_touch(slot, 1, now_ns);
    }
  }
  c.step(now_ns, std::span<const core::Event>(events.data(), k), out);
}

}  // namespace nccomp::test::calib
