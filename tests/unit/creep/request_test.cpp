// The "measurement due" request (item 4 of issue 3) after a measurement that is refused (item 5:
// broken or mis-measured → alarm, nothing applied; excessive, beyond the limit, invalid): every
// laser measurement answers the request, so its flag falls; a refused one is asked for again one
// interval later, never while halted, at once after the operator's acknowledgement. The flag
// register's value sequence is checked write by write, and against an NC that measures whenever
// the flag is 1 (it reacts to the level, not to the rising edge).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <memory>
#include <vector>

#include "tests/unit/creep/rig.hpp"

namespace nccomp::core::creep {
namespace {

using testing::base_config;
using testing::Rig;

constexpr std::uint16_t kRequest = 12;  // base_config's measurement_due_register
constexpr std::uint16_t kAlarm = 11;

/// Every value written to the request register, in order.
std::vector<double> request_writes(const Rig& r) {
  std::vector<double> v;
  for (const auto& w : r.writes) {
    if (w.register_index == kRequest) v.push_back(w.value_um);
  }
  return v;
}

/// The value of the request register the NC holds now (0 before any write).
double request_level(const Rig& r) {
  const double v = r.last_write(kRequest);
  return std::isnan(v) ? 0.0 : v;
}

CreepConfig interval_config() {
  auto c = base_config();
  c.interval.basis = IntervalBasis::kPath;
  c.interval.interval_mm = 100.0;
  c.tool_life.noise_um = 2.0;
  c.tool_life.implausible_factor = 5.0;
  c.tool_life.min_expected_increment_um = 10.0;
  return c;
}

TEST(CreepRequest, ABrokenMeasurementLowersTheFlagWhichStaysLowWhileHalted) {
  Rig r(interval_config());
  r.run_to(100.0);
  EXPECT_EQ(request_writes(r), (std::vector<double>{0.0, 1.0}));
  r.measure({5.0});  // accepted
  r.run_to(200.0);
  EXPECT_EQ(request_writes(r), (std::vector<double>{0.0, 1.0, 0.0, 1.0}));
  r.measure({6.0}, /*broken=*/true);
  EXPECT_TRUE(r.comp.halted());
  EXPECT_EQ(r.count(AlarmCode::kToolBrokenOrMismeasured), 1U);
  EXPECT_NEAR(r.last_write(kAlarm), 1.0, 0.0);
  // The flag fell in the cycle of the broken measurement (it used to be raised again in that
  // same cycle: the cut path since the last accepted measurement is past the interval).
  EXPECT_EQ(request_writes(r), (std::vector<double>{0.0, 1.0, 0.0, 1.0, 0.0}));
  r.run_to(700.0);  // five intervals later, still halted: nothing asked, nothing applied
  EXPECT_EQ(request_writes(r), (std::vector<double>{0.0, 1.0, 0.0, 1.0, 0.0}));
  EXPECT_EQ(r.count(AlarmCode::kMeasurementDue), 2U);
  EXPECT_TRUE(std::isinf(r.comp.next_measurement_path_mm()));
  EXPECT_NEAR(r.z(), -5.0, 1e-9);
  // The operator acknowledges: the overdue measurement is asked for once, in the next cycle.
  r.comp.clear_alarm();
  r.advance(0.5);
  EXPECT_EQ(request_writes(r), (std::vector<double>{0.0, 1.0, 0.0, 1.0, 0.0, 1.0}));
  EXPECT_EQ(r.count(AlarmCode::kMeasurementDue), 3U);
  r.advance(0.5);
  EXPECT_EQ(request_writes(r).size(), 6U);  // a level, not a pulse train
  r.measure({11.0});                        // the re-measurement, accepted at 701 mm
  EXPECT_FALSE(r.comp.halted());
  EXPECT_EQ(request_writes(r), (std::vector<double>{0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0}));
  EXPECT_NEAR(r.comp.next_measurement_path_mm(), 801.0, 1e-9);
  r.run_to(800.5);
  EXPECT_EQ(request_writes(r).size(), 7U);
  r.run_to(801.0);
  EXPECT_EQ(request_writes(r), (std::vector<double>{0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0}));
}

/// An NC that sends the tool to the laser in every cycle in which it sees the request at 1; the
/// laser reads `reading(path)`. Returns the cut paths at which it measured.
template <class Reading>
std::vector<double> level_nc(Rig& r, double to_mm, Reading reading) {
  std::vector<double> trips;
  while (r.program_path_mm < to_mm - 1e-9) {
    r.advance(0.5);
    if (request_level(r) > 0.5) {
      trips.push_back(r.comp.cut_path_mm());
      reading(r);
    }
  }
  return trips;
}

TEST(CreepRequest, AnNcReactingToTheLevelMeasuresOnceMoreAfterABrokenToolNotAgainAndAgain) {
  // 0.02 µm/mm of wear until the tool breaks at 250 mm; the laser says broken from then on.
  Rig r(interval_config());
  const auto trips = level_nc(r, 1000.0, [](Rig& rig) {
    const double p = rig.comp.cut_path_mm();
    rig.measure({0.02 * p}, /*broken=*/p > 250.0);
  });
  // 100 and 200 accepted, 300 broken → halted: 3 trips in 1000 mm (the old flag stayed at 1
  // after the broken measurement: this NC would have measured in each of the 1400 cycles left).
  EXPECT_EQ(trips, (std::vector<double>{100.0, 200.0, 300.0}));
  EXPECT_EQ(request_writes(r), (std::vector<double>{0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0}));
  EXPECT_EQ(r.count(AlarmCode::kToolBrokenOrMismeasured), 1U);
  EXPECT_EQ(r.comp.counters().measurements_accepted, 2U);
  EXPECT_EQ(r.comp.counters().measurements_refused, 1U);
}

TEST(CreepRequest, ARefusalThatDoesNotHaltIsAskedForAgainOneIntervalLater) {
  // Four refusals that do not halt; each time the request falls and rises one interval (100 mm
  // of cut path) after the refused measurement, so a level-reacting NC measures at the normal
  // rate and an edge-reacting one sees a rise for every request.
  struct Case {
    const char* what;
    AlarmCode code;
  };
  const Case cases[] = {
      {"excessive increment, continue with the sister", AlarmCode::kToolExcessivelyWorn},
      {"beyond the limiter's absolute bound", AlarmCode::kOffsetBeyondAbsoluteLimit},
      {"wrong number of support points", AlarmCode::kEventInvalid},
      {"another tool", AlarmCode::kEventInvalid}};
  for (std::size_t k = 0; k < std::size(cases); ++k) {
    SCOPED_TRACE(cases[k].what);
    auto c = interval_config();
    c.tool_life.excessive_increment_um = 15.0;
    c.tool_life.on_excessive = ExcessivePolicy::kSister;
    c.tool_life.min_expected_increment_um = 100.0;  // 20 µm jumps are plausible here
    c.limiter.max_abs_um = 15.0;
    Rig r(c);
    const auto trips = level_nc(r, 650.0, [k](Rig& rig) {
      if (rig.comp.cut_path_mm() < 150.0) {
        rig.measure({5.0});  // the first one accepted
        return;
      }
      switch (k) {
        case 0:
          rig.measure({25.0});  // +20 µm > 15
          break;
        case 1:
          rig.measure({16.0});  // beyond 15 µm absolute
          break;
        case 2:
          rig.measure({6.0, 6.0});  // two points, the config has one
          break;
        default: {
          ToolMeasurement m;
          m.time_ns = rig.now_ns;
          m.tool = 9;  // the spindle holds tool 1
          m.wear_um[0] = 6.0;
          rig.events.emplace_back(m);
          rig.step();
        }
      }
    });
    EXPECT_EQ(trips, (std::vector<double>{100.0, 200.0, 300.0, 400.0, 500.0, 600.0}));
    EXPECT_EQ(request_writes(r), (std::vector<double>{0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0,
                                                      1.0, 0.0, 1.0, 0.0}));
    EXPECT_FALSE(r.comp.halted());
    EXPECT_EQ(r.count(cases[k].code), 5U);
    EXPECT_EQ(r.comp.counters().measurements_accepted, 1U);
    EXPECT_NEAR(r.z(), -5.0, 1e-9);  // none of the refused values applied
    EXPECT_NEAR(r.comp.next_measurement_path_mm(), 700.0, 1e-9);
  }
}

TEST(CreepRequest, TheHoldAfterARefusalCountsOnTheIntervalsOwnClock) {
  {  // cutting time: every 60 s; refused at 120.2 s → asked again 60 s later
    auto c = interval_config();
    c.interval.basis = IntervalBasis::kTime;
    c.interval.interval_s = 60.0;
    Rig r(c);
    for (int i = 0; i < 6010; ++i) r.advance(0.1, 0.01);
    EXPECT_NEAR(request_level(r), 1.0, 0.0);
    r.measure({5.0});  // accepted at 60.101 s of cutting
    for (int i = 0; i < 6010; ++i) r.advance(0.1, 0.01);
    EXPECT_NEAR(request_level(r), 1.0, 0.0);
    r.measure({5.0, 5.0});  // refused at 120.202 s: wrong number of points
    EXPECT_NEAR(request_level(r), 0.0, 0.0);
    for (int i = 0; i < 5990; ++i) r.advance(0.1, 0.01);  // 59.9 s
    EXPECT_NEAR(request_level(r), 0.0, 0.0);
    for (int i = 0; i < 20; ++i) r.advance(0.1, 0.01);
    EXPECT_NEAR(request_level(r), 1.0, 0.0);
    EXPECT_EQ(request_writes(r), (std::vector<double>{0.0, 1.0, 0.0, 1.0, 0.0, 1.0}));
  }
  {  // material: 50 mm³ at 0.5 mm² = 100 mm of path
    auto c = interval_config();
    c.interval.basis = IntervalBasis::kMaterial;
    c.interval.interval_mm3 = 50.0;
    c.interval.removal_mm3_per_mm = 0.5;
    Rig r(c);
    r.run_to(100.0);
    r.measure({5.0});
    r.run_to(200.0);
    r.measure({5.0, 5.0});  // refused at 100 mm³
    EXPECT_NEAR(r.comp.next_measurement_removed_mm3(), 150.0, 1e-9);
    EXPECT_NEAR(r.comp.next_measurement_path_mm(), 300.0, 1e-9);
    r.run_to(299.5);
    EXPECT_NEAR(request_level(r), 0.0, 0.0);
    r.run_to(300.0);
    EXPECT_NEAR(request_level(r), 1.0, 0.0);
  }
}

TEST(CreepRequest, TheHoldSurvivesARestart) {
  auto c = interval_config();
  Rig r(c);
  r.run_to(100.0);
  r.measure({5.0});
  r.run_to(200.0);
  r.measure({5.0, 5.0});  // refused at 200 mm: asked again at 300 mm
  const CreepState saved = r.comp.export_state();
  EXPECT_TRUE(saved.request_held);
  EXPECT_NEAR(saved.refused_cut_path_mm, 200.0, 1e-9);
  Rig b(c);
  b.comp.import_state(saved);
  b.program_path_mm = r.program_path_mm;
  b.sample();
  b.run_to(299.5);
  EXPECT_NEAR(request_level(b), 0.0, 0.0);
  b.run_to(300.0);
  EXPECT_NEAR(request_level(b), 1.0, 0.0);
  // A halted state stays quiet after a restart too.
  Rig h(c);
  h.run_to(100.0);
  h.measure({5.0}, /*broken=*/true);
  Rig h2(c);
  h2.comp.import_state(h.comp.export_state());
  h2.program_path_mm = h.program_path_mm;
  h2.sample();
  h2.run_to(500.0);
  EXPECT_TRUE(h2.comp.halted());
  EXPECT_NEAR(request_level(h2), 0.0, 0.0);
}

// A request restored high at start-up (nccompd stopped while it was up, the NC still holds it,
// and its answer may have been lost): rearm_request() (the daemon's creep start-up hook) writes
// the register 0 for request_rearm_s and 1 again, so that an NC that reacts to the rising edge
// sees one; a measurement that arrives meanwhile answers the request and ends it. Without
// rearm_request() (the NC reads 0) or with request_rearm_s = 0 the register is written 1 at once.
TEST(CreepRequest, ARequestRestoredHighIsLoweredForRequestRearmSAndRaisedAgain) {
  auto c = interval_config();
  c.output.request_rearm_s = 1.0;
  Rig before(c);
  before.run_to(100.0);
  ASSERT_NEAR(request_level(before), 1.0, 0.0);
  const CreepState saved = before.comp.export_state();
  ASSERT_TRUE(saved.measurement_due_flag);

  const auto restart = [&](const CreepConfig& config, bool rearm) {
    auto r = std::make_unique<Rig>(config);
    r->comp.import_state(saved);
    r->program_path_mm = before.program_path_mm;
    r->writes.clear();
    if (rearm) r->comp.rearm_request();
    return r;
  };

  // Re-armed: 0 from the first step, for 1 s (100 steps of 10 ms from the first), then 1.
  auto r = restart(c, true);
  EXPECT_TRUE(r->comp.rearming());
  r->advance(0.01);
  EXPECT_EQ(request_writes(*r), (std::vector<double>{0.0}));
  for (int k = 1; k < 100; ++k) r->advance(0.01);
  EXPECT_EQ(request_writes(*r), (std::vector<double>{0.0}));
  EXPECT_TRUE(r->comp.rearming());
  r->advance(0.01);
  EXPECT_EQ(request_writes(*r), (std::vector<double>{0.0, 1.0}));
  EXPECT_FALSE(r->comp.rearming());
  EXPECT_TRUE(r->comp.state().measurement_due_flag);    // the state never changed
  EXPECT_EQ(r->count(AlarmCode::kMeasurementDue), 0U);  // not a new request

  // The measurement arrives while the register is held low: it answers the request, which
  // then stays low until the next interval is used up.
  auto m = restart(c, true);
  for (int k = 0; k < 30; ++k) m->advance(0.01);
  m->measure({5.0});
  EXPECT_FALSE(m->comp.state().measurement_due_flag);
  EXPECT_FALSE(m->comp.rearming());
  for (int k = 0; k < 200; ++k) m->advance(0.01);
  EXPECT_EQ(request_writes(*m), (std::vector<double>{0.0}));
  EXPECT_EQ(m->comp.counters().measurements_accepted, 1U);

  // Not re-armed, or request_rearm_s = 0: the restored request is written 1 at once.
  auto plain = restart(c, false);
  plain->advance(0.01);
  EXPECT_EQ(request_writes(*plain), (std::vector<double>{1.0}));
  auto off_config = c;
  off_config.output.request_rearm_s = 0.0;
  auto off = restart(off_config, true);
  EXPECT_FALSE(off->comp.rearming());
  off->advance(0.01);
  EXPECT_EQ(request_writes(*off), (std::vector<double>{1.0}));

  // A request that is low is not re-armed.
  Rig low(c);
  low.run_to(50.0);
  low.comp.rearm_request();
  EXPECT_FALSE(low.comp.rearming());
}

}  // namespace
}  // namespace nccomp::core::creep
