// The machine model of ncsim (issue 10 item 3): what the machine does to the part that the
// program does not say. Pure and deterministic: no I/O, no clock; time, path and positions come in
// as arguments, random numbers from a seeded Rng. Every effect has an `enabled` switch; a
// disabled effect contributes exactly zero.
//
// Sign convention (the one the machined-result files use): an error is measured along the
// surface's outward normal n, positive = material left (oversize). A displacement d of the tool
// relative to the part [µm, machine axes] leaves d·n of material.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "sim/ncsim/random.hpp"

namespace nccomp::sim::ncsim {

using Vec3 = std::array<double, 3>;

inline double dot(const Vec3& a, const Vec3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

/// A sampled curve y(x), x strictly increasing; linear in between, held at the ends.
struct Curve {
  std::vector<double> x;
  std::vector<double> y;
  [[nodiscard]] double at(double xq) const;
  [[nodiscard]] bool empty() const { return x.empty(); }
};

enum class WearCurve : std::uint8_t { kLinear, kPower, kTable };

/// [effects.wear]: radial wear of the cutting edge [µm] as a function of cut path.
struct WearConfig {
  bool enabled{true};
  WearCurve curve{WearCurve::kLinear};
  /// kLinear: wear = initial_um + rate_um_per_m · path_m.
  double initial_um{0.0};
  double rate_um_per_m{2.0};
  /// kPower: wear = initial_um + coefficient_um · path_m^exponent.
  double coefficient_um{2.0};
  double exponent{0.7};
  /// kTable (e.g. the PHM 2010 curves): wear [µm] over path [mm], already converted from the
  /// source (flank wear VB → radial wear, cut number → path) by the config loader.
  Curve table{};
  /// Where the table came from (for result.json).
  std::string table_source{};
};

/// [effects.pushoff]: the tool is pushed off the surface by the cutting force, more so with
/// wear (a blunt edge cuts with more force), harder material and a longer lever above the clamp.
struct PushoffConfig {
  bool enabled{true};
  /// Push-off of a sharp tool in material of nominal hardness at the reference lever [µm].
  double base_um{4.0};
  /// Force growth per µm of wear [1/µm]: force ∝ 1 + wear_gain_per_um · wear_um.
  double wear_gain_per_um{0.02};
  /// Height of the clamping plane [mm]; lever = z − clamp_z_mm (≥ 0).
  double clamp_z_mm{-60.0};
  /// Lever at which base_um applies [mm].
  double reference_lever_mm{60.0};
};

/// [effects.hardness]: a smooth seeded field of relative hardness over the part (3–5 HRC scatter
/// on a large blank is about ±10 % of the cutting force).
struct HardnessConfig {
  bool enabled{true};
  /// Peak relative change of the cutting force (0.1 = ±10 %).
  double amplitude{0.1};
  /// Typical wavelength of the field [mm].
  double wavelength_mm{60.0};
  /// Every blank has its own field (S1 mode B's case); false: the same field for every part.
  bool per_part{false};
};

enum class ThermalMode : std::uint8_t { kFirstOrder, kReplay };

/// [effects.thermal]: thermal drift of the tool relative to the part [µm per axis].
struct ThermalConfig {
  bool enabled{true};
  ThermalMode mode{ThermalMode::kFirstOrder};
  /// kFirstOrder: drift = gain_um · (1 − exp(−t / time_constant_s)) from the program start.
  Vec3 gain_um{0.0, 0.0, -12.0};
  double time_constant_s{600.0};
  /// Temperature published for sensor 0 (spindle) = ambient + rise · (same lag) [°C].
  double ambient_c{22.0};
  double temperature_rise_c{8.0};
  /// kReplay: drift per axis [µm] and temperatures [°C] over data time [s]; data time =
  /// replay_start_s + time_scale · sim time.
  std::array<Curve, 3> replay_um{};
  std::array<Curve, 2> replay_temperature_c{};
  double time_scale{1.0};
  double replay_start_s{0.0};
  std::string replay_source{};
};

/// [effects.pitch]: ball-screw pitch error per axis: amplitude · sin(2π pos / pitch) + slope.
struct PitchConfig {
  bool enabled{true};
  Vec3 amplitude_um{1.5, 1.5, 1.0};
  double pitch_mm{10.0};
  Vec3 slope_um_per_m{3.0, -2.0, 0.0};
};

/// [effects.probe_noise] / [effects.laser_noise]: Gaussian noise of a measuring device.
struct NoiseConfig {
  bool enabled{true};
  double sigma_um{0.5};
};

/// [effects.broken_tool]: the tool breaks at a cut path; the laser then reports it.
struct BrokenToolConfig {
  bool enabled{false};
  double at_path_mm{1000.0};
  /// Extra radial loss of the broken edge [µm].
  double wear_jump_um{300.0};
  /// The laser flags the tool as broken (else it only sees the jump).
  bool report_flag{true};
};

/// [effects.probe_outlier]: one implausible probe reading (a chip under the ball).
struct ProbeOutlierConfig {
  bool enabled{false};
  std::int32_t part{1};
  std::int32_t checkpoint{0};
  /// Added to the probe's displayed deviation [µm].
  double value_um{500.0};
};

struct EffectsConfig {
  WearConfig wear;
  PushoffConfig pushoff;
  HardnessConfig hardness;
  ThermalConfig thermal;
  PitchConfig pitch;
  NoiseConfig probe_noise{true, 0.5};
  NoiseConfig laser_noise{true, 0.8};
  BrokenToolConfig broken_tool;
  ProbeOutlierConfig probe_outlier;
};

/// The machine. Not thread-safe; one program drives it.
class MachineModel {
 public:
  MachineModel(EffectsConfig config, std::uint64_t seed);

  [[nodiscard]] const EffectsConfig& config() const noexcept { return config_; }

  /// Radial wear of the edge [µm] after cut_path_mm of cutting (broken tool included).
  [[nodiscard]] double wear_um(double cut_path_mm) const;
  [[nodiscard]] bool broken(double cut_path_mm) const;
  /// The program starts part `part` (1, 2, ...): with hardness.per_part, a new blank's field.
  void set_part(std::int32_t part);
  /// Relative hardness at a point of the part (1 = nominal).
  [[nodiscard]] double hardness(const Vec3& p_mm) const;
  /// Push-off along the normal [µm] (material left) at point p with the given wear.
  [[nodiscard]] double pushoff_um(const Vec3& p_mm, double wear_um) const;
  /// Thermal displacement of the tool relative to the part at sim time t [µm per axis].
  [[nodiscard]] Vec3 thermal_um(double t_s) const;
  /// Temperature of sensor 0 (spindle) and 1 (bed / ambient) [°C] at sim time t.
  [[nodiscard]] std::array<double, 2> temperature_c(double t_s) const;
  /// Ball-screw pitch error at an axis position [µm per axis].
  [[nodiscard]] Vec3 pitch_um(const Vec3& p_mm) const;
  /// Tool displacement relative to the part from the machine (thermal + pitch) [µm].
  [[nodiscard]] Vec3 machine_error_um(const Vec3& p_mm, double t_s) const;

  /// Laser reading of the wear [µm] (noise drawn from the model's stream).
  double laser_reading_um(double cut_path_mm);
  /// Probe noise [µm] for one reading.
  double probe_noise_um();

 private:
  EffectsConfig config_;
  // Separate streams: switching one device's noise does not change the other's draws.
  Rng laser_rng_;
  Rng probe_rng_;
  // Hardness field: a sum of plane waves with seeded directions and phases.
  static constexpr std::size_t kWaves = 6;
  std::array<Vec3, kWaves> wave_k_{};
  std::array<double, kWaves> wave_phase_{};
  double wave_norm_{1.0};
  std::uint64_t seed_{0};
  void make_field(std::uint64_t field_seed);
};

}  // namespace nccomp::sim::ncsim
