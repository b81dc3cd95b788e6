#include "sim/ncsim/model.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace nccomp::sim::ncsim {

double Curve::at(double xq) const {
  if (x.empty()) {
    return 0.0;
  }
  if (xq <= x.front()) {
    return y.front();
  }
  if (xq >= x.back()) {
    return y.back();
  }
  const auto it = std::upper_bound(x.begin(), x.end(), xq);
  const auto i = static_cast<std::size_t>(it - x.begin());
  const double f = (xq - x[i - 1]) / (x[i] - x[i - 1]);
  return y[i - 1] + f * (y[i] - y[i - 1]);
}

MachineModel::MachineModel(EffectsConfig config, std::uint64_t seed)
    : config_(std::move(config)), laser_rng_(seed), probe_rng_(seed ^ 0x5DEECE66DULL), seed_(seed) {
  make_field(seed);
}

void MachineModel::set_part(std::int32_t part) {
  if (config_.hardness.per_part) {
    const auto blank = static_cast<std::uint64_t>(static_cast<std::uint32_t>(part));
    make_field(seed_ + std::uint64_t{0x9E3779B97F4A7C15} * blank);
  }
}

void MachineModel::make_field(std::uint64_t field_seed) {
  // The field uses its own stream so that switching the noise effects does not move it.
  Rng field(field_seed ^ 0xA5A5A5A55A5A5A5AULL);
  const double k = 2.0 * std::numbers::pi / std::max(config_.hardness.wavelength_mm, 1e-6);
  for (std::size_t i = 0; i < kWaves; ++i) {
    // Directions mostly in XY (a blank's hardness varies across it), some along Z.
    const double az = 2.0 * std::numbers::pi * field.uniform();
    const double el = (field.uniform() - 0.5) * std::numbers::pi / 3.0;
    const double scale = 0.6 + 0.8 * field.uniform();  // wavelengths 0.6..1.4 × nominal
    wave_k_[i] = {k * scale * std::cos(el) * std::cos(az), k * scale * std::cos(el) * std::sin(az),
                  k * scale * std::sin(el)};
    wave_phase_[i] = 2.0 * std::numbers::pi * field.uniform();
  }
  // A sum of kWaves unit cosines has RMS sqrt(kWaves / 2): normalise so the field's RMS is
  // amplitude / sqrt(2) like a single sine of that amplitude.
  wave_norm_ = 1.0 / std::sqrt(static_cast<double>(kWaves));
}

double MachineModel::wear_um(double cut_path_mm) const {
  double w = 0.0;
  const WearConfig& c = config_.wear;
  if (c.enabled) {
    const double path_m = std::max(cut_path_mm, 0.0) / 1000.0;
    switch (c.curve) {
      case WearCurve::kLinear:
        w = c.initial_um + c.rate_um_per_m * path_m;
        break;
      case WearCurve::kPower:
        w = c.initial_um + c.coefficient_um * std::pow(path_m, c.exponent);
        break;
      case WearCurve::kTable:
        w = c.initial_um + c.table.at(cut_path_mm);
        break;
    }
  }
  if (broken(cut_path_mm)) {
    w += config_.broken_tool.wear_jump_um;
  }
  return w;
}

bool MachineModel::broken(double cut_path_mm) const {
  return config_.broken_tool.enabled && cut_path_mm >= config_.broken_tool.at_path_mm;
}

double MachineModel::hardness(const Vec3& p_mm) const {
  if (!config_.hardness.enabled) {
    return 1.0;
  }
  double s = 0.0;
  for (std::size_t i = 0; i < kWaves; ++i) {
    s += std::cos(dot(wave_k_[i], p_mm) + wave_phase_[i]);
  }
  return 1.0 + config_.hardness.amplitude * s * wave_norm_;
}

double MachineModel::pushoff_um(const Vec3& p_mm, double wear) const {
  const PushoffConfig& c = config_.pushoff;
  if (!c.enabled) {
    return 0.0;
  }
  const double lever = std::max(p_mm[2] - c.clamp_z_mm, 0.0) / c.reference_lever_mm;
  const double force = (1.0 + c.wear_gain_per_um * std::max(wear, 0.0)) * hardness(p_mm);
  return c.base_um * force * lever;
}

Vec3 MachineModel::thermal_um(double t_s) const {
  const ThermalConfig& c = config_.thermal;
  if (!c.enabled) {
    return {0.0, 0.0, 0.0};
  }
  if (c.mode == ThermalMode::kReplay) {
    const double td = c.replay_start_s + c.time_scale * t_s;
    // Zeroed at the replay start: the machine was referenced there.
    return {c.replay_um[0].at(td) - c.replay_um[0].at(c.replay_start_s),
            c.replay_um[1].at(td) - c.replay_um[1].at(c.replay_start_s),
            c.replay_um[2].at(td) - c.replay_um[2].at(c.replay_start_s)};
  }
  const double f = 1.0 - std::exp(-std::max(t_s, 0.0) / c.time_constant_s);
  return {c.gain_um[0] * f, c.gain_um[1] * f, c.gain_um[2] * f};
}

std::array<double, 2> MachineModel::temperature_c(double t_s) const {
  const ThermalConfig& c = config_.thermal;
  if (c.mode == ThermalMode::kReplay && c.enabled) {
    const double td = c.replay_start_s + c.time_scale * t_s;
    return {c.replay_temperature_c[0].at(td), c.replay_temperature_c[1].at(td)};
  }
  const double f = c.enabled ? 1.0 - std::exp(-std::max(t_s, 0.0) / c.time_constant_s) : 0.0;
  return {c.ambient_c + c.temperature_rise_c * f, c.ambient_c};
}

Vec3 MachineModel::pitch_um(const Vec3& p_mm) const {
  const PitchConfig& c = config_.pitch;
  if (!c.enabled) {
    return {0.0, 0.0, 0.0};
  }
  Vec3 e{};
  for (std::size_t a = 0; a < 3; ++a) {
    e[a] = c.amplitude_um[a] * std::sin(2.0 * std::numbers::pi * p_mm[a] / c.pitch_mm) +
           c.slope_um_per_m[a] * p_mm[a] / 1000.0;
  }
  return e;
}

Vec3 MachineModel::machine_error_um(const Vec3& p_mm, double t_s) const {
  const Vec3 th = thermal_um(t_s);
  const Vec3 pe = pitch_um(p_mm);
  return {th[0] + pe[0], th[1] + pe[1], th[2] + pe[2]};
}

double MachineModel::laser_reading_um(double cut_path_mm) {
  const double n =
      config_.laser_noise.enabled ? config_.laser_noise.sigma_um * laser_rng_.gaussian() : 0.0;
  return wear_um(cut_path_mm) + n;
}

double MachineModel::probe_noise_um() {
  return config_.probe_noise.enabled ? config_.probe_noise.sigma_um * probe_rng_.gaussian() : 0.0;
}

}  // namespace nccomp::sim::ncsim
