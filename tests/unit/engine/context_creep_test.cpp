// GIVEN the same stream of axis samples, tool changes (another tool, one coming back, a sister,
// one only the axis samples name) and interruptions WHEN the engine's machine context and the
// creep module (S0) both follow it THEN both count the same cut path for the tool in the spindle
// after every cycle: the log's path_mm, the model's path_mm and creep's wear clock agree.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "core/creep/wear_compensator.hpp"
#include "core/engine/context.hpp"

namespace nccomp::core::engine {
namespace {

AxisSample sample(double x, double y, std::int32_t tool, bool cutting = true,
                  double program_path_mm = kNaN) {
  AxisSample a;
  a.position_mm = {x, y, 0.0, 0.0, 0.0, 0.0};
  a.tool = tool;
  a.cutting = cutting;
  a.program_path_mm = program_path_mm;
  return a;
}

// A creep configuration that only counts (axis mode on three registers, no limits in the way).
creep::CreepConfig counting_creep() {
  creep::CreepConfig c;
  c.edge.tool_shape = creep::ToolShape::kTip;
  c.edge.edge_points = 1;
  c.edge.normal_source = creep::NormalSource::kNone;
  c.edge.fallback_channel = creep::Channel::kZ;
  c.edge.fallback_sign = -1.0;
  c.output.mode = creep::OutputMode::kAxes;
  c.output.channel_register = {0, 1, 2, -1, -1};
  c.limiter = {500.0, 1000.0, 1e7};
  return c;
}

TEST(MachineContextPath, CountsEveryToolLikeTheCreepModule) {
  creep::WearCompensator creep;
  creep.configure(counting_creep());
  MachineContext ctx;
  StepOutput out;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  TimeNs t = 0;
  double x = 0.0;
  double prog = 0.0;
  std::int32_t tool = 1;
  bool interrupted = false;
  std::vector<double> diffs;
  auto step = [&](std::vector<Event> ev) {
    t += 10'000'000;
    out.clear();
    creep.step(t, ev, out);
    ctx.update(t, ev);
    EXPECT_EQ(ctx.tool(), creep.state().tool) << t;
    EXPECT_NEAR(ctx.cut_path_mm(), creep.cut_path_mm(), 1e-9) << "at " << t;
  };
  step({ToolChange{t, 1, false}, sample(x, 0.0, 1)});
  // 2000 cycles: cutting runs with and without the program path, rapids, interruptions, tool
  // changes (another tool, the first one back, a sister, one the axis sample names alone).
  for (int k = 0; k < 2000; ++k) {
    std::vector<Event> ev;
    const double r = uni(rng);
    if (k % 400 == 399) {
      const std::int32_t next = k == 799 ? 1 : (k == 1599 ? tool + 10 : tool + 1);
      const bool sister = k == 1199;
      if (k == 1599) {
        tool = next;  // no event: the axis samples name the new tool
      } else {
        ev.emplace_back(ToolChange{t, next, sister});
        tool = next;
      }
    } else if (r < 0.01 && !interrupted) {
      ev.emplace_back(ProgramEvent{t, ProgramEventKind::kInterruption, 1});
      interrupted = true;
    } else if (r < 0.03 && interrupted) {
      ev.emplace_back(ProgramEvent{t, ProgramEventKind::kResume, 1});
      interrupted = false;
    }
    const bool cutting = (k / 50) % 4 != 3;  // every fourth block of 50 cycles a rapid
    x += 0.5 + uni(rng);
    prog += 0.7;
    const bool publish = (k / 100) % 2 == 0;  // the NC publishes the program path or not
    ev.emplace_back(sample(x, 0.3 * x, tool, cutting, publish ? prog : kNaN));
    step(ev);
  }
  // The numbers are not trivial: tool 12 (named by the axis samples alone at cycle 1599) cut
  // more than 100 mm before tool 13 came in at cycle 1999 (a fresh tool, 0 mm); tool 2, the
  // sister of cycle 1199, too.
  EXPECT_EQ(ctx.tool(), 13);
  EXPECT_DOUBLE_EQ(ctx.cut_path_mm(), 0.0);
  EXPECT_GT(ctx.cut_path_mm(12), 100.0);
  EXPECT_GT(ctx.cut_path_mm(2), 100.0);
}

}  // namespace
}  // namespace nccomp::core::engine
