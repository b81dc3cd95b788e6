// The programs on the machine model, with numbers: the cut follows the offsets in force (after
// the NC's latency), the NC refuses out-of-range values, the events come in program order.
#include <gtest/gtest.h>

#include <cmath>
#include <variant>

#include "sim/ncsim/simulation.hpp"

namespace nccomp::sim::ncsim {
namespace {

// The reference map's logical registers: tool length / radius wear 0, 1; checkpoints 2..5;
// axis offsets X, Y, Z 6, 7, 8.
const std::vector<std::uint16_t> kKnown{0, 1, 2, 3, 4, 5, 6, 7, 8};

SimConfig quiet_config() {
  SimConfig c;
  EffectsConfig& e = c.effects;
  e.wear.enabled = false;
  e.pushoff.enabled = false;
  e.hardness.enabled = false;
  e.thermal.enabled = false;
  e.pitch.enabled = false;
  e.probe_noise.enabled = false;
  e.laser_noise.enabled = false;
  c.mould_face.size_x_mm = 10.0;
  c.mould_face.size_y_mm = 2.0;
  c.mould_face.stepover_mm = 1.0;
  c.mould_face.feed_mm_per_min = 600.0;  // 10 mm/s: 0.05 mm steps of 5 ms
  c.mould_face.measure_interval_mm = 0.0;
  c.nc.latency_s = 0.1;
  return c;
}

TEST(NcsimRegisters, RangeCheckLatencyAndUnknownRegisters) {
  OffsetRegisters r({0, 20}, 100.0, 0.5);
  EXPECT_EQ(r.write(1.0, 20, -7.5), WriteResult::kAccepted);
  EXPECT_EQ(r.write(1.0, 20, 100.5), WriteResult::kOutOfRange);
  EXPECT_EQ(r.write(1.0, 20, std::nan("")), WriteResult::kOutOfRange);
  EXPECT_EQ(r.write(1.0, 5, 1.0), WriteResult::kUnknownRegister);
  EXPECT_EQ(r.refused(), 3U);
  r.advance(1.49);
  EXPECT_EQ(r.value(20), 0.0);  // not yet in force
  r.advance(1.5);
  EXPECT_EQ(r.value(20), -7.5);
  ASSERT_EQ(r.log().size(), 1U);
  EXPECT_DOUBLE_EQ(r.log()[0].effective_t_s, 1.5);
}

TEST(NcsimMouldFace, ErrorIsTheWearAlongThePathAndEveryRowIsFine) {
  SimConfig c = quiet_config();
  c.effects.wear.enabled = true;
  c.effects.wear.rate_um_per_m = 100.0;  // 0.1 µm per mm of cut
  Simulation sim(c, ProgramKind::kMouldFace, kKnown);
  sim.advance_to(core::from_seconds(100.0));
  ASSERT_TRUE(sim.done());
  const auto& rows = sim.results().surface;
  // 3 passes of 10 mm at 0.05 mm.
  ASSERT_EQ(rows.size(), 600U);
  double cut = 0.0;
  for (std::size_t i = 0; i < rows.size(); ++i) {
    cut += 0.05;
    EXPECT_NEAR(rows[i].error_um, 0.1 * cut, 1e-9) << i;
    EXPECT_EQ(rows[i].offset_um, 0.0);
    EXPECT_NEAR(rows[i].z_mm, mould_face_z_mm(c.mould_face, rows[i].x_mm, rows[i].y_mm), 1e-12);
    if (i > 0 && rows[i].pass == rows[i - 1].pass) {
      EXPECT_LE(std::hypot(rows[i].x_mm - rows[i - 1].x_mm, rows[i].y_mm - rows[i - 1].y_mm),
                0.1 + 1e-9);
    }
  }
  EXPECT_EQ(rows.back().pass, 2);
  // Zig-zag: the second pass runs from x = 10 back to 0 at y = 1.
  EXPECT_NEAR(rows[200].x_mm, 9.95, 1e-9);
  EXPECT_NEAR(rows[200].y_mm, 1.0, 1e-12);
}

// approach_s: after each part start the tool waits at the first pass's start without cutting,
// then the part is cut as without it (the same rows, approach_s later).
TEST(NcsimMouldFace, ApproachWaitsAtTheFirstPassStartWithoutCutting) {
  SimConfig c = quiet_config();
  c.effects.wear.enabled = true;
  c.effects.wear.rate_um_per_m = 100.0;
  c.mould_face.approach_s = 0.5;
  c.parts = 2;
  Simulation sim(c, ProgramKind::kMouldFace, kKnown);
  std::vector<double> part_start_s;
  double first_cut_s = -1.0;
  std::size_t samples_before_cut = 0;
  for (int k = 1; k <= 20000 && !sim.done(); ++k) {
    sim.advance_to(core::from_seconds(0.001 * k));
    for (const auto& e : sim.take_events()) {
      if (const auto* pe = std::get_if<core::ProgramEvent>(&e)) {
        if (pe->kind == core::ProgramEventKind::kPartStart) {
          part_start_s.push_back(core::seconds(pe->time_ns));
        }
      }
    }
    const core::AxisSample& a = sim.axis();
    if (first_cut_s < 0.0 && !part_start_s.empty()) {
      if (a.cutting) {
        first_cut_s = core::seconds(a.time_ns);
      } else {
        ++samples_before_cut;
        EXPECT_NEAR(a.position_mm[0], 0.0 + c.mould_face.ball_radius_mm *
                                                mould_face_normal(c.mould_face, 0.0, 0.0)[0],
                    1e-9);
      }
    }
  }
  ASSERT_TRUE(sim.done());
  ASSERT_EQ(part_start_s.size(), 2U);
  EXPECT_NEAR(first_cut_s - part_start_s[0], 0.5, 0.011);
  EXPECT_GT(samples_before_cut, 50U);
  // 3 passes of 1 s and 2 links of 0.1 s after the approach: the second part starts 3.7 s in.
  EXPECT_NEAR(part_start_s[1] - part_start_s[0], 3.7, 0.011);
  const auto& rows = sim.results().surface;
  // Steps of 1 ms, 0.01 mm: 2 parts of 3 passes of 1000 rows, as without the approach (it cuts
  // nothing, so the wear at the first part's end is that of its 30 mm).
  ASSERT_EQ(rows.size(), 6000U);
  EXPECT_NEAR(rows[2999].error_um, 0.1 * 30.0, 1e-9);
}

// The probe cycle after each part reads the finished face at mid-X of passes spread from the
// first to the last: the wear at the cut path where the point was cut plus the push-off there
// (which a laser measurement of the tool never shows), then the part ends.
TEST(NcsimMouldFace, ProbeCycleReadsTheFinishedFaceWithItsPushoff) {
  SimConfig c = quiet_config();
  c.effects.wear.enabled = true;
  c.effects.wear.rate_um_per_m = 100.0;  // 0.1 µm per mm of cut
  c.effects.pushoff.enabled = true;
  c.mould_face.probe_points = 2;
  c.mould_face.probe_time_s = 0.5;
  c.parts = 2;
  Simulation sim(c, ProgramKind::kMouldFace, kKnown);
  std::vector<core::ProbeMeasurement> probes;
  std::vector<double> part_end_s;
  for (int k = 1; k <= 20000 && !sim.done(); ++k) {
    sim.advance_to(core::from_seconds(0.001 * k));
    for (const auto& e : sim.take_events()) {
      if (const auto* pm = std::get_if<core::ProbeMeasurement>(&e)) {
        probes.push_back(*pm);
      } else if (const auto* pe = std::get_if<core::ProgramEvent>(&e)) {
        if (pe->kind == core::ProgramEventKind::kPartEnd) {
          part_end_s.push_back(core::seconds(pe->time_ns));
          EXPECT_EQ(probes.size(), 2U * part_end_s.size());  // the probe cycle, then the end
        }
      }
    }
  }
  ASSERT_TRUE(sim.done());
  ASSERT_EQ(probes.size(), 4U);
  ASSERT_EQ(part_end_s.size(), 2U);
  // 3 passes of 1 s, 2 links of 0.1 s, 2 probed points of 0.5 s.
  EXPECT_NEAR(part_end_s[0], 4.2, 0.011);
  const PushoffConfig& po = c.effects.pushoff;
  const auto& m = sim.results().measurements;
  ASSERT_EQ(m.size(), 4U);
  for (std::size_t i = 0; i < probes.size(); ++i) {
    const int part = static_cast<int>(i / 2);
    const int pass = i % 2 == 0 ? 0 : 2;  // 2 points on 3 passes: the first and the last
    const double y = pass * 1.0;
    const double z = mould_face_z_mm(c.mould_face, 5.0, y);
    const double cut_mm = 30.0 * part + 10.0 * pass + 5.0;
    const double wear = 0.1 * cut_mm;
    const double pushoff = po.base_um * (1.0 + po.wear_gain_per_um * wear) * (z - po.clamp_z_mm) /
                           po.reference_lever_mm;
    EXPECT_EQ(probes[i].part, part + 1) << i;
    EXPECT_EQ(probes[i].checkpoint, static_cast<std::int32_t>(i % 2)) << i;
    EXPECT_EQ(probes[i].wall_angle_deg, 0.0);
    EXPECT_EQ(probes[i].ball_radius_mm, c.mould_face.ball_radius_mm);
    EXPECT_NEAR(probes[i].position_mm[0], 5.0, 0.026) << i;
    EXPECT_NEAR(probes[i].position_mm[1], y, 1e-12) << i;
    EXPECT_NEAR(probes[i].raw_deviation_um, wear + pushoff, 0.005) << i;
    EXPECT_EQ(m[i].kind, MeasurementKind::kProbe);
    EXPECT_EQ(m[i].checkpoint, probes[i].checkpoint);
    EXPECT_DOUBLE_EQ(m[i].reading_um, probes[i].raw_deviation_um);  // no probe noise
    EXPECT_NEAR(m[i].cut_path_mm, 30.0 * (part + 1), 1e-9);         // probed after the part
  }
}

TEST(NcsimMouldFace, AxisAndToolOffsetsActAfterTheLatency) {
  SimConfig c = quiet_config();
  c.effects.wear.enabled = true;
  c.effects.wear.rate_um_per_m = 0.0;
  c.effects.wear.initial_um = 6.0;  // a constant 6 µm of wear
  Simulation sim(c, ProgramKind::kMouldFace, kKnown);
  sim.advance_to(core::from_seconds(0.5));
  // Z axis offset −6 µm (creep's sign: −c·n on a floor) at t = 0.5 s, in force at 0.6 s.
  ASSERT_EQ(sim.write_offset(0.5, 8, -6.0), WriteResult::kAccepted);
  // Beyond the NC's range: refused, nothing changes.
  EXPECT_EQ(sim.write_offset(0.5, 0, 1e4), WriteResult::kOutOfRange);
  sim.advance_to(core::from_seconds(1.0));
  const auto& rows = sim.results().surface;
  for (const SurfaceRow& r : rows) {
    const Vec3 n = mould_face_normal(c.mould_face, r.x_mm, r.y_mm);
    // rows are cut at path/feed: 0.05 mm every 5 ms.
    const double t = r.path_mm / 10.0;
    if (t < 0.6 - 1e-9) {
      EXPECT_NEAR(r.error_um, 6.0, 1e-9);
    } else {
      EXPECT_NEAR(r.error_um, 6.0 - 6.0 * n[2], 1e-9) << t;
      EXPECT_NEAR(r.offset_um, 6.0 * n[2], 1e-9);
    }
  }
  // Length and radius wear registers split as the NC applies them: L·n_z + R·sinθ.
  ASSERT_EQ(sim.write_offset(1.0, 8, 0.0), WriteResult::kAccepted);
  ASSERT_EQ(sim.write_offset(1.0, 0, -4.0), WriteResult::kAccepted);
  ASSERT_EQ(sim.write_offset(1.0, 1, -2.0), WriteResult::kAccepted);
  sim.advance_to(core::from_seconds(3.0));
  const SurfaceRow& r = sim.results().surface.back();
  const Vec3 n = mould_face_normal(c.mould_face, r.x_mm, r.y_mm);
  EXPECT_NEAR(r.error_um, 6.0 - 4.0 * n[2] - 2.0 * std::sqrt(1.0 - n[2] * n[2]), 1e-9);
}

TEST(NcsimMouldFace, LaserTripsAtTheIntervalInProgramOrder) {
  SimConfig c = quiet_config();
  c.effects.wear.enabled = true;
  c.effects.wear.rate_um_per_m = 1000.0;  // 1 µm per mm
  c.mould_face.measure_interval_mm = 12.0;
  c.mould_face.laser_trip_s = 1.0;
  Simulation sim(c, ProgramKind::kMouldFace, kKnown);
  std::vector<core::Event> ev;
  bool cutting_in_trip = false;
  bool in_trip = false;
  for (int k = 1; k <= 10000 && !sim.done(); ++k) {
    sim.advance_to(core::from_seconds(0.001 * k));
    // The step that raised the interruption still cut; every step of the trip after it must not.
    cutting_in_trip = cutting_in_trip || (in_trip && sim.axis().cutting);
    for (auto& e : sim.take_events()) {
      if (const auto* pe = std::get_if<core::ProgramEvent>(&e)) {
        in_trip = pe->kind == core::ProgramEventKind::kInterruption;
      }
      ev.push_back(e);
    }
  }
  ASSERT_TRUE(sim.done());
  EXPECT_FALSE(cutting_in_trip);
  // 30 mm of cut: measurements after 12 and 24 mm.
  ASSERT_EQ(ev.size(), 9U);  // tool, start, 2 × (interruption, measurement, resume), end
  EXPECT_TRUE(std::holds_alternative<core::ToolChange>(ev[0]));
  EXPECT_EQ(std::get<core::ProgramEvent>(ev[1]).kind, core::ProgramEventKind::kPartStart);
  std::vector<double> wear;
  for (const auto& e : ev) {
    if (const auto* tm = std::get_if<core::ToolMeasurement>(&e)) {
      wear.push_back(tm->wear_um[0]);
      EXPECT_FALSE(tm->broken);
    }
  }
  ASSERT_EQ(wear.size(), 2U);
  EXPECT_NEAR(wear[0], 12.0, 0.051);
  EXPECT_NEAR(wear[1], 24.0, 0.051);
  EXPECT_EQ(std::get<core::ProgramEvent>(ev.back()).kind, core::ProgramEventKind::kPartEnd);
  // The trips take 2 × 1 s on top of 30 mm cut + 2 mm of links at 10 mm/s.
  EXPECT_NEAR(sim.time_s(), 3.2 + 2.0, 0.01);
}

TEST(NcsimMouldFace, TheDaemonAsksForAMeasurementThroughItsRegister) {
  SimConfig c = quiet_config();
  c.mould_face.measure_interval_mm = 0.0;  // only when asked
  c.mould_face.laser_trip_s = 0.5;
  c.nc.measure_request_register = 3;
  Simulation sim(c, ProgramKind::kMouldFace, kKnown);
  auto measurements = [&] {
    int n = 0;
    for (const auto& e : sim.take_events()) {
      n += std::holds_alternative<core::ToolMeasurement>(e) ? 1 : 0;
    }
    return n;
  };
  sim.advance_to(core::from_seconds(0.5));
  EXPECT_EQ(measurements(), 0);
  // The request (1) is in force after the 0.1 s latency: one trip; holding it at 1 asks nothing
  // more; 0 then 1 again asks once more (a rising edge per request).
  ASSERT_EQ(sim.write_offset(0.5, 3, 1.0), WriteResult::kAccepted);
  sim.advance_to(core::from_seconds(1.5));
  EXPECT_EQ(measurements(), 1);
  sim.advance_to(core::from_seconds(2.0));
  EXPECT_EQ(measurements(), 0);
  ASSERT_EQ(sim.write_offset(2.0, 3, 0.0), WriteResult::kAccepted);
  sim.advance_to(core::from_seconds(2.2));
  ASSERT_EQ(sim.write_offset(2.2, 3, 1.0), WriteResult::kAccepted);
  sim.advance_to(core::from_seconds(3.2));
  EXPECT_EQ(measurements(), 1);
}

TEST(NcsimMouldFace, BrokenToolIsReportedByTheLaser) {
  SimConfig c = quiet_config();
  c.effects.broken_tool = {true, 5.0, 300.0, true};
  c.mould_face.measure_interval_mm = 8.0;
  c.mould_face.laser_trip_s = 0.2;
  Simulation sim(c, ProgramKind::kMouldFace, kKnown);
  sim.advance_to(core::from_seconds(10.0));
  bool seen = false;
  for (const auto& e : sim.take_events()) {
    if (const auto* tm = std::get_if<core::ToolMeasurement>(&e)) {
      seen = true;
      EXPECT_TRUE(tm->broken);
      EXPECT_NEAR(tm->wear_um[0], 300.0, 1e-9);
    }
  }
  EXPECT_TRUE(seen);
}

SimConfig wall_config() {
  SimConfig c = quiet_config();
  auto& p = c.side_wall.plan;
  p.contour = {{0.0, 0.0}, {40.0, 0.0}};
  p.closed = false;
  p.material = core::checkpoint::MaterialSide::kLeft;
  p.z_start_mm = -5.0;
  p.z_end_mm = -25.0;
  p.depth_step_mm = 20.0;
  p.wall_angle_deg = 3.0;
  p.extra_points_mm = {10.0, 30.0};
  p.ball_radius_mm = 2.0;
  p.tool_radius_mm = 5.0;
  c.side_wall.feed_mm_per_min = 1200.0;
  c.side_wall.probe_time_s = 0.5;
  c.parts = 2;
  return c;
}

TEST(NcsimSideWall, PushoffGrowsWithHeightAndTheProbeSeesItPlusDelta0) {
  SimConfig c = wall_config();
  c.effects.pushoff.enabled = true;
  c.effects.pushoff.base_um = 10.0;
  c.effects.pushoff.clamp_z_mm = -45.0;
  c.effects.pushoff.reference_lever_mm = 40.0;
  c.effects.pushoff.wear_gain_per_um = 0.0;
  c.effects.probe_outlier = {true, 2, 1, 400.0};
  Simulation sim(c, ProgramKind::kSideWall, kKnown);
  sim.advance_to(core::from_seconds(1000.0));
  ASSERT_TRUE(sim.done());
  const auto& walls = sim.results().walls;
  ASSERT_FALSE(walls.empty());
  for (const WallRow& w : walls) {
    EXPECT_NEAR(w.error_um, 10.0 * (w.z_mm + 45.0) / 40.0, 1e-9);
  }
  const auto& cps = sim.results().checkpoints;
  ASSERT_EQ(cps.size(), 8U);  // 2 parts × 2 levels × 2 points
  const double delta0 = (2.0 / std::cos(3.0 * std::numbers::pi / 180.0) - 2.0) * 1000.0;
  for (const CheckpointRow& cp : cps) {
    EXPECT_NEAR(cp.error_um, 10.0 * (cp.z_mm + 45.0) / 40.0, 1e-9);
    const double outlier = (cp.part == 2 && cp.checkpoint == 1) ? 400.0 : 0.0;
    EXPECT_NEAR(cp.probed_um, cp.error_um + delta0 + outlier, 1e-9);
  }
  // The radius register moves the wall: write +3 µm (S1: c > 0 leaves material) and cut again.
  SimConfig c2 = c;
  c2.parts = 1;
  Simulation s2(c2, ProgramKind::kSideWall, kKnown);
  ASSERT_EQ(s2.write_offset(0.0, 1, 3.0), WriteResult::kAccepted);
  s2.advance_to(core::from_seconds(1000.0));
  for (const WallRow& w : s2.results().walls) {
    if (w.s_mm > 2.5) {  // after the 0.1 s latency at 20 mm/s
      EXPECT_NEAR(w.error_um, 10.0 * (w.z_mm + 45.0) / 40.0 + 3.0, 1e-9);
      EXPECT_NEAR(w.offset_um, -3.0, 1e-12);
    }
  }
  // Probe events: one per checkpoint, with the plan's ids and the wall angle.
  int probes = 0;
  for (const auto& e : s2.take_events()) {
    if (const auto* pm = std::get_if<core::ProbeMeasurement>(&e)) {
      EXPECT_EQ(pm->checkpoint, probes);
      EXPECT_DOUBLE_EQ(pm->wall_angle_deg, 3.0);
      EXPECT_DOUBLE_EQ(pm->ball_radius_mm, 2.0);
      ++probes;
    }
  }
  EXPECT_EQ(probes, 4);
}

TEST(NcsimTouch, TriggerShiftIsTheDriftAndTheOffsetCancelsIt) {
  SimConfig c = quiet_config();
  c.effects.thermal.enabled = true;
  c.effects.thermal.gain_um = {6.0, -3.0, 9.0};
  c.effects.thermal.time_constant_s = 100.0;
  c.touch.cycles = 2;
  c.touch.cycle_interval_s = 100.0;
  c.touch.touch_time_s = 1.0;
  Simulation sim(c, ProgramKind::kTouch, kKnown);
  sim.advance_to(core::from_seconds(150.0));
  // Cancel the X drift from now on with the X axis offset.
  const double dx = 6.0 * (1.0 - std::exp(-2.0));
  ASSERT_EQ(sim.write_offset(150.0, 6, -dx), WriteResult::kAccepted);
  sim.advance_to(core::from_seconds(1000.0));
  ASSERT_TRUE(sim.done());
  const auto& t = sim.results().touches;
  // Reference set and nominal set (X lateral, X axial, Y, Z, from +), then 2 cycles.
  ASSERT_EQ(t.size(), 4U + 4U + 2U * 4U);
  for (const TouchRow& r : t) {
    const double sign = static_cast<double>(r.direction);
    const Vec3 c0 = r.probe == 1 ? c.touch.reference_center_mm : c.touch.body_center_mm;
    const double rad =
        r.probe == 1
            ? (r.variant == 1 ? c.touch.reference_axial_radius_mm : c.touch.reference_radius_mm)
            : (r.variant == 1 ? c.touch.body_axial_radius_mm : c.touch.body_radius_mm);
    const double nominal = c0[static_cast<std::size_t>(r.axis)] - sign * rad;
    EXPECT_NEAR((r.trigger_position_mm - nominal) * 1000.0, r.true_drift_um, 1e-6);
    if (r.cycle == 2 && r.axis == 0) {
      // A second apart at t ≈ 200 s: the offset written at 150 s cancels the drift at 200 s.
      EXPECT_NEAR(r.true_drift_um, 0.0, 0.05);
    }
    if (r.cycle == 2 && r.axis == 2) {
      EXPECT_NEAR(r.true_drift_um, -9.0 * (1.0 - std::exp(-2.04)), 0.05);
    }
  }
}

TEST(NcsimRoll, GroundProfileIsTheEnvelopeMovedByTheXOffset) {
  SimConfig c = quiet_config();
  // A 3 % flank ground with a straight wheel (h = 0) whose reference point rides on the target:
  // a straight wheel touches with its end, so the profile comes out exact on the flat parts.
  for (int i = 0; i <= 400; ++i) {
    const double z = 0.5 * i;
    c.roll.target_z_mm.push_back(z);
    c.roll.target_u_mm.push_back(z < 80 ? 0.0 : std::min(z - 80.0, 40.0) * 0.03);
  }
  c.roll.z_mm = c.roll.target_z_mm;
  c.roll.u_mm = c.roll.target_u_mm;
  c.roll.wheel_width_mm = 1.0;
  c.roll.wheel_height_mm = 0.0;
  c.roll.passes = 1;
  c.roll.feed_mm_per_min = 6000.0;
  Simulation sim(c, ProgramKind::kRoll, kKnown);
  ASSERT_EQ(sim.write_offset(0.0, 6, 5.0), WriteResult::kAccepted);
  sim.advance_to(core::from_seconds(100.0));
  ASSERT_TRUE(sim.done());
  const auto& rows = sim.results().surface;
  ASSERT_GT(rows.size(), 3000U);
  for (const SurfaceRow& r : rows) {
    // The offset is in force after 0.1 s = 10 mm; on the flank a straight wheel 1 mm wide
    // grinds the lower end's height (the envelope), 0.5 mm · 3 % = 15 µm lower.
    if (r.z_mm > 10.5 && (r.z_mm < 79.5 || r.z_mm > 120.5)) {
      EXPECT_NEAR(r.error_um, 5.0, 1e-6) << r.z_mm;
    }
  }
}

// measurements.csv: every laser reading with the true wear it measured, every probe reading with
// what a noise-free probe would show.
TEST(NcsimMeasurements, LaserAndProbeReadingsWithTheirTrueValues) {
  SimConfig c = quiet_config();
  c.effects.wear.enabled = true;
  c.effects.wear.rate_um_per_m = 1000.0;  // 1 µm per mm
  c.effects.laser_noise.enabled = true;
  c.effects.laser_noise.sigma_um = 0.8;
  c.mould_face.measure_interval_mm = 12.0;
  c.mould_face.laser_trip_s = 1.0;
  Simulation sim(c, ProgramKind::kMouldFace, kKnown);
  std::vector<double> published;
  for (int k = 1; k <= 10000 && !sim.done(); ++k) {
    sim.advance_to(core::from_seconds(0.001 * k));
    for (const auto& e : sim.take_events()) {
      if (const auto* tm = std::get_if<core::ToolMeasurement>(&e)) {
        published.push_back(tm->wear_um[0]);
      }
    }
  }
  const auto& m = sim.results().measurements;
  ASSERT_EQ(m.size(), 2U);
  ASSERT_EQ(published.size(), 2U);
  for (std::size_t i = 0; i < 2; ++i) {
    EXPECT_EQ(m[i].kind, MeasurementKind::kLaser);
    EXPECT_EQ(m[i].part, 1);
    EXPECT_EQ(m[i].checkpoint, -1);
    EXPECT_NEAR(m[i].cut_path_mm, 12.0 * static_cast<double>(i + 1), 0.051);
    EXPECT_DOUBLE_EQ(m[i].true_um, m[i].cut_path_mm);  // 1 µm per mm from a new tool
    EXPECT_DOUBLE_EQ(m[i].reading_um, published[i]);
    EXPECT_GT(std::fabs(m[i].reading_um - m[i].true_um), 1e-6);  // the laser's noise
    EXPECT_LT(std::fabs(m[i].reading_um - m[i].true_um), 4.0);   // 5 σ
    EXPECT_FALSE(m[i].broken);
  }
  // Half-way through the 1 s trips, at 10 mm/s: 12 mm of cut + 1 mm of link (1.3 s) + 0.5 s;
  // then the rest of the trip, 12 mm of cut + 1 mm of link again, + 0.5 s.
  EXPECT_NEAR(m[0].t_s, 1.8, 0.011);
  EXPECT_NEAR(m[1].t_s, 1.8 + 0.5 + 1.3 + 0.5, 0.011);

  SimConfig w = wall_config();
  w.effects.pushoff.enabled = true;
  w.effects.probe_noise.enabled = true;
  w.effects.probe_outlier = {true, 2, 1, 400.0};
  Simulation s2(w, ProgramKind::kSideWall, kKnown);
  s2.advance_to(core::from_seconds(1000.0));
  const auto& cps = s2.results().checkpoints;
  const auto& pm = s2.results().measurements;
  ASSERT_EQ(pm.size(), cps.size());
  ASSERT_EQ(pm.size(), 8U);
  const double delta0 = (2.0 / std::cos(3.0 * std::numbers::pi / 180.0) - 2.0) * 1000.0;
  for (std::size_t i = 0; i < pm.size(); ++i) {
    EXPECT_EQ(pm[i].kind, MeasurementKind::kProbe);
    EXPECT_EQ(pm[i].part, cps[i].part);
    EXPECT_EQ(pm[i].checkpoint, cps[i].checkpoint);
    EXPECT_DOUBLE_EQ(pm[i].true_um, cps[i].error_um + delta0);
    EXPECT_DOUBLE_EQ(pm[i].reading_um, cps[i].probed_um);
    const double outlier = (pm[i].part == 2 && pm[i].checkpoint == 1) ? 400.0 : 0.0;
    EXPECT_LT(std::fabs(pm[i].reading_um - pm[i].true_um - outlier), 2.5);  // 5 σ of 0.5 µm
    // Probed after both levels of 40 mm: the tool has 80 mm per part behind it.
    EXPECT_NEAR(pm[i].cut_path_mm, 80.0 * pm[i].part, 1e-9);
  }
}

// An alarm register counts each rise from 0 to a non-zero value once (the daemon re-sends a raised
// flag every refresh interval); other registers and refused writes count nothing.
TEST(NcsimAlarms, OneAlarmPerRiseOfAnAlarmRegister) {
  SimConfig c = quiet_config();
  c.nc.alarm_registers = {9};
  const std::vector<std::uint16_t> known{0, 1, 2, 3, 4, 5, 6, 7, 8, 9};
  Simulation sim(c, ProgramKind::kMouldFace, known);
  ASSERT_EQ(sim.write_offset(0.1, 9, 0.0), WriteResult::kAccepted);
  EXPECT_EQ(sim.alarms_seen(), 0);
  ASSERT_EQ(sim.write_offset(0.2, 9, 1.0), WriteResult::kAccepted);
  ASSERT_EQ(sim.write_offset(1.2, 9, 1.0), WriteResult::kAccepted);  // refresh
  ASSERT_EQ(sim.write_offset(1.3, 1, 5.0), WriteResult::kAccepted);  // not an alarm register
  ASSERT_EQ(sim.write_offset(1.4, 9, 900.0), WriteResult::kOutOfRange);
  EXPECT_EQ(sim.alarms_seen(), 1);
  ASSERT_EQ(sim.write_offset(2.0, 9, 0.0), WriteResult::kAccepted);
  ASSERT_EQ(sim.write_offset(3.0, 9, 2.0), WriteResult::kAccepted);
  EXPECT_EQ(sim.alarms_seen(), 2);
  const auto& a = sim.results().alarms;
  ASSERT_EQ(a.size(), 2U);
  EXPECT_DOUBLE_EQ(a[0].t_s, 0.2);
  EXPECT_EQ(a[0].register_index, 9);
  EXPECT_DOUBLE_EQ(a[0].value, 1.0);
  EXPECT_DOUBLE_EQ(a[1].t_s, 3.0);
  EXPECT_DOUBLE_EQ(a[1].value, 2.0);
}

// A run continued from another one's end state (first part, the tool's cut path) machines the
// same parts as one longer run: the worn tool stays worn, the part numbers go on.
TEST(NcsimContinue, TwoRunsMachineWhatOneLongRunMachines) {
  SimConfig c = wall_config();
  c.effects.wear.enabled = true;
  c.effects.wear.rate_um_per_m = 50.0;
  c.effects.pushoff.enabled = true;
  c.effects.hardness.enabled = true;
  c.effects.hardness.per_part = true;
  c.parts = 4;
  Simulation whole(c, ProgramKind::kSideWall, kKnown);
  whole.advance_to(core::from_seconds(1000.0));
  ASSERT_TRUE(whole.done());
  EXPECT_EQ(whole.end_state().next_part, 5);

  c.parts = 2;
  Simulation first(c, ProgramKind::kSideWall, kKnown);
  first.advance_to(core::from_seconds(1000.0));
  ASSERT_TRUE(first.done());
  const EndState end = first.end_state();
  ASSERT_TRUE(end.valid);
  EXPECT_EQ(end.next_part, 3);
  EXPECT_NEAR(end.tool_cut_path_mm, 2 * 80.0, 1e-9);
  c.first_part = end.next_part;
  c.tool_cut_path_mm = end.tool_cut_path_mm;
  Simulation second(c, ProgramKind::kSideWall, kKnown);
  second.advance_to(core::from_seconds(1000.0));
  ASSERT_TRUE(second.done());
  EXPECT_EQ(second.end_state().next_part, 5);
  EXPECT_NEAR(second.end_state().tool_cut_path_mm, 4 * 80.0, 1e-9);

  std::vector<WallRow> later;
  for (const WallRow& w : whole.results().walls) {
    if (w.part >= 3) {
      later.push_back(w);
    }
  }
  const auto& cont = second.results().walls;
  ASSERT_EQ(cont.size(), later.size());
  ASSERT_FALSE(cont.empty());
  EXPECT_EQ(cont.front().part, 3);
  EXPECT_EQ(cont.back().part, 4);
  for (std::size_t i = 0; i < cont.size(); ++i) {
    EXPECT_EQ(cont[i].part, later[i].part);
    EXPECT_DOUBLE_EQ(cont[i].s_mm, later[i].s_mm);
    EXPECT_DOUBLE_EQ(cont[i].error_um, later[i].error_um);
  }
  // Wear 50 µm/m over 160 mm before part 3: its first sample is 8 µm worse than part 1's.
  EXPECT_GT(cont.front().error_um, first.results().walls.front().error_um + 7.0);
  // The first part of the continued run gets the tool change (the tool in the spindle) and a
  // part start with its number.
  std::vector<core::Event> ev;
  Simulation third(c, ProgramKind::kSideWall, kKnown);
  third.advance_to(core::from_seconds(0.01));
  ev = third.take_events();
  ASSERT_GE(ev.size(), 2U);
  EXPECT_TRUE(std::holds_alternative<core::ToolChange>(ev[0]));
  EXPECT_EQ(std::get<core::ProgramEvent>(ev[1]).part, 3);

  // The mould face: the laser's first reading continues the tool's wear.
  SimConfig m = quiet_config();
  m.effects.wear.enabled = true;
  m.effects.wear.rate_um_per_m = 1000.0;
  m.mould_face.measure_interval_mm = 12.0;
  m.mould_face.laser_trip_s = 0.2;
  m.first_part = 7;
  m.tool_cut_path_mm = 500.0;
  Simulation face(m, ProgramKind::kMouldFace, kKnown);
  face.advance_to(core::from_seconds(100.0));
  ASSERT_FALSE(face.results().measurements.empty());
  EXPECT_EQ(face.results().measurements[0].part, 7);
  EXPECT_NEAR(face.results().measurements[0].true_um, 512.0, 0.051);
  EXPECT_EQ(face.end_state().next_part, 8);
}

// The side wall's approach: an offset the daemon writes at the part start is in force before the
// first cut (the NC's latency is shorter than the approach).
TEST(NcsimSideWall, ApproachBeforeTheFirstCut) {
  for (const double approach_s : {0.5, 0.0}) {
    SimConfig c = wall_config();
    c.parts = 1;
    c.side_wall.approach_s = approach_s;
    Simulation sim(c, ProgramKind::kSideWall, kKnown);
    ASSERT_EQ(sim.write_offset(0.0, 1, 3.0), WriteResult::kAccepted);  // in force at 0.1 s
    sim.advance_to(core::from_seconds(1000.0));
    const auto& walls = sim.results().walls;
    ASSERT_FALSE(walls.empty());
    EXPECT_NEAR(walls.front().offset_um, approach_s > 0.0 ? -3.0 : 0.0, 1e-12) << approach_s;
  }
}

}  // namespace
}  // namespace nccomp::sim::ncsim
