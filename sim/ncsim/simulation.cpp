#include "sim/ncsim/simulation.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>

#include "core/checkpoint/plan.hpp"

namespace nccomp::sim::ncsim {

using core::AxisSample;
using core::ProgramEvent;
using core::ProgramEventKind;

namespace {

constexpr double kDegPerRad = 180.0 / std::numbers::pi;

Vec3 axis_offsets_um(const Simulation& sim) {
  const NcConfig& nc = sim.config().nc;
  return {sim.reg(nc.axis_register[0]), sim.reg(nc.axis_register[1]), sim.reg(nc.axis_register[2])};
}

void set_position(AxisSample& a, const Vec3& p_mm, const Vec3& offsets_um) {
  // The NC reports its commanded machine position, offsets included.
  for (std::size_t i = 0; i < 3; ++i) {
    a.position_mm[i] = p_mm[i] + offsets_um[i] / 1000.0;
  }
  a.axis_count = 3;
}

// ---------------------------------------------------------------------------------------------
// (a) mould face: raster passes along X with a ball-end mill, zig-zag, links along Y.
class MouldFace final : public Program {
 public:
  explicit MouldFace(const SimConfig& c)
      : c_(c.mould_face),
        first_part_(c.first_part),
        last_part_(c.first_part + c.parts - 1),
        step_mm_(c.step_mm),
        part_(c.first_part),
        cut_path_mm_(c.tool_cut_path_mm),
        last_measure_mm_(c.tool_cut_path_mm) {
    passes_ = static_cast<std::int32_t>(std::floor(c_.size_y_mm / c_.stepover_mm + 1e-9)) + 1;
    const auto n = static_cast<std::size_t>(c_.probe_points);
    probes_.resize(n);
    for (std::size_t j = 0; j < n; ++j) {
      probes_[j].pass = n == 1 ? passes_ / 2
                               : static_cast<std::int32_t>(std::lround(
                                     static_cast<double>(j) * static_cast<double>(passes_ - 1) /
                                     (static_cast<double>(n) - 1.0)));
    }
  }
  [[nodiscard]] double max_step_s() const override {
    return step_mm_ / (c_.feed_mm_per_min / 60.0);
  }
  [[nodiscard]] EndState end_state() const override {
    return {true, phase_ == Phase::kDone ? part_ + 1 : part_, cut_path_mm_};
  }

  bool step(Simulation& sim, double h_s) override {
    const double d_mm = c_.feed_mm_per_min / 60.0 * h_s;
    const NcConfig& nc = sim.config().nc;
    AxisSample& a = sim.mutable_axis();
    a.time_ns = sim.now_ns();
    a.tool = nc.tool;
    switch (phase_) {
      case Phase::kStart:
        if (part_ == first_part_) {
          // The NC reports the tool in the spindle at the program start.
          sim.emit(core::ToolChange{sim.now_ns(), nc.tool, false});
        }
        sim.emit(ProgramEvent{sim.now_ns(), ProgramEventKind::kPartStart, part_});
        sim.model().set_part(part_);
        approach_left_s_ = c_.approach_s;
        phase_ = approach_left_s_ > 0.0 ? Phase::kApproach : Phase::kCut;
        return step(sim, h_s);
      case Phase::kApproach:
        // At the first pass's start, not cutting, for approach_s (the tool comes down to the
        // face; the daemon sees the part start before the first cut).
        publish(sim, dir_ > 0 ? 0.0 : c_.size_x_mm, pass_y(), false);
        approach_left_s_ -= h_s;
        if (approach_left_s_ <= 1e-12) {
          phase_ = Phase::kCut;
        }
        return true;
      case Phase::kCut:
        cut(sim, d_mm);
        return true;
      case Phase::kLink: {
        const double d = std::min(d_mm, link_left_mm_);
        link_left_mm_ -= d;
        path_mm_ += d;
        const double y =
            std::min(static_cast<double>(pass_) * c_.stepover_mm + d_link_done(), c_.size_y_mm);
        const double x = dir_ > 0 ? c_.size_x_mm : 0.0;
        publish(sim, x, y, false);
        if (link_left_mm_ <= 1e-12) {
          ++pass_;
          dir_ = -dir_;
          u_mm_ = 0.0;
          phase_ = Phase::kCut;
        }
        return true;
      }
      case Phase::kTrip:
        trip(sim, h_s);
        return true;
      case Phase::kProbe:
        probe(sim, h_s);
        return true;
      case Phase::kDone:
        return false;
    }
    return false;
  }

 private:
  enum class Phase : std::uint8_t { kStart, kApproach, kCut, kLink, kTrip, kProbe, kDone };

  /// A point of the probe cycle: the face at mid-X of one pass, and its error as cut.
  struct ProbePoint {
    std::int32_t pass{0};
    double dx_mm{1e300};  // distance from mid-X of the sample the error is from
    Vec3 p_mm{};
    double error_um{0.0};
  };

  double d_link_done() const { return c_.stepover_mm - link_left_mm_; }
  double pass_y() const {
    return std::min(static_cast<double>(pass_) * c_.stepover_mm, c_.size_y_mm);
  }

  void publish(Simulation& sim, double x, double y, bool cutting) {
    AxisSample& a = sim.mutable_axis();
    const Vec3 n = mould_face_normal(c_, x, y);
    const double z = mould_face_z_mm(c_, x, y);
    const double r = c_.ball_radius_mm;
    set_position(a, {x + r * n[0], y + r * n[1], z + r * n[2]}, axis_offsets_um(sim));
    a.program_path_mm = path_mm_;
    a.has_normal = true;
    a.normal = n;
    a.cutting = cutting;
  }

  void cut(Simulation& sim, double d_mm) {
    const double d = std::min(d_mm, c_.size_x_mm - u_mm_);
    u_mm_ += d;
    path_mm_ += d;
    cut_path_mm_ += d;
    const double x = dir_ > 0 ? u_mm_ : c_.size_x_mm - u_mm_;
    const double y = pass_y();
    publish(sim, x, y, true);
    record(sim, x, y);
    if (u_mm_ >= c_.size_x_mm - 1e-12) {
      if (pass_ + 1 < passes_) {
        phase_ = Phase::kLink;
        link_left_mm_ = std::min(c_.stepover_mm, c_.size_y_mm - pass_y());
        if (link_left_mm_ <= 1e-12) {
          link_left_mm_ = 1e-9;
        }
      } else if (!probes_.empty()) {
        phase_ = Phase::kProbe;
        probe_index_ = 0;
        probe_s_ = 0.0;
      } else {
        end_part(sim);
      }
    }
    maybe_measure(sim);
  }

  void end_part(Simulation& sim) {
    sim.emit(ProgramEvent{sim.now_ns(), ProgramEventKind::kPartEnd, part_});
    total_passes_ += passes_;
    if (part_ < last_part_) {
      ++part_;
      pass_ = 0;
      dir_ = 1;
      u_mm_ = 0.0;
      path_mm_ = 0.0;
      phase_ = Phase::kStart;
      for (ProbePoint& q : probes_) {
        q.dx_mm = 1e300;
      }
    } else {
      phase_ = Phase::kDone;
      sim.mutable_axis().cutting = false;
    }
  }

  // The probe touches the finished face along its normal (no wall angle, so no δ0): it reads
  // the face's deviation as cut, push-off included, which the laser never sees.
  void probe(Simulation& sim, double h_s) {
    AxisSample& a = sim.mutable_axis();
    a.cutting = false;
    a.has_normal = false;
    if (probe_index_ >= probes_.size()) {
      end_part(sim);
      return;
    }
    const ProbePoint& q = probes_[probe_index_];
    set_position(a, q.p_mm, axis_offsets_um(sim));
    probe_s_ += h_s;
    if (probe_s_ < c_.probe_time_s) {
      return;
    }
    probe_s_ = 0.0;
    const double raw = q.error_um + sim.model().probe_noise_um();
    core::ProbeMeasurement pm{};
    pm.time_ns = sim.now_ns();
    pm.part = part_;
    pm.checkpoint = static_cast<std::int32_t>(probe_index_);
    pm.raw_deviation_um = raw;
    pm.wall_angle_deg = 0.0;
    pm.ball_radius_mm = c_.ball_radius_mm;
    pm.position_mm = q.p_mm;
    sim.emit(pm);
    sim.mutable_results().measurements.push_back({sim.time_s(), MeasurementKind::kProbe, part_,
                                                  pm.checkpoint, cut_path_mm_, q.error_um, raw,
                                                  false});
    ++probe_index_;
  }

  void record(Simulation& sim, double x, double y) {
    const NcConfig& nc = sim.config().nc;
    MachineModel& m = sim.model();
    const Vec3 n = mould_face_normal(c_, x, y);
    const Vec3 p{x, y, mould_face_z_mm(c_, x, y)};
    const double w = m.wear_um(cut_path_mm_);
    const double e_machine = w + m.pushoff_um(p, w) + dot(m.machine_error_um(p, sim.time_s()), n);
    const double sin_theta = std::sqrt(std::max(0.0, 1.0 - n[2] * n[2]));
    // Offsets act as the NC applies them: axis offsets shift the tool, length wear moves it along
    // the tool axis (Z), radius wear across it.
    const double comp = dot(axis_offsets_um(sim), n) + sim.reg(nc.tool_length_register) * n[2] +
                        sim.reg(nc.tool_radius_register) * sin_theta;
    sim.mutable_results().surface.push_back(
        {total_passes_ + pass_, path_mm_, p[0], p[1], p[2], e_machine + comp, 0.0 - comp});
    for (ProbePoint& q : probes_) {
      const double dx = std::fabs(x - 0.5 * c_.size_x_mm);
      if (q.pass == pass_ && dx < q.dx_mm) {
        q.dx_mm = dx;
        q.p_mm = p;
        q.error_um = e_machine + comp;
      }
    }
  }

  void maybe_measure(Simulation& sim) {
    const NcConfig& nc = sim.config().nc;
    bool due =
        c_.measure_interval_mm > 0.0 && cut_path_mm_ - last_measure_mm_ >= c_.measure_interval_mm;
    if (nc.measure_request_register >= 0) {
      const bool request = std::fabs(sim.reg(nc.measure_request_register)) > 0.0;
      due = due || (request && !request_seen_);
      request_seen_ = request;
    }
    if (due && phase_ != Phase::kDone) {
      sim.emit(ProgramEvent{sim.now_ns(), ProgramEventKind::kInterruption, part_});
      resume_phase_ = phase_;
      phase_ = Phase::kTrip;
      trip_s_ = 0.0;
      measured_ = false;
    }
  }

  void trip(Simulation& sim, double h_s) {
    trip_s_ += h_s;
    AxisSample& a = sim.mutable_axis();
    set_position(a, c_.laser_position_mm, axis_offsets_um(sim));
    a.cutting = false;
    a.has_normal = false;
    MachineModel& m = sim.model();
    if (!measured_ && trip_s_ >= 0.5 * c_.laser_trip_s) {
      core::ToolMeasurement tm{};
      tm.time_ns = sim.now_ns();
      tm.tool = sim.config().nc.tool;
      const bool broken = m.broken(cut_path_mm_);
      tm.broken = broken && m.config().broken_tool.report_flag;
      tm.point_count = 1;
      tm.wear_um[0] = m.laser_reading_um(cut_path_mm_);
      sim.emit(tm);
      sim.mutable_results().measurements.push_back({sim.time_s(), MeasurementKind::kLaser, part_,
                                                    -1, cut_path_mm_, m.wear_um(cut_path_mm_),
                                                    tm.wear_um[0], tm.broken});
      measured_ = true;
    }
    if (trip_s_ >= c_.laser_trip_s) {
      last_measure_mm_ = cut_path_mm_;
      sim.emit(ProgramEvent{sim.now_ns(), ProgramEventKind::kResume, part_});
      phase_ = resume_phase_;
    }
  }

  MouldFaceConfig c_;
  std::int32_t first_part_;
  std::int32_t last_part_;
  double step_mm_;
  std::int32_t part_;
  double cut_path_mm_;
  double last_measure_mm_;
  std::int32_t passes_{0};
  std::int32_t pass_{0};
  std::int32_t total_passes_{0};
  int dir_{1};
  double u_mm_{0.0};
  double approach_left_s_{0.0};
  double link_left_mm_{0.0};
  double path_mm_{0.0};
  bool request_seen_{false};
  Phase phase_{Phase::kStart};
  Phase resume_phase_{Phase::kCut};
  double trip_s_{0.0};
  bool measured_{false};
  std::vector<ProbePoint> probes_;
  std::size_t probe_index_{0};
  double probe_s_{0.0};
};

// ---------------------------------------------------------------------------------------------
// (b) side wall: the contour of the [checkpoints] plan cut once per level (the plan's levels and
// program path positions), then probed at every checkpoint; part after part.
class SideWall final : public Program {
 public:
  explicit SideWall(const SimConfig& c)
      : c_(c.side_wall),
        first_part_(c.first_part),
        last_part_(c.first_part + c.parts - 1),
        step_mm_(c.step_mm),
        plan_(checked_plan(c_)),
        part_(c.first_part),
        cut_path_mm_(c.tool_cut_path_mm) {
    const auto& pts = c_.plan.contour;
    const std::size_t n = pts.size();
    const std::size_t segs = c_.plan.closed ? n : n - 1;
    double area2 = 0.0;
    for (std::size_t i = 0; i < n; ++i) {
      const auto& p = pts[i];
      const auto& q = pts[(i + 1) % n];
      area2 += p.x_mm * q.y_mm - q.x_mm * p.y_mm;
    }
    using core::checkpoint::MaterialSide;
    bool material_left = c_.plan.material == MaterialSide::kLeft;
    if (c_.plan.material == MaterialSide::kInside) {
      material_left = area2 > 0.0;  // counter-clockwise: the inside is on the left
    } else if (c_.plan.material == MaterialSide::kOutside) {
      material_left = area2 < 0.0;
    }
    s0_.push_back(0.0);
    for (std::size_t i = 0; i < segs; ++i) {
      const auto& p = pts[i];
      const auto& q = pts[(i + 1) % n];
      const double dx = q.x_mm - p.x_mm;
      const double dy = q.y_mm - p.y_mm;
      const double len = std::hypot(dx, dy);
      const double tx = len > 0 ? dx / len : 1.0;
      const double ty = len > 0 ? dy / len : 0.0;
      // Air side = away from the material.
      seg_n_.push_back(material_left ? Vec3{ty, -tx, 0.0} : Vec3{-ty, tx, 0.0});
      s0_.push_back(s0_.back() + len);
    }
    length_mm_ = s0_.back();
    link_mm_ = c_.plan.level_link_mm < 0.0 ? c_.plan.depth_step_mm : c_.plan.level_link_mm;
    cells_ = static_cast<std::size_t>(std::ceil(length_mm_ / step_mm_)) + 1;
    wall_.assign(plan_.levels_z_mm.size(), std::vector<double>(cells_, 0.0));
  }
  [[nodiscard]] double max_step_s() const override {
    return step_mm_ / (c_.feed_mm_per_min / 60.0);
  }
  [[nodiscard]] const core::checkpoint::Plan& plan() const { return plan_; }
  [[nodiscard]] EndState end_state() const override {
    return {true, phase_ == Phase::kDone ? part_ + 1 : part_, cut_path_mm_};
  }

  static core::checkpoint::Plan checked_plan(const SideWallConfig& c) {
    if (c.plan.contour.size() < 2) {
      throw std::invalid_argument(
          "side_wall: no wall to machine: set program.side_wall.checkpoints_file (a file with "
          "the [checkpoints] table, contour of at least 2 points)");
    }
    return core::checkpoint::make_plan(c.plan);
  }

  bool step(Simulation& sim, double h_s) override {
    const double d_mm = c_.feed_mm_per_min / 60.0 * h_s;
    const NcConfig& nc = sim.config().nc;
    AxisSample& a = sim.mutable_axis();
    a.time_ns = sim.now_ns();
    a.tool = nc.tool;
    switch (phase_) {
      case Phase::kStart:
        if (part_ == first_part_) {
          // The NC reports the tool in the spindle at the program start.
          sim.emit(core::ToolChange{sim.now_ns(), nc.tool, false});
        }
        sim.emit(ProgramEvent{sim.now_ns(), ProgramEventKind::kPartStart, part_});
        sim.model().set_part(part_);
        phase_ = Phase::kApproach;
        approach_left_s_ = c_.approach_s;
        level_ = 0;
        s_mm_ = 0.0;
        return step(sim, h_s);
      case Phase::kApproach:
        publish(sim, 0.0, plan_.levels_z_mm[0], false);
        approach_left_s_ -= h_s;
        if (approach_left_s_ <= 1e-12) {
          phase_ = Phase::kCut;
        }
        return true;
      case Phase::kCut:
        cut(sim, d_mm);
        return true;
      case Phase::kLink: {
        const double d = std::min(d_mm, link_left_mm_);
        link_left_mm_ -= d;
        path_mm_ += d;
        publish(sim, 0.0, plan_.levels_z_mm[static_cast<std::size_t>(level_)], false);
        if (link_left_mm_ <= 1e-12) {
          ++level_;
          s_mm_ = 0.0;
          phase_ = Phase::kCut;
        }
        return true;
      }
      case Phase::kProbe:
        probe(sim, h_s);
        return true;
      case Phase::kDone:
        return false;
    }
    return false;
  }

 private:
  enum class Phase : std::uint8_t { kStart, kApproach, kCut, kLink, kProbe, kDone };

  std::size_t segment(double s) const {
    const auto it = std::upper_bound(s0_.begin(), s0_.end(), s);
    const auto i = static_cast<std::size_t>(std::max<std::ptrdiff_t>(it - s0_.begin() - 1, 0));
    return std::min(i, seg_n_.size() - 1);
  }
  /// Nominal wall point at contour position s and height z [mm], and its air-side normal.
  Vec3 wall_point(double s, double z, Vec3& n) const {
    const std::size_t i = segment(s);
    const auto& pts = c_.plan.contour;
    const auto& p = pts[i];
    const auto& q = pts[(i + 1) % pts.size()];
    const double f = (s - s0_[i]) / std::max(s0_[i + 1] - s0_[i], 1e-12);
    n = seg_n_[i];
    const double draft = (c_.plan.contour_z_mm - z) * std::tan(c_.plan.wall_angle_deg / kDegPerRad);
    return {p.x_mm + f * (q.x_mm - p.x_mm) + n[0] * draft,
            p.y_mm + f * (q.y_mm - p.y_mm) + n[1] * draft, z};
  }

  void publish(Simulation& sim, double s, double z, bool cutting) {
    Vec3 n{};
    const Vec3 w = wall_point(s, z, n);
    const double r = c_.plan.tool_radius_mm;
    set_position(sim.mutable_axis(), {w[0] + r * n[0], w[1] + r * n[1], z}, axis_offsets_um(sim));
    AxisSample& a = sim.mutable_axis();
    a.program_path_mm = path_mm_;
    a.has_normal = true;
    a.normal = n;
    a.cutting = cutting;
  }

  double table_offset(const Simulation& sim, double s) const {
    if (!c_.table_registers) {
      return 0.0;
    }
    // The NC program switches to the nearest checkpoint's offset of this level.
    const NcConfig& nc = sim.config().nc;
    double best = 1e300;
    std::int32_t id = -1;
    for (const auto& cp : plan_.checkpoints) {
      if (cp.level == level_ && std::fabs(cp.s_mm - s) < best) {
        best = std::fabs(cp.s_mm - s);
        id = cp.id;
      }
    }
    if (id < 0 || id >= nc.checkpoint_register_count) {
      return 0.0;
    }
    return sim.reg(nc.checkpoint_base_register + id);
  }

  void cut(Simulation& sim, double d_mm) {
    const double d = std::min(d_mm, length_mm_ - s_mm_);
    s_mm_ += d;
    path_mm_ += d;
    cut_path_mm_ += d;
    const double z = plan_.levels_z_mm[static_cast<std::size_t>(level_)];
    publish(sim, s_mm_, z, true);
    const NcConfig& nc = sim.config().nc;
    MachineModel& m = sim.model();
    Vec3 n{};
    const Vec3 p = wall_point(s_mm_, z, n);
    const double w = m.wear_um(cut_path_mm_);
    const double e_machine = w + m.pushoff_um(p, w) + dot(m.machine_error_um(p, sim.time_s()), n);
    // Radius wear (live register, and the table register in table mode) moves the wall along
    // its normal (S1 convention: c > 0 leaves material); axis offsets shift the tool.
    const double comp =
        dot(axis_offsets_um(sim), n) + sim.reg(nc.tool_radius_register) + table_offset(sim, s_mm_);
    const double e = e_machine + comp;
    const auto cell = std::min(static_cast<std::size_t>(std::lround(s_mm_ / step_mm_)), cells_ - 1);
    wall_[static_cast<std::size_t>(level_)][cell] = e;
    sim.mutable_results().walls.push_back({part_, level_, z, s_mm_, e, 0.0 - comp});
    if (s_mm_ >= length_mm_ - 1e-12) {
      if (static_cast<std::size_t>(level_ + 1) < plan_.levels_z_mm.size()) {
        phase_ = Phase::kLink;
        link_left_mm_ = link_mm_;
      } else {
        phase_ = Phase::kProbe;
        probe_index_ = 0;
        probe_s_ = 0.0;
      }
    }
  }

  void probe(Simulation& sim, double h_s) {
    AxisSample& a = sim.mutable_axis();
    a.cutting = false;
    if (probe_index_ >= plan_.checkpoints.size()) {
      sim.emit(ProgramEvent{sim.now_ns(), ProgramEventKind::kPartEnd, part_});
      if (part_ < last_part_) {
        ++part_;
        path_mm_ = c_.plan.program_path_start_mm;
        phase_ = Phase::kStart;
      } else {
        phase_ = Phase::kDone;
      }
      return;
    }
    const auto& cp = plan_.checkpoints[probe_index_];
    set_position(a, {cp.start_x_mm, cp.start_y_mm, cp.z_mm}, axis_offsets_um(sim));
    a.has_normal = false;
    probe_s_ += h_s;
    if (probe_s_ < c_.probe_time_s) {
      return;
    }
    probe_s_ = 0.0;
    MachineModel& m = sim.model();
    const auto level = static_cast<std::size_t>(cp.level);
    const auto cell =
        std::min(static_cast<std::size_t>(std::lround(cp.s_mm / step_mm_)), cells_ - 1);
    const double e = wall_[level][cell];
    const double r = c_.plan.ball_radius_mm;
    const double delta0_um = (r / std::cos(cp.alpha_deg / kDegPerRad) - r) * 1000.0;
    double raw = e + delta0_um + m.probe_noise_um();
    const ProbeOutlierConfig& out = m.config().probe_outlier;
    if (out.enabled && out.part == part_ && out.checkpoint == cp.id) {
      raw += out.value_um;
    }
    core::ProbeMeasurement pm{};
    pm.time_ns = sim.now_ns();
    pm.part = part_;
    pm.checkpoint = cp.id;
    pm.raw_deviation_um = raw;
    pm.wall_angle_deg = cp.alpha_deg;
    pm.ball_radius_mm = r;
    pm.position_mm = {cp.x_mm, cp.y_mm, cp.z_mm};
    sim.emit(pm);
    sim.mutable_results().checkpoints.push_back({part_, cp.id, cp.level, cp.z_mm, cp.s_mm, e, raw});
    sim.mutable_results().measurements.push_back({sim.time_s(), MeasurementKind::kProbe, part_,
                                                  cp.id, cut_path_mm_, e + delta0_um, raw, false});
    ++probe_index_;
  }

  SideWallConfig c_;
  std::int32_t first_part_;
  std::int32_t last_part_;
  double step_mm_;
  core::checkpoint::Plan plan_;
  std::int32_t part_;
  double cut_path_mm_;
  std::vector<double> s0_;
  std::vector<Vec3> seg_n_;
  double length_mm_{0.0};
  double link_mm_{0.0};
  std::size_t cells_{0};
  std::vector<std::vector<double>> wall_;
  std::int32_t level_{0};
  double approach_left_s_{0.0};
  double s_mm_{0.0};
  double link_left_mm_{0.0};
  double path_mm_{0.0};
  Phase phase_{Phase::kStart};
  std::size_t probe_index_{0};
  double probe_s_{0.0};
};

}  // namespace

double mould_face_z_mm(const MouldFaceConfig& c, double x_mm, double y_mm) {
  const double u = 2.0 * x_mm / c.size_x_mm - 1.0;
  const double v = 2.0 * y_mm / c.size_y_mm - 1.0;
  return c.base_z_mm + c.bulge_x_mm * (1.0 - u * u) + c.bulge_y_mm * (1.0 - v * v);
}

Vec3 mould_face_normal(const MouldFaceConfig& c, double x_mm, double y_mm) {
  const double u = 2.0 * x_mm / c.size_x_mm - 1.0;
  const double v = 2.0 * y_mm / c.size_y_mm - 1.0;
  const double dzdx = -c.bulge_x_mm * 2.0 * u * 2.0 / c.size_x_mm;
  const double dzdy = -c.bulge_y_mm * 2.0 * v * 2.0 / c.size_y_mm;
  const double norm = std::sqrt(dzdx * dzdx + dzdy * dzdy + 1.0);
  return {-dzdx / norm, -dzdy / norm, 1.0 / norm};
}

std::unique_ptr<Program> make_touch_program(const SimConfig& c);
std::unique_ptr<Program> make_roll_program(const SimConfig& c);

Simulation::Simulation(const SimConfig& config, ProgramKind program,
                       const std::vector<std::uint16_t>& known_registers)
    : config_(config),
      model_(config.effects, config.seed),
      registers_(known_registers, config.nc.offset_limit_um, config.nc.latency_s) {
  for (std::size_t k = 0; k < config.initial_register_indices.size(); ++k) {
    const std::int32_t i = config.initial_register_indices[k];
    if (!registers_.preset(static_cast<std::uint16_t>(i), config.initial_registers_um[k])) {
      throw std::runtime_error("ncsim.initial_registers_um: register " + std::to_string(i) +
                               " is not an offset register of the bus map, or " +
                               std::to_string(config.initial_registers_um[k]) +
                               " um is beyond nc.offset_limit_um");
    }
  }
  switch (program) {
    case ProgramKind::kMouldFace:
      program_ = std::make_unique<MouldFace>(config_);
      break;
    case ProgramKind::kSideWall:
      program_ = std::make_unique<SideWall>(config_);
      break;
    case ProgramKind::kTouch:
      program_ = make_touch_program(config_);
      break;
    case ProgramKind::kRoll:
      program_ = make_roll_program(config_);
      break;
  }
  axis_.cutting = false;
  axis_.tool = config_.nc.tool;
}

Simulation::~Simulation() = default;

void Simulation::advance_to(core::TimeNs t_ns) {
  const double t_end = core::seconds(t_ns);
  const double h_max = program_->max_step_s();
  while (!done_ && t_s_ < t_end - 1e-12) {
    const double h = std::min(h_max, t_end - t_s_);
    t_s_ += h;
    registers_.advance(t_s_);
    if (!program_->step(*this, h)) {
      done_ = true;
    }
  }
  registers_.advance(t_s_);
  axis_.time_ns = core::from_seconds(t_s_);
}

std::array<double, 2> Simulation::temperatures_c() const { return model_.temperature_c(t_s_); }

std::vector<core::Event> Simulation::take_events() {
  std::vector<core::Event> out;
  out.swap(events_);
  return out;
}

WriteResult Simulation::write_offset(double t_s, std::uint16_t register_index, double value_um) {
  const WriteResult r = registers_.write(t_s, register_index, value_um);
  const auto& al = config_.nc.alarm_registers;
  if (r == WriteResult::kAccepted && std::find(al.begin(), al.end(), register_index) != al.end()) {
    auto it = std::find_if(alarm_values_.begin(), alarm_values_.end(),
                           [&](const auto& e) { return e.first == register_index; });
    if (it == alarm_values_.end()) {
      alarm_values_.emplace_back(register_index, 0.0);
      it = alarm_values_.end() - 1;
    }
    // The daemon re-sends a raised flag every refresh interval: one alarm per rising edge.
    if (!(std::fabs(it->second) > 0.0) && std::fabs(value_um) > 0.0) {
      results_.alarms.push_back({t_s, register_index, value_um});
    }
    it->second = value_um;
  }
  return r;
}

}  // namespace nccomp::sim::ncsim
