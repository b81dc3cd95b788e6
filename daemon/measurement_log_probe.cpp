#include "daemon/measurement_log_probe.hpp"

#include <algorithm>
#include <cmath>

namespace nccomp::daemon {

void FaceProbeCapture::on_part_start() noexcept {
  for (Cut& c : cuts_) c.valid = false;
}

void FaceProbeCapture::on_axis(const core::AxisSample& a, double length_um, double radius_um,
                               double cut_path_mm) noexcept {
  if (a.has_normal) normal_ = a.normal;
  if (!a.cutting || a.axis_count < 3) return;
  const double r = config_.ball_radius_mm;
  const double cx = a.position_mm[0] - r * normal_[0];
  const double cy = a.position_mm[1] - r * normal_[1];
  for (std::size_t k = 0; k < config_.count; ++k) {
    const double d = std::hypot(cx - config_.point_mm[k][0], cy - config_.point_mm[k][1]);
    Cut& c = cuts_[k];
    // Written so that a NaN position captures nothing.
    if (!(d <= config_.capture_radius_mm) || (c.valid && !(d < c.distance_mm))) continue;
    // The length wear moves the tool along its axis (Z), the radius wear across it: along the
    // face normal they compensate L·n_z + R·sin θ, which the log's applied_um takes back out.
    const double nz = normal_[2];
    const double sin_theta = std::sqrt(std::max(0.0, 1.0 - nz * nz));
    c.valid = true;
    c.distance_mm = d;
    c.tool = a.tool;
    c.applied_um = 0.0 - (length_um * nz + radius_um * sin_theta);
    c.path_mm = cut_path_mm;
  }
}

bool FaceProbeCapture::on_probe(const core::ProbeMeasurement& m,
                                core::MeasurementRecord& row) noexcept {
  if (!enabled()) return false;
  const bool known = m.checkpoint >= 0 && static_cast<std::size_t>(m.checkpoint) < config_.count;
  const auto k = known ? static_cast<std::size_t>(m.checkpoint) : 0U;
  if (!known || m.fault != core::InputFault::kNone || !std::isfinite(m.raw_deviation_um) ||
      !cuts_[k].valid ||
      !(std::hypot(m.position_mm[0] - config_.point_mm[k][0],
                   m.position_mm[1] - config_.point_mm[k][1]) <= config_.capture_radius_mm)) {
    ++rejected_;
    return false;
  }
  const Cut& c = cuts_[k];
  row = core::MeasurementRecord{};
  row.time_ns = m.time_ns;
  row.part = m.part;
  row.tool = c.tool;
  row.kind = core::MeasurementKind::kContour;
  row.point = m.checkpoint;
  row.position_mm = m.position_mm;
  row.path_mm = c.path_mm;
  // The probe touches the face along its normal: its reading is the deviation itself.
  row.measured_um = m.raw_deviation_um;
  row.applied_um = c.applied_um;
  return true;
}

}  // namespace nccomp::daemon
