// Arbitrary event streams into CheckpointCompensator::step: no crash, no UB, offsets always
// finite and inside the limiter's absolute limit.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <vector>

#include "core/checkpoint/compensator.hpp"
#include "core/checkpoint/plan.hpp"

namespace {

namespace cp = nccomp::core::checkpoint;
using namespace nccomp::core;

double take_double(const std::uint8_t*& p, const std::uint8_t* end) {
  double v = 0.0;
  if (end - p >= 8) {
    std::memcpy(&v, p, 8);
    p += 8;
  } else if (p < end) {
    v = static_cast<double>(*p++) - 128.0;
  }
  return v;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static cp::CheckpointCompensator* comp = nullptr;
  static LimiterConfig limits{};
  if (comp == nullptr) {
    comp = new cp::CheckpointCompensator();
  }
  // Plans: six points on one open pass, or a closed 40 × 20 rectangle on three levels (seams and
  // level links), or the same rectangle open.
  static const std::vector<cp::Checkpoint> line = [] {
    std::vector<cp::Checkpoint> plan;
    for (int i = 0; i < 6; ++i) {
      cp::Checkpoint c;
      c.id = i;
      c.path_mm = 10.0 * (i + 1);
      c.s_mm = c.path_mm;
      c.tool_x_mm = c.path_mm;
      c.z_mm = -5.0;
      plan.push_back(c);
    }
    return plan;
  }();
  const auto rect = [](bool closed) {
    cp::PlanConfig c;
    c.contour = {{0, 0}, {40, 0}, {40, 20}, {0, 20}};
    c.closed = closed;
    c.material = closed ? cp::MaterialSide::kInside : cp::MaterialSide::kLeft;
    c.z_start_mm = -2.0;
    c.z_end_mm = -12.0;
    c.corner_offset_mm = 3.0;
    return cp::make_plan(c).checkpoints;
  };
  static const std::vector<cp::Checkpoint> closed_rect = rect(true);
  static const std::vector<cp::Checkpoint> open_rect = rect(false);
  cp::CompensatorConfig cfg;
  cfg.active_register = 3;
  cfg.apply = cp::ApplyMode::kCreep;
  cfg.finishing_tool = 1;
  const std::vector<cp::Checkpoint>* plan = &line;
  const std::uint8_t* p = data;
  const std::uint8_t* end = data + size;
  if (p < end) {
    const std::uint8_t mode = *p++;
    cfg.apply = (mode & 1) ? cp::ApplyMode::kStep : cp::ApplyMode::kCreep;
    cfg.trigger = (mode & 2) ? cp::TriggerMode::kPosition : cp::TriggerMode::kPath;
    cfg.learning_mode =
        (mode & 4) ? cp::LearningMode::kSemiFinishing : cp::LearningMode::kPreviousPart;
    if (mode & 8) {
      plan = (mode & 16) ? &open_rect : &closed_rect;
    }
    if (mode & 32) {
      cfg.apply = cp::ApplyMode::kTable;
      cfg.active_register = -1;
    }
  }
  comp->configure(cfg, *plan, limits);
  StepOutput out;
  std::vector<Event> events;
  // The live target is always one of the table's values or between two of them: of the table as
  // it is or as it was (it is recomputed only at the finishing tool's next sample, so after a
  // probe it may still show an older table's value). lo / hi: every table value of this input
  // so far [µm]; a probe or a part start (which change the table) ends its cycle, so no table
  // goes unseen.
  double lo = 0.0;
  double hi = 0.0;
  const auto widen = [&] {
    for (std::size_t i = 0; i < comp->size(); ++i) {
      lo = std::min(lo, comp->register_value_um(i));
      hi = std::max(hi, comp->register_value_um(i));
    }
  };
  widen();
  const auto step = [&] {
    out.clear();
    comp->step(static_cast<TimeNs>(p - data) * 1000, events, out);
    events.clear();
    for (const OffsetWrite& w : out.writes) {
      if (!std::isfinite(w.value_um) || std::fabs(w.value_um) > limits.max_abs_um) {
        __builtin_trap();
      }
    }
    widen();
    const double target = comp->live_target_um();
    if (std::isfinite(target) && (target < lo - 1e-9 || target > hi + 1e-9)) {
      __builtin_trap();
    }
  };
  while (p < end) {
    const std::uint8_t kind = *p++;
    switch (kind % 5) {
      case 0: {
        AxisSample s;
        s.tool = (kind & 0x80) ? 1 : 2;
        s.position_mm[0] = take_double(p, end);
        s.position_mm[1] = take_double(p, end);
        s.position_mm[2] = take_double(p, end);
        s.program_path_mm = take_double(p, end);
        events.emplace_back(s);
        break;
      }
      case 1: {
        ProbeMeasurement m;
        m.checkpoint = (p < end) ? static_cast<std::int8_t>(*p++) : 0;
        m.raw_deviation_um = take_double(p, end);
        m.wall_angle_deg = take_double(p, end);
        m.ball_radius_mm = take_double(p, end);
        events.emplace_back(m);
        step();
        break;
      }
      case 2:
        events.emplace_back(ProgramEvent{0, ProgramEventKind::kPartStart, 1});
        step();
        break;
      case 3:
        events.emplace_back(ToolChange{0, (kind & 0x80) ? 1 : 2, false});
        break;
      default:
        step();
    }
  }
  out.clear();
  comp->step(0, events, out);
  return 0;
}
