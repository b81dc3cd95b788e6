// Probe readings of the finished face as contour rows of the measurement log
// (docs/closing-the-loop.md, "A probe of the finished face"). A reading is the face's error as
// cut, after the compensation that was in force where that point was cut; the log's convention
// is the error before compensation (measured_um + applied_um). So, as the tool passes each
// configured probe point, the loop captures the compensation the wear registers then applied
// along the face normal and the tool's cut path; the probe's reading of that point later becomes
// a row carrying both. Fixed-size state: real-time safe on the loop thread.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>

#include "core/common/types.hpp"

namespace nccomp::daemon {

inline constexpr std::size_t kMaxFaceProbePoints = 32;
/// The longest segment between two cutting samples that the capture interpolates, in capture
/// radii (longer: a jump, e.g. from one pass's end to the next one's start; its ends count).
inline constexpr double kMaxSegmentRadii = 10.0;

struct FaceProbeConfig {
  /// The probe points (x, y) [mm]; the probe's checkpoint number k reads point k. 0 = off.
  std::size_t count{0};
  std::array<std::array<double, 2>, kMaxFaceProbePoints> point_mm{};
  /// Point k is cut where the contact point's (x, y) path comes within this distance of it (the
  /// nearest place counts). The path between two consecutive cutting samples of one tool (also
  /// across samples that are not cutting: the tool lifted and came back) is a straight segment,
  /// searched too, when it is at most kMaxSegmentRadii times this long: at a high feed or a
  /// coarse sampling the samples are farther apart than the radius.
  double capture_radius_mm{1.0};
  /// The ball-end mill's radius [mm]: the NC reports the ball's centre, which on a sloped face
  /// lies r·n off the point it cuts (contact = centre − r·n).
  double ball_radius_mm{0.0};
  /// The tool's length and radius wear registers (engine indices).
  std::size_t length_register{0};
  std::size_t radius_register{0};
};

/// Why a probe reading gave no row.
enum class FaceProbeReject : std::uint8_t {
  kNone = 0,
  kUnknownPoint = 1,   // its number is no configured point
  kFault = 2,          // the bus marked it faulty, or its value is not finite
  kOtherPosition = 3,  // it was taken farther than capture_radius_mm from the point
  kNotCut = 4,         // the point was not cut in this part (within capture_radius_mm)
};

/// "its number is no configured point", ...: for the daemon's log.
const char* to_string(FaceProbeReject r) noexcept;

class FaceProbeCapture {
 public:
  FaceProbeCapture() = default;
  explicit FaceProbeCapture(const FaceProbeConfig& config) : config_(config) {}

  [[nodiscard]] bool enabled() const noexcept { return config_.count > 0; }
  [[nodiscard]] const FaceProbeConfig& config() const noexcept { return config_; }

  /// Real-time safe. A new part: the points are cut again.
  void on_part_start() noexcept;
  /// Real-time safe. A sample of the cut, with the wear registers' values as the NC has them [µm]
  /// and the tool's cut path [mm]. A sample without a normal uses the last one seen (the tool
  /// axis before any). Where the point's nearest place lies between this sample and the one
  /// before, the compensation and the cut path there are interpolated linearly.
  void on_axis(const core::AxisSample& a, double length_um, double radius_um,
               double cut_path_mm) noexcept;
  /// Real-time safe. Fills the row of a probe reading; false (and counted, with its reason in
  /// last_reject()) for a reading of no configured point, one whose position is not that
  /// point's, a fault, or a point not cut yet.
  bool on_probe(const core::ProbeMeasurement& m, core::MeasurementRecord& row) noexcept;
  [[nodiscard]] FaceProbeReject last_reject() const noexcept { return last_reject_; }

  [[nodiscard]] std::uint64_t rejected() const noexcept { return rejected_; }

 private:
  struct Cut {
    bool valid{false};
    double distance_mm{0.0};
    std::int32_t tool{0};
    double applied_um{0.0};
    double path_mm{0.0};
  };
  /// The last cutting sample: its contact point, compensation along its normal, cut path.
  struct Last {
    bool valid{false};
    std::int32_t tool{0};
    double x_mm{0.0};
    double y_mm{0.0};
    double applied_um{0.0};
    double path_mm{0.0};
  };
  FaceProbeConfig config_;
  std::array<Cut, kMaxFaceProbePoints> cuts_{};
  Last last_{};
  std::array<double, 3> normal_{0.0, 0.0, 1.0};
  std::uint64_t rejected_{0};
  FaceProbeReject last_reject_{FaceProbeReject::kNone};
};

}  // namespace nccomp::daemon
