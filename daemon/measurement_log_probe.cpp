#include "daemon/measurement_log_probe.hpp"

#include <algorithm>
#include <cmath>

namespace nccomp::daemon {

const char* to_string(FaceProbeReject r) noexcept {
  switch (r) {
    case FaceProbeReject::kNone:
      return "none";
    case FaceProbeReject::kUnknownPoint:
      return "its number is no configured point";
    case FaceProbeReject::kFault:
      return "the reading is faulty or not a number";
    case FaceProbeReject::kOtherPosition:
      return "it was taken farther than capture_radius_mm from the point";
    case FaceProbeReject::kNotCut:
      return "the point was not cut in this part within capture_radius_mm";
  }
  return "unknown";
}

void FaceProbeCapture::on_part_start() noexcept {
  for (Cut& c : cuts_) c.valid = false;
  last_.valid = false;
}

void FaceProbeCapture::on_axis(const core::AxisSample& a, double length_um, double radius_um,
                               double cut_path_mm) noexcept {
  if (a.has_normal) normal_ = a.normal;
  // Samples that are not cutting (the tool lifted to the laser, a link between passes) leave
  // the last cutting sample as it is: where the tool comes back to cut near where it left, the
  // places between were cut, just before it left or just after it came back.
  if (!a.cutting || a.axis_count < 3) return;
  const double r = config_.ball_radius_mm;
  const double cx = a.position_mm[0] - r * normal_[0];
  const double cy = a.position_mm[1] - r * normal_[1];
  // The length wear moves the tool along its axis (Z), the radius wear across it: along the
  // face normal they compensate L·n_z + R·sin θ, which the log's applied_um takes back out.
  const double nz = normal_[2];
  const double sin_theta = std::sqrt(std::max(0.0, 1.0 - nz * nz));
  const double applied = 0.0 - (length_um * nz + radius_um * sin_theta);
  // The segment from the last cutting sample of this tool, when it is one (not a jump).
  const double sx = cx - last_.x_mm;
  const double sy = cy - last_.y_mm;
  const double seg2 = sx * sx + sy * sy;
  const double max_seg = kMaxSegmentRadii * config_.capture_radius_mm;
  const bool segment = last_.valid && last_.tool == a.tool && seg2 > 0.0 &&
                       seg2 <= max_seg * max_seg;
  for (std::size_t k = 0; k < config_.count; ++k) {
    const double px = config_.point_mm[k][0];
    const double py = config_.point_mm[k][1];
    // Without a segment this sample's contact point; with one the nearest place on it, at t
    // (0 = the last sample, 1 = this one), where compensation and cut path are interpolated.
    double d = std::hypot(cx - px, cy - py);
    double t = 1.0;
    if (segment) {
      t = std::clamp(((px - last_.x_mm) * sx + (py - last_.y_mm) * sy) / seg2, 0.0, 1.0);
      d = std::hypot(last_.x_mm + t * sx - px, last_.y_mm + t * sy - py);
    }
    Cut& c = cuts_[k];
    // Written so that a NaN position captures nothing.
    if (!(d <= config_.capture_radius_mm) || (c.valid && !(d < c.distance_mm))) continue;
    c.valid = true;
    c.distance_mm = d;
    c.tool = a.tool;
    c.applied_um = segment ? last_.applied_um + t * (applied - last_.applied_um) : applied;
    c.path_mm = segment ? last_.path_mm + t * (cut_path_mm - last_.path_mm) : cut_path_mm;
  }
  last_ = Last{true, a.tool, cx, cy, applied, cut_path_mm};
}

bool FaceProbeCapture::on_probe(const core::ProbeMeasurement& m,
                                core::MeasurementRecord& row) noexcept {
  if (!enabled()) return false;
  const bool known = m.checkpoint >= 0 && static_cast<std::size_t>(m.checkpoint) < config_.count;
  const auto k = known ? static_cast<std::size_t>(m.checkpoint) : 0U;
  last_reject_ = FaceProbeReject::kNone;
  if (!known) {
    last_reject_ = FaceProbeReject::kUnknownPoint;
  } else if (m.fault != core::InputFault::kNone || !std::isfinite(m.raw_deviation_um)) {
    last_reject_ = FaceProbeReject::kFault;
  } else if (!(std::hypot(m.position_mm[0] - config_.point_mm[k][0],
                          m.position_mm[1] - config_.point_mm[k][1]) <=
               config_.capture_radius_mm)) {
    last_reject_ = FaceProbeReject::kOtherPosition;
  } else if (!cuts_[k].valid) {
    last_reject_ = FaceProbeReject::kNotCut;
  }
  if (last_reject_ != FaceProbeReject::kNone) {
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
