// Probe geometry correction of S1 (seeds.md, S1 method A step 2):
//   δ' = δ − δ0,  δ0 = r / cos α − r
// δ is the deviation the probe displays, r the probe ball radius and α the wall's normal
// inclination angle. A ball touching an inclined wall while moving horizontally touches it off
// its equator: the trigger comes r/cos α − r early, which is not a part error.
#pragma once

#include <cstdint>

namespace nccomp::core::checkpoint {

/// Largest wall angle accepted [deg]: at 89° cos α = 0.017 and δ0 = 56·r, i.e. the horizontal
/// probing of such a wall is meaningless (the probe slides along it).
inline constexpr double kMaxWallAngleDeg = 89.0;

enum class ProbeStatus : std::uint8_t {
  kOk = 0,
  kNonFinite = 1,       // δ, α or r is NaN or ±inf
  kNegativeRadius = 2,  // r < 0
  kAngleTooSteep = 3,   // |α| ≥ 89°
};

/// A short operator-readable reason for a status.
const char* probe_status_text(ProbeStatus status) noexcept;

struct ProbeCorrection {
  /// δ' [µm]; 0 unless status == kOk.
  double corrected_um{0.0};
  /// δ0 = r/cos α − r [µm].
  double delta0_um{0.0};
  ProbeStatus status{ProbeStatus::kOk};
};

/// δ0 = r/cos α − r [µm] for a ball radius r [mm] and a wall angle α [deg]; the caller has
/// validated the inputs. Real-time safe.
double probe_delta0_um(double ball_radius_mm, double wall_angle_deg) noexcept;

/// Validates and corrects one probe reading. Real-time safe: no allocation, no throw.
ProbeCorrection correct_probe(double raw_deviation_um, double wall_angle_deg,
                              double ball_radius_mm) noexcept;

/// The same, for operator tools: throws std::invalid_argument naming the offending input.
double corrected_deviation_um(double raw_deviation_um, double wall_angle_deg,
                              double ball_radius_mm);

}  // namespace nccomp::core::checkpoint
