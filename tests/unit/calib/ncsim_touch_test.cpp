// ncsim's touch program in request mode (the daemon's calibrator tells it what to do through the
// request register), checked against its documented model (sim/ncsim/programs_extra.cpp):
//
// GIVEN static errors, reference-probe pretravel and a request register
// WHEN the "daemon" (this test) writes request codes and the X offset
// THEN reference touches trigger at nominal + (−E + pretravel − o)/1000 in program coordinates
//   (machine coordinates: without −o), a test grind leaves the chords of facets d0 ∓ (E + o) in
//   the device export with the X offset in force at the end of the grind, a new grind starts
//   only when the daemon put a new Δx on X, the nominal set starts the warm-up, and the run ends
//   cycles × cycle_interval_s later.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "core/calib/facet.hpp"
#include "formats/calib/facet_import.hpp"
#include "sim/ncsim/simulation.hpp"

namespace nccomp::test::calib {
namespace {

namespace fs = std::filesystem;
using namespace sim::ncsim;

const std::vector<std::uint16_t> kKnown{0, 1, 2, 3, 4, 5, 6, 7, 8};

SimConfig touch_config(const std::string& export_path) {
  SimConfig c;
  EffectsConfig& e = c.effects;
  e.wear.enabled = false;
  e.pushoff.enabled = false;
  e.hardness.enabled = false;
  e.thermal.enabled = true;
  e.thermal.gain_um = {20.0, -8.0, -12.0};
  e.thermal.time_constant_s = 1000.0;
  e.pitch.enabled = false;
  e.probe_noise.enabled = false;
  e.laser_noise.enabled = false;
  TouchConfig& t = c.touch;
  t.request_register = 5;
  t.touches_per_axis = 1;
  t.touch_time_s = 1.0;
  t.axis_error_um = {-23.0, 12.0, -8.0};
  t.x_axial_error_um = -31.0;
  t.reference_pretravel_um = 4.0;
  t.reference_axial_pretravel_um = 6.5;
  t.chord_noise_um = 0.0;
  t.grind_time_s = 60.0;
  t.facet_export_path = export_path;
  t.warm_up_after_nominals = true;
  t.cycles = 2;
  t.cycle_interval_s = 500.0;
  return c;
}

std::string read(const std::string& p) {
  std::ifstream in(p);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

TEST(NcsimTouchRequests, ReferenceTouchesGrindsNominalsAndWarmUpFollowTheRequests) {
  const std::string exp =
      (fs::temp_directory_path() / ("facets_" + std::to_string(::getpid()) + ".csv")).string();
  const SimConfig c = touch_config(exp);
  Simulation sim(c, ProgramKind::kTouch, kKnown);
  sim.advance_to(core::from_seconds(30.0));
  EXPECT_TRUE(sim.results().touches.empty());  // nothing requested yet
  // The old calibration still in force on X: +7 µm (program coordinates read it).
  ASSERT_EQ(sim.write_offset(30.0, 6, 7.0), WriteResult::kAccepted);
  ASSERT_EQ(sim.write_offset(30.0, 5, 1.0), WriteResult::kAccepted);  // reference touches
  sim.advance_to(core::from_seconds(60.0));
  const auto& t = sim.results().touches;
  ASSERT_EQ(t.size(), 4u);
  // X lateral: nominal 100 − 25 = 75 mm; E = −23 µm, pretravel 4, o = 7 (thermal not started).
  EXPECT_EQ(t[0].probe, 1);
  EXPECT_NEAR(t[0].trigger_position_mm, 75.0 + (23.0 + 4.0 - 7.0) / 1000.0, 1e-9);
  EXPECT_NEAR(t[0].true_drift_um, 23.0 - 7.0, 1e-9);
  // X axial: 100 − 30 = 70 mm, E = −31, pretravel 6.5.
  EXPECT_EQ(t[1].variant, 1);
  EXPECT_NEAR(t[1].trigger_position_mm, 70.0 + (31.0 + 6.5 - 7.0) / 1000.0, 1e-9);
  // Y: 50 − 25 = 25 mm, E = +12, o = 0.
  EXPECT_NEAR(t[2].trigger_position_mm, 25.0 + (-12.0 + 4.0) / 1000.0, 1e-9);
  // The code stays 1: nothing more is touched.
  sim.advance_to(core::from_seconds(80.0));
  EXPECT_EQ(t.size(), 4u);

  // Lateral test grind with Δx = +20 on X: facets d0 ∓ (E + o) = 0.1 ∓ (−3 µm).
  ASSERT_EQ(sim.write_offset(80.0, 6, 20.0), WriteResult::kAccepted);
  ASSERT_EQ(sim.write_offset(80.0, 5, 2.0), WriteResult::kAccepted);
  sim.advance_to(core::from_seconds(200.0));
  auto rows = formats::calib::parse_facet_export(read(exp), exp);
  ASSERT_EQ(rows.size(), 1u);  // one grind: the same Δx is not ground twice
  EXPECT_EQ(rows[0].face, core::calib::Face::kLateral);
  EXPECT_NEAR(rows[0].chord_plus_mm, core::calib::chord_from_depth_mm(5.0, 0.1 + 0.003), 1e-6);
  EXPECT_NEAR(rows[0].chord_minus_mm, core::calib::chord_from_depth_mm(5.0, 0.1 - 0.003), 1e-6);
  // The exact rule on these chords gives e = −3 µm → next Δx = 23 = −E.
  EXPECT_NEAR(core::calib::facet_error_exact_um(5.0, rows[0].chord_plus_mm, rows[0].chord_minus_mm),
              3.0, 1e-3);
  // A new Δx (+23) → a second grind with equal facets.
  ASSERT_EQ(sim.write_offset(200.0, 6, 23.0), WriteResult::kAccepted);
  sim.advance_to(core::from_seconds(300.0));
  rows = formats::calib::parse_facet_export(read(exp), exp);
  ASSERT_EQ(rows.size(), 2u);
  EXPECT_NEAR(rows[1].chord_plus_mm, rows[1].chord_minus_mm, 1e-9);
  // End face with Δx = +31: equal facets at once.
  ASSERT_EQ(sim.write_offset(300.0, 6, 31.0), WriteResult::kAccepted);
  ASSERT_EQ(sim.write_offset(300.0, 5, 3.0), WriteResult::kAccepted);
  sim.advance_to(core::from_seconds(400.0));
  rows = formats::calib::parse_facet_export(read(exp), exp);
  ASSERT_EQ(rows.size(), 3u);
  EXPECT_EQ(rows[2].face, core::calib::Face::kEndFace);
  EXPECT_NEAR(rows[2].chord_plus_mm, rows[2].chord_minus_mm, 1e-9);

  // Nominals with X = 23 in force: the machine-probe set, then the warm-up starts.
  ASSERT_EQ(sim.write_offset(400.0, 6, 23.0), WriteResult::kAccepted);
  ASSERT_EQ(sim.write_offset(400.0, 5, 4.0), WriteResult::kAccepted);
  sim.advance_to(core::from_seconds(420.0));
  ASSERT_EQ(t.size(), 8u);
  EXPECT_EQ(t[4].probe, 0);
  // Body X: 200 − 10 = 190 mm; E + o = −23 + 23 = 0, no thermal yet.
  EXPECT_NEAR(t[4].trigger_position_mm, 190.0, 1e-9);
  const double warm = 404.0;  // the fourth touch of the set (touches every 1 s from 400 s)
  ASSERT_EQ(sim.write_offset(420.0, 5, 0.0), WriteResult::kAccepted);
  // A recalibration at 900 s: X reads the thermal drift since the warm-up start.
  ASSERT_EQ(sim.write_offset(900.0, 5, 5.0), WriteResult::kAccepted);
  sim.advance_to(core::from_seconds(910.0));
  ASSERT_EQ(t.size(), 12u);
  const double th = 20.0 * (1.0 - std::exp(-(901.0 - warm) / 1000.0));
  EXPECT_NEAR(t[8].true_drift_um, -th, 0.02);
  EXPECT_EQ(t[8].cycle, 1);
  // The run ends cycles × cycle_interval_s = 1000 s after the warm-up start.
  sim.advance_to(core::from_seconds(1400.0));
  EXPECT_FALSE(sim.done());
  sim.advance_to(core::from_seconds(1410.0));
  EXPECT_TRUE(sim.done());
  fs::remove(exp);
}

TEST(NcsimTouchRequests, MachineCoordinatesDoNotReadTheOffset) {
  SimConfig c = touch_config("");
  c.touch.program_coordinates = false;
  Simulation sim(c, ProgramKind::kTouch, kKnown);
  ASSERT_EQ(sim.write_offset(0.0, 6, 7.0), WriteResult::kAccepted);
  ASSERT_EQ(sim.write_offset(0.0, 5, 1.0), WriteResult::kAccepted);
  sim.advance_to(core::from_seconds(10.0));
  const auto& t = sim.results().touches;
  ASSERT_EQ(t.size(), 4u);
  EXPECT_NEAR(t[0].trigger_position_mm, 75.0 + (23.0 + 4.0) / 1000.0, 1e-9);
  EXPECT_NEAR(t[0].true_drift_um, 23.0, 1e-9);
}

}  // namespace
}  // namespace nccomp::test::calib
