// Fuzz target: arbitrary event streams (what a broken or hostile NC, laser or PLC can send) and
// arbitrary persisted state bytes into the real-time path. Invariants: no crash or sanitizer
// report; every offset write finite and within the absolute limit; flags 0 or 1.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <vector>

#include "core/common/output.hpp"
#include "core/creep/wear_compensator.hpp"

using namespace nccomp::core;
using namespace nccomp::core::creep;

namespace {

struct Reader {
  const std::uint8_t* p;
  std::size_t n;
  std::uint8_t byte() {
    if (n == 0) return 0;
    --n;
    return *p++;
  }
  double value() {
    // Mostly small numbers, sometimes the awkward ones.
    const std::uint8_t k = byte();
    switch (k % 16) {
      case 0:
        return std::numeric_limits<double>::quiet_NaN();
      case 1:
        return std::numeric_limits<double>::infinity();
      case 2:
        return -1e300;
      case 3: {
        double d = 0.0;
        std::uint8_t b[8];
        for (auto& x : b) x = byte();
        std::memcpy(&d, b, sizeof d);
        return d;
      }
      default:
        return (static_cast<double>(byte()) - 64.0) * 0.5 + static_cast<double>(k) * 0.01;
    }
  }
};

void check(const StepOutput& out, const CreepConfig& c) {
  for (const auto& w : out.writes) {
    if (!std::isfinite(w.value_um)) std::abort();
    if (w.register_index < 3 && std::fabs(w.value_um) > c.limiter.max_abs_um) std::abort();
    if (w.register_index >= 10 && w.register_index <= 13 &&
        !(std::fabs(w.value_um) < 1e-12 || std::fabs(w.value_um - 1.0) < 1e-12)) {
      std::abort();
    }
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  Reader r{data, size};
  CreepConfig c;
  const std::uint8_t mode = r.byte();
  c.creep_basis = static_cast<CreepBasis>(mode % 4);
  c.profile = static_cast<ProfileShape>((mode / 4) % 5);
  if (c.profile == ProfileShape::kTable) c.profile_table = {0.0, 0.3, 1.0};
  c.on_unfinished = static_cast<UnfinishedPolicy>((mode / 32) % 3);
  c.edge.tool_shape = ToolShape::kBall;
  c.edge.edge_points = 1 + r.byte() % kMaxEdgePoints;
  c.edge.normal_source = NormalSource::kAxisSample;
  c.output.channel_register = {0, 1, 2, -1, -1};
  c.output.warning_register = 10;
  c.output.alarm_register = 11;
  c.output.measurement_due_register = 12;
  c.output.tool_change_register = 13;
  const std::uint8_t iv = r.byte();
  c.interval.basis = static_cast<IntervalBasis>(iv % 5);
  // Without a normal: the lateral deflection across the feed direction, toward either side.
  c.edge.material_side = static_cast<MaterialSide>((iv / 8) % 3);
  c.predict.enabled = (mode & 1) != 0;
  // The wear estimator (gate 3σ, so that the gate's refusals are reached too).
  c.estimator.enabled = (iv & 0x80) != 0;
  c.estimator.gate_sigmas = 3.0;
  c.entry.sister_offset_um = 5.0;
  c.entry.retract_um = (mode & 2) != 0 ? 3.0 : 0.0;
  c.tool_life.wear_limit_um = 100.0;
  c.tool_life.excessive_increment_um = 40.0;
  c.deflection = {{0, {0.0, 50.0}, {0.0, 5.0}, {0.0, 2.0}}};
  c.transitions = {{2, 10.0, 50.0, 5.0, 10.0, 5.0, 10.0}};
  c.creep_length_mm = 5.0;
  c.creep_time_s = 1.0;
  WearCompensator w;
  w.configure(c);

  // Sometimes start from arbitrary state bytes, as a corrupt state file would give.
  if (r.byte() % 4 == 0 && r.n >= sizeof(CreepState)) {
    const auto* bytes = reinterpret_cast<const std::byte*>(r.p);
    if (state_bytes_loadable(bytes, sizeof(CreepState))) {
      CreepState s;
      std::memcpy(&s, bytes, sizeof s);
      (void)w.restore_state(s);
    }
    r.p += sizeof(CreepState);
    r.n -= sizeof(CreepState);
  }

  StepOutput out;
  std::vector<Event> ev;
  TimeNs now = 0;
  while (r.n > 0) {
    ev.clear();
    const std::uint8_t count = r.byte() % 4;
    for (std::uint8_t i = 0; i < count; ++i) {
      switch (r.byte() % 5) {
        case 0:
        case 1: {
          AxisSample a;
          a.program_path_mm = r.value();
          a.position_mm = {r.value(), r.value(), r.value(), 0.0, 0.0, 0.0};
          a.axis_count = static_cast<std::uint8_t>(r.byte() % 7);
          a.has_normal = (r.byte() & 1) != 0;
          a.normal = {r.value(), r.value(), r.value()};
          a.cutting = (r.byte() & 3) != 0;
          a.tool = r.byte() % 3;
          ev.emplace_back(a);
          break;
        }
        case 2: {
          ToolMeasurement m;
          m.tool = r.byte() % 3;
          m.broken = r.byte() % 16 == 0;
          m.point_count = r.byte();
          for (std::size_t k = 0; k < kMaxEdgePoints && k < 4; ++k) m.wear_um[k] = r.value();
          for (std::size_t k = 4; k < kMaxEdgePoints; ++k) m.wear_um[k] = m.wear_um[k % 4];
          ev.emplace_back(m);
          break;
        }
        case 3:
          ev.emplace_back(
              ToolChange{now, static_cast<std::int32_t>(r.byte() % 3), (r.byte() & 1) != 0});
          break;
        default:
          ev.emplace_back(ProgramEvent{now, static_cast<ProgramEventKind>(r.byte() % 4), 1});
          break;
      }
    }
    // Time usually advances, sometimes jumps or goes backwards (a broken clock source).
    const std::uint8_t t = r.byte();
    now += t < 250 ? static_cast<TimeNs>(t) * 1'000'000 : -static_cast<TimeNs>(t) * 1'000'000;
    out.clear();
    w.step(now, ev, out);
    check(out, c);
    if ((t & 63) == 7) w.clear_alarm();
  }
  return 0;
}
