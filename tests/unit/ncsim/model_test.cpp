// The machine model with numbers: every effect's formula, its switch, and seeded determinism.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "sim/ncsim/config.hpp"
#include "sim/ncsim/model.hpp"

namespace nccomp::sim::ncsim {
namespace {

EffectsConfig all_off() {
  EffectsConfig e;
  e.wear.enabled = false;
  e.pushoff.enabled = false;
  e.hardness.enabled = false;
  e.thermal.enabled = false;
  e.pitch.enabled = false;
  e.probe_noise.enabled = false;
  e.laser_noise.enabled = false;
  return e;
}

TEST(NcsimModel, EveryEffectOffContributesNothing) {
  MachineModel m(all_off(), 7);
  const Vec3 p{12.0, 34.0, 5.0};
  EXPECT_EQ(m.wear_um(5000.0), 0.0);
  EXPECT_EQ(m.hardness(p), 1.0);
  EXPECT_EQ(m.pushoff_um(p, 20.0), 0.0);
  const Vec3 d = m.machine_error_um(p, 1000.0);
  EXPECT_EQ(d[0], 0.0);
  EXPECT_EQ(d[1], 0.0);
  EXPECT_EQ(d[2], 0.0);
  EXPECT_EQ(m.laser_reading_um(5000.0), 0.0);
  EXPECT_EQ(m.probe_noise_um(), 0.0);
}

TEST(NcsimModel, LinearAndPowerWearCurves) {
  EffectsConfig e = all_off();
  e.wear.enabled = true;
  e.wear.curve = WearCurve::kLinear;
  e.wear.initial_um = 1.0;
  e.wear.rate_um_per_m = 4.0;
  MachineModel lin(e, 1);
  EXPECT_DOUBLE_EQ(lin.wear_um(2500.0), 1.0 + 4.0 * 2.5);
  e.wear.curve = WearCurve::kPower;
  e.wear.coefficient_um = 3.0;
  e.wear.exponent = 0.5;
  MachineModel pw(e, 1);
  EXPECT_DOUBLE_EQ(pw.wear_um(4000.0), 1.0 + 3.0 * 2.0);
}

TEST(NcsimModel, BrokenToolJumpsAtItsPath) {
  EffectsConfig e = all_off();
  e.broken_tool.enabled = true;
  e.broken_tool.at_path_mm = 100.0;
  e.broken_tool.wear_jump_um = 250.0;
  MachineModel m(e, 1);
  EXPECT_FALSE(m.broken(99.9));
  EXPECT_EQ(m.wear_um(99.9), 0.0);
  EXPECT_TRUE(m.broken(100.0));
  EXPECT_DOUBLE_EQ(m.wear_um(100.0), 250.0);
}

TEST(NcsimModel, PushoffProportionalToLeverForceAndHardness) {
  EffectsConfig e = all_off();
  e.pushoff.enabled = true;
  e.pushoff.base_um = 4.0;
  e.pushoff.wear_gain_per_um = 0.05;
  e.pushoff.clamp_z_mm = -50.0;
  e.pushoff.reference_lever_mm = 50.0;
  MachineModel m(e, 1);
  // GIVEN nominal hardness WHEN the lever halves THEN the push-off halves.
  EXPECT_DOUBLE_EQ(m.pushoff_um({0, 0, 0}, 0.0), 4.0);
  EXPECT_DOUBLE_EQ(m.pushoff_um({0, 0, -25.0}, 0.0), 2.0);
  EXPECT_DOUBLE_EQ(m.pushoff_um({0, 0, -60.0}, 0.0), 0.0);  // below the clamp: no lever
  // 10 µm of wear: force × (1 + 0.05 · 10) = 1.5.
  EXPECT_DOUBLE_EQ(m.pushoff_um({0, 0, 0}, 10.0), 6.0);
  // With the hardness field on, the push-off scales with the local hardness.
  e.hardness.enabled = true;
  e.hardness.amplitude = 0.1;
  MachineModel h(e, 3);
  const Vec3 p{17.0, 23.0, 0.0};
  EXPECT_NEAR(h.pushoff_um(p, 0.0), 4.0 * h.hardness(p), 1e-12);
}

TEST(NcsimModel, HardnessFieldIsSmoothBoundedAndSeeded) {
  EffectsConfig e = all_off();
  e.hardness.enabled = true;
  e.hardness.amplitude = 0.1;
  e.hardness.wavelength_mm = 60.0;
  MachineModel a(e, 11);
  MachineModel b(e, 11);
  MachineModel c(e, 12);
  double sum = 0.0;
  double sq = 0.0;
  double max_dev = 0.0;
  double max_slope = 0.0;
  int n = 0;
  bool differs = false;
  for (double x = 0.0; x <= 300.0; x += 1.0) {
    for (double y = 0.0; y <= 300.0; y += 5.0) {
      const double h = a.hardness({x, y, 0.0});
      EXPECT_EQ(h, b.hardness({x, y, 0.0}));  // same seed, same part
      differs = differs || std::fabs(h - c.hardness({x, y, 0.0})) > 1e-6;
      sum += h;
      sq += (h - 1.0) * (h - 1.0);
      max_dev = std::max(max_dev, std::fabs(h - 1.0));
      max_slope = std::max(max_slope, std::fabs(a.hardness({x + 1.0, y, 0.0}) - h));
      ++n;
    }
  }
  EXPECT_TRUE(differs);
  const double mean = sum / n;
  const double rms = std::sqrt(sq / n);
  EXPECT_NEAR(mean, 1.0, 0.02);
  // Six unit waves normalised by sqrt(6): RMS amplitude / sqrt(2) = 0.0707 in the mean.
  EXPECT_NEAR(rms, 0.1 / std::sqrt(2.0), 0.025);
  EXPECT_LE(max_dev, 0.1 * std::sqrt(6.0) + 1e-12);
  // Smooth: over 1 mm it changes by at most amplitude · sqrt(6) · k_max · 1 mm.
  EXPECT_LT(max_slope, 0.1 * std::sqrt(6.0) * 2.0 * std::numbers::pi / (60.0 * 0.6));
}

TEST(NcsimModel, HardnessPerPartGivesEveryBlankItsOwnField) {
  EffectsConfig e = all_off();
  e.hardness.enabled = true;
  e.hardness.amplitude = 0.1;
  MachineModel same(e, 4);
  e.hardness.per_part = true;
  MachineModel own(e, 4);
  const Vec3 p{30.0, 20.0, -5.0};
  same.set_part(1);
  own.set_part(1);
  const double s1 = same.hardness(p);
  const double o1 = own.hardness(p);
  same.set_part(2);
  own.set_part(2);
  EXPECT_EQ(same.hardness(p), s1);
  double diff = 0.0;
  for (double x = 0.0; x < 200.0; x += 10.0) {
    diff = std::max(diff, std::fabs(own.hardness({x, 20.0, -5.0}) - o1));
  }
  EXPECT_GT(diff, 0.02);
  own.set_part(1);
  EXPECT_EQ(own.hardness(p), o1);  // part 1's blank again: the same field (seeded)
}

TEST(NcsimModel, FirstOrderThermalDriftAndTemperature) {
  EffectsConfig e = all_off();
  e.thermal.enabled = true;
  e.thermal.gain_um = {2.0, 0.0, -10.0};
  e.thermal.time_constant_s = 100.0;
  e.thermal.ambient_c = 20.0;
  e.thermal.temperature_rise_c = 5.0;
  MachineModel m(e, 1);
  const Vec3 d = m.thermal_um(100.0);
  const double f = 1.0 - std::exp(-1.0);
  EXPECT_NEAR(d[0], 2.0 * f, 1e-12);
  EXPECT_NEAR(d[2], -10.0 * f, 1e-12);
  EXPECT_NEAR(m.thermal_um(1e6)[2], -10.0, 1e-9);
  EXPECT_NEAR(m.temperature_c(100.0)[0], 20.0 + 5.0 * f, 1e-12);
  EXPECT_DOUBLE_EQ(m.temperature_c(100.0)[1], 20.0);
}

TEST(NcsimModel, PitchErrorPerAxis) {
  EffectsConfig e = all_off();
  e.pitch.enabled = true;
  e.pitch.amplitude_um = {1.0, 2.0, 0.0};
  e.pitch.pitch_mm = 10.0;
  e.pitch.slope_um_per_m = {3.0, 0.0, -4.0};
  MachineModel m(e, 1);
  const Vec3 p = m.pitch_um({2.5, 102.5, 500.0});
  EXPECT_NEAR(p[0], 1.0 + 3.0 * 0.0025, 1e-12);
  EXPECT_NEAR(p[1], 2.0, 1e-12);
  EXPECT_NEAR(p[2], -2.0, 1e-12);
}

TEST(NcsimModel, NoiseHasItsSigmaAndSeparateStreams) {
  EffectsConfig e = all_off();
  e.probe_noise = {true, 0.5};
  e.laser_noise = {true, 2.0};
  MachineModel m(e, 5);
  double s1 = 0.0;
  double s2 = 0.0;
  const int n = 20000;
  for (int i = 0; i < n; ++i) {
    const double v = m.probe_noise_um();
    s1 += v;
    s2 += v * v;
  }
  EXPECT_NEAR(s1 / n, 0.0, 0.02);
  EXPECT_NEAR(std::sqrt(s2 / n), 0.5, 0.02);
  // Switching the laser noise off leaves the probe's draws as they were.
  EffectsConfig off = e;
  off.laser_noise.enabled = false;
  MachineModel a(e, 9);
  MachineModel b(off, 9);
  for (int i = 0; i < 10; ++i) {
    (void)a.laser_reading_um(0.0);
    (void)b.laser_reading_um(0.0);
    EXPECT_EQ(a.probe_noise_um(), b.probe_noise_um());
  }
}

// The real data sets live in ../shared/data beside the checkout (CI clones the project there).
std::string shared_data(const char* relative) {
  return std::string(NCCOMP_SOURCE_DIR) + "/../shared/data/" + relative;
}

TEST(NcsimModel, Phm2010CurveReplaysTheMeasuredWear) {
  // c4 flute_1 (PHM 2010): VB at cut 1 = 31.41635516 µm, cut 2 = 34.8927704 µm.
  const std::string text = std::string("[ncsim]\nbus_map = \"") + NCCOMP_SOURCE_DIR +
                           "/config/reference-nc-modbus.toml\"\n"
                           "[effects.wear]\ncurve = \"phm2010\"\nphm_file = \"" +
                           shared_data("phm2010_milling_wear/c4_wear.csv") +
                           "\"\nphm_column = \"flute_1\"\npath_per_cut_mm = 100.0\n"
                           "radial_per_vb = 0.5\n";
  const std::string data = shared_data("phm2010_milling_wear/c4_wear.csv");
  if (FILE* f = std::fopen(data.c_str(), "r"); f == nullptr) {
    FAIL() << "PHM 2010 data not found at " << data << " (../shared beside the checkout)";
  } else {
    std::fclose(f);
  }
  const SimConfig c = parse_sim_config(text, "phm.toml", ".");
  MachineModel m(c.effects, 1);
  EXPECT_DOUBLE_EQ(m.wear_um(0.0), 0.0);
  EXPECT_NEAR(m.wear_um(100.0), (34.8927704 - 31.41635516) * 0.5, 1e-9);
  EXPECT_NEAR(m.wear_um(50.0), (34.8927704 - 31.41635516) * 0.25, 1e-9);
  // Never decreasing, 314 cuts later held at the last value.
  double last = 0.0;
  for (double p = 0.0; p < 40000.0; p += 250.0) {
    EXPECT_GE(m.wear_um(p), last - 1e-12);
    last = m.wear_um(p);
  }
  EXPECT_EQ(m.wear_um(31400.0), m.wear_um(1e9));
}

TEST(NcsimModel, ThermalReplayFollowsTheFlThermalGauges) {
  const std::string data = shared_data("fl_thermal_spindle_drift/data.csv");
  if (FILE* f = std::fopen(data.c_str(), "r"); f == nullptr) {
    FAIL() << "FL_THERMAL data not found at " << data << " (../shared beside the checkout)";
  } else {
    std::fclose(f);
  }
  const std::string text = std::string("[ncsim]\nbus_map = \"") + NCCOMP_SOURCE_DIR +
                           "/config/reference-nc-modbus.toml\"\n"
                           "[effects.thermal]\nmode = \"replay\"\nreplay_file = \"" +
                           data +
                           "\"\nx_channel = \"ch1\"\nz_channel = \"ch5\"\n"
                           "channel_sign = [1.0, 1.0, -1.0]\ntime_scale = 1.0\n";
  const SimConfig c = parse_sim_config(text, "thermal.toml", ".");
  MachineModel m(c.effects, 1);
  // Rows t = 0 and 15 s of data.csv: ch1 0.377452788 → 0.399399975, ch5 0.14420852 →
  // 0.175689695 µm; t5 31.486612097343599 °C and t1 26.181494231478801 °C at 15 s.
  const Vec3 d = m.thermal_um(15.0);
  EXPECT_NEAR(d[0], 0.399399975 - 0.377452788, 1e-9);
  EXPECT_EQ(d[1], 0.0);
  EXPECT_NEAR(d[2], -(0.175689695 - 0.14420852), 1e-9);
  EXPECT_NEAR(m.thermal_um(7.5)[2], -(0.175689695 - 0.14420852) / 2.0, 1e-9);
  EXPECT_NEAR(m.temperature_c(15.0)[0], 31.486612097343599, 1e-9);
  EXPECT_NEAR(m.temperature_c(15.0)[1], 26.181494231478801, 1e-9);
  // The axial gauge's peak (SOURCE.md: ch5 up to +39 µm) appears, with the configured sign.
  double lowest = 0.0;
  for (double t = 0.0; t < 170000.0; t += 60.0) {
    lowest = std::min(lowest, m.thermal_um(t)[2]);
  }
  EXPECT_LT(lowest, -35.0);
  EXPECT_GT(lowest, -40.0);
}

}  // namespace
}  // namespace nccomp::sim::ncsim
