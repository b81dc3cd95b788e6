// Configuration of calibration and thermal recalibration (S3). CalibrationConfig maps 1:1 onto
// the `[calibration]` TOML table documented in docs/calibration.md: one field per key, same
// name, units in the names. validate() is the single place where a config is judged; it names
// each offending key by its TOML path ("calibration.blank_radius_mm") in a core::ConfigIssue.
#pragma once

#include <array>
#include <cstdint>
#include <limits>
#include <string>

#include "core/common/profile.hpp"

namespace nccomp::core::calib {

/// How a test grind's two facet chords are turned into a correction of Δx.
enum class FacetRule : std::uint8_t {
  kExact = 0,  // depth from chord on a cylinder: d = ρ − sqrt(ρ² − c²/4), e = (d₊ − d₋)/2
  kProportional = 1,  // the seed's controller: e = gain · (c₊ − c₋)
};

/// How the drift is predicted between recalibrations.
enum class Prediction : std::uint8_t {
  kNone = 0,         // hold the last measured drift (the seed: corrections lag the drift)
  kTime = 1,         // first-order thermal model in time (time constant configured)
  kTemperature = 2,  // drift linear in the mapped temperature, slope learned from the touches
  /// Kalman estimate of the drift: the mean drift of earlier shifts (by time since the nominals)
  /// scaled by a gain, plus a random-walk level and a temperature slope (drift_estimator.hpp).
  kEstimator = 3,
};

/// In which coordinates the NC reports a touch's trigger position.
enum class TouchPositions : std::uint8_t {
  /// Machine coordinates: where the axis is at the trigger. The axis offsets nccomp writes do not
  /// change where the probe meets the body, so they do not enter the reading (drift = touch −
  /// nominal directly). Sinumerik $AA_MM, a PLC reading the position encoder.
  kMachine = 0,
  /// Program (work) coordinates: machine position − axis offset in force (the NC adds the offset
  /// to the commanded position, machine = program + offset). The calibrator adds the offset it
  /// last wrote back before comparing with the nominal; without that the corrections would
  /// alternate between the drift and zero. ncsim's touch program reports these by default.
  kProgram = 1,
};

/// Values of the request register (CalibrationConfig::request_register): what the calibrator
/// waits for, so that the NC or PLC can start the matching cycle. Stable numbers.
enum class RequestCode : std::uint8_t {
  kNone = 0,              // nothing to do
  kReferenceTouches = 1,  // touch the reference disk with the reference probe
  kTestGrindLateral = 2,  // grind the blank from ±X (X register = the Δx to grind with)
  kTestGrindEndFace = 3,  // grind the end face from ±X (X register = the Δx to grind with)
  kNominalTouches = 4,    // machine probe on the test body: the nominals
  kRecalibration = 5,     // machine probe on the test body: a recalibration (due or on demand)
};

struct CalibrationConfig {
  // --- NC registers (logical indices of the config's register map) -------------------------
  /// Axis offset registers that take the X / Y / Z correction [µm].
  std::uint16_t register_x{0};
  std::uint16_t register_y{1};
  std::uint16_t register_z{2};

  // --- reference-probe touches of the reference disk (initial calibration) ------------------
  /// Axis positions [mm] at which, on an error-free machine, the centres of reference disk and
  /// probe ball coincide: X with the stylus across X (lateral) and along X (axial), Y, Z.
  double reference_x_lateral_mm{0.0};
  double reference_x_axial_mm{0.0};
  double reference_y_mm{0.0};
  double reference_z_mm{0.0};
  /// Nominal centre distance at the trigger [mm] for lateral touches (disk half-thickness +
  /// ball radius) and for the axial touch (disk half-thickness + ball radius along the stylus).
  /// A touch approaching in direction s triggers nominally at centre − s · contact.
  double reference_contact_mm{0.0};
  double reference_axial_contact_mm{0.0};
  /// Touches per axis (and variant) in one set; their scatter is checked.
  std::int32_t touches_per_axis{1};
  /// Coordinates of the reported trigger positions (see TouchPositions).
  TouchPositions touch_positions{TouchPositions::kMachine};
  /// Largest spread (max − min) of the repeated touches of one axis [µm].
  double max_scatter_um{5.0};
  /// A set not completed within this time is discarded [s].
  double touch_set_timeout_s{900.0};

  // --- test grinding ----------------------------------------------------------------------
  /// "exact" or "proportional".
  FacetRule facet_rule{FacetRule::kExact};
  /// Radius ρ of the cylindrical test blank [mm].
  double blank_radius_mm{5.0};
  /// Gain of the proportional rule [µm of Δx per µm of chord difference].
  double facet_gain_um_per_um{0.05};
  /// Facets agree when their chord lengths differ by at most this [µm].
  double facet_tolerance_um{2.0};
  /// Test grinds per face before the calibration is abandoned.
  std::int32_t max_test_grinds{6};
  /// Also grind the end face from ±X (ΔxA); false: ΔxA is taken from the axial touch.
  bool end_face_test_grind{true};

  // --- recalibration ------------------------------------------------------------------------
  /// Largest change of a correction a recalibration may make [µm] (Heidenhain MP6600: 50 µm).
  double plausibility_um{50.0};
  /// "Recalibration due" is raised this long after the last touch set [s]; 0 = no schedule.
  double recalibration_interval_s{3600.0};
  /// How a new drift correction is fed in, and over how long [s].
  ProfileShape creep_shape{ProfileShape::kCosine};
  double creep_duration_s{600.0};
  /// Drift prediction between recalibrations.
  Prediction prediction{Prediction::kTime};
  /// Time constant of the first-order thermal model [s].
  double thermal_time_constant_s{3600.0};
  /// Sensor index of the TemperatureSample events that drive the temperature model; −1 = none.
  std::int32_t temperature_sensor{-1};
  /// Weight kept per touch by the temperature fit (exponential forgetting), in (0, 1].
  double temperature_forgetting{0.8};
  /// Slopes learned beyond ± this are clamped [µm/°C].
  double max_temperature_slope_um_per_c{20.0};

  // --- prediction = "estimator" (docs/calibration.md, "Drift estimator") --------------------
  /// Standard deviation of one touch set's drift reading (touch and nominal noise) [µm].
  double estimator_touch_noise_um{0.7};
  /// Standard deviation of the level's random walk over one hour [µm]; it grows with √hours.
  double estimator_level_noise_um_per_h{6.0};
  /// true: per slot, the level noise is the RMS of the earlier shifts' hourly drift increments
  /// (learned_level_noise_um_per_h), within the bounds below; the configured value until an
  /// earlier shift has an hour of drift.
  bool estimator_learn_level_noise{false};
  double estimator_min_level_noise_um_per_h{3.0};
  double estimator_max_level_noise_um_per_h{20.0};
  /// false: the earlier shifts' mean drift is not a regressor (its gain stays 0), e.g. when
  /// each slot's input is a drift model that already predicts the shift's shape
  /// (estimator_input_sensors); the earlier shifts still give the learned level noise.
  bool estimator_shift_prior{true};
  /// Prior standard deviation of the gain on the earlier shifts' mean drift (prior gain 1).
  double estimator_prior_gain_sigma{0.5};
  /// Weight kept per shift by the earlier shifts' mean drift, in (0, 1].
  double estimator_prior_forgetting{0.8};
  /// Prior standard deviation of the temperature slope [µm/°C]; 0 = temperature not used.
  double estimator_slope_sigma_um_per_c{0.0};
  /// Per slot (X lateral, X axial, Y, Z): the temperature slope of a model fitted on earlier
  /// shifts (nccomp analyze's thermal_drift coefficient) [µm/°C] and its standard deviation
  /// (the 95 % interval's half-width / 1.96). Where set, every new shift's estimate starts
  /// there instead of at the slope the shift before learned, with this σ instead of
  /// estimator_slope_sigma_um_per_c (σ 0: the slope stays the model's). NaN = not set.
  std::array<double, 4> estimator_model_slope_um_per_c{
      std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::quiet_NaN(),
      std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::quiet_NaN()};
  std::array<double, 4> estimator_model_slope_sigma_um_per_c{
      std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::quiet_NaN(),
      std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::quiet_NaN()};
  /// Per slot (X lateral, X axial, Y, Z): the sensor whose samples are that slot's estimator
  /// input instead of temperature_sensor's, e.g. a drift model's prediction that nccompd computes
  /// from many sensors ([[input_sums]]); −1 = temperature_sensor. The slope's unit is then µm
  /// per unit of that sensor (1 for a model that predicts the drift in µm).
  std::array<std::int32_t, 4> estimator_input_sensors{-1, -1, -1, -1};
  /// A touch set beyond this many σ of the estimate's prediction changes nothing (alarm
  /// 'implausible'); 0 = no gate.
  double estimator_gate_sigmas{5.0};

  /// Logical register (kind flag) that gets the RequestCode the calibrator waits for; the NC or
  /// PLC polls it to start its touch cycle or test grind. −1 = none.
  std::int32_t request_register{-1};

  // --- output -------------------------------------------------------------------------------
  /// A correction is re-sent at most this often [s] and only when it moved by the dead band.
  double write_period_s{1.0};
  double write_deadband_um{0.1};
  /// Limiter of the three axis registers (every write passes it).
  double max_abs_um{200.0};
  double max_step_um{5.0};
  double max_rate_um_per_s{50.0};

  // --- daemon only ----------------------------------------------------------------------------
  /// A state file of `nccomp calibrate --state` that nccompd adopts at start-up when it is newer
  /// than the calibration the daemon holds (relative to the config file). Empty = none.
  std::string state_file{};
};

/// The sensor that is slot `slot`'s estimator input: estimator_input_sensors[slot], or
/// temperature_sensor where that is −1 (−1: none). Real-time safe.
std::int32_t estimator_input_sensor(const CalibrationConfig& config, std::size_t slot) noexcept;

/// Throws core::ConfigInvalid (a std::invalid_argument) with every offending key
/// ("calibration.<key>") and why, with its value.
void validate(const CalibrationConfig& config);

/// Name ↔ enum for the TOML strings (nullptr / false for an unknown name).
const char* to_string(FacetRule rule) noexcept;
const char* to_string(Prediction prediction) noexcept;
const char* to_string(ProfileShape shape) noexcept;
bool parse_facet_rule(const std::string& s, FacetRule& out) noexcept;
bool parse_prediction(const std::string& s, Prediction& out) noexcept;
const char* to_string(TouchPositions positions) noexcept;
bool parse_touch_positions(const std::string& s, TouchPositions& out) noexcept;
const char* to_string(RequestCode code) noexcept;
/// The analytic shapes only: linear, cosine, smoothstep, step.
bool parse_creep_shape(const std::string& s, ProfileShape& out) noexcept;

}  // namespace nccomp::core::calib
