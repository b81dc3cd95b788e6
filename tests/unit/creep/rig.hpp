// Test rig for the creeping wear correction: a fake clock and a synthetic axis stream.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

#include "core/common/output.hpp"
#include "core/common/types.hpp"
#include "core/creep/wear_compensator.hpp"

namespace nccomp::core::creep::testing {

/// Axis mode, X/Y/Z on registers 0/1/2, one support point, no normal (mean wear on Z, sign −1),
/// a limiter that does not interfere, creep over 50 mm of path, linear.
inline CreepConfig base_config() {
  CreepConfig c;
  c.creep_basis = CreepBasis::kPath;
  c.creep_length_mm = 50.0;
  c.profile = ProfileShape::kLinear;
  c.edge.tool_shape = ToolShape::kTip;
  c.edge.edge_points = 1;
  c.edge.normal_source = NormalSource::kNone;
  c.edge.fallback_channel = Channel::kZ;
  c.edge.fallback_sign = -1.0;
  c.output.mode = OutputMode::kAxes;
  c.output.channel_register = {0, 1, 2, -1, -1};
  c.output.warning_register = 10;
  c.output.alarm_register = 11;
  c.output.measurement_due_register = 12;
  c.output.tool_change_register = 13;
  c.output.write_resolution_um = 0.01;
  c.output.refresh_interval_s = 0.0;
  c.limiter = {500.0, 1000.0, 1e7};
  c.tool_life.min_expected_increment_um = 50.0;
  return c;
}

struct Rig {
  WearCompensator comp;
  StepOutput out;
  std::vector<Event> events;
  TimeNs now_ns{0};
  double program_path_mm{0.0};
  std::array<double, 3> pos_mm{0.0, 0.0, 0.0};
  bool publish_program_path{true};
  bool has_normal{false};
  std::array<double, 3> normal{0.0, 0.0, 1.0};
  bool cutting{true};
  std::int32_t tool{1};
  // Everything the rig saw, over all steps.
  std::vector<AlarmEvent> alarms;
  std::vector<MeasurementRecord> records;
  std::vector<OffsetWrite> writes;

  explicit Rig(const CreepConfig& c) {
    comp.configure(c);
    tool_change(1, false);
    sample();
  }

  void step() {
    out.clear();
    comp.step(now_ns, events, out);
    events.clear();
    for (const auto& a : out.alarms) alarms.push_back(a);
    for (const auto& r : out.records) records.push_back(r);
    for (const auto& w : out.writes) writes.push_back(w);
  }
  /// One cycle: the tool moved ds_mm along X (and the program path) in dt_s.
  void advance(double ds_mm, double dt_s = 0.01) {
    now_ns += from_seconds(dt_s);
    program_path_mm += ds_mm;
    pos_mm[0] += ds_mm;
    sample();
  }
  /// Advances to an absolute program path in steps of ds_mm.
  void run_to(double path_mm, double ds_mm = 0.5, double dt_s = 0.01) {
    while (program_path_mm + ds_mm <= path_mm + 1e-9) advance(ds_mm, dt_s);
    if (path_mm - program_path_mm > 1e-9) advance(path_mm - program_path_mm, dt_s);
  }
  void sample() {
    AxisSample a;
    a.time_ns = now_ns;
    a.position_mm = {pos_mm[0], pos_mm[1], pos_mm[2], 0.0, 0.0, 0.0};
    a.axis_count = 3;
    a.program_path_mm = publish_program_path ? program_path_mm : kNaN;
    a.tool = tool;
    a.has_normal = has_normal;
    a.normal = normal;
    a.cutting = cutting;
    events.emplace_back(a);
    step();
  }
  void measure(std::vector<double> wear_um, bool broken = false) {
    ToolMeasurement m;
    m.time_ns = now_ns;
    m.tool = tool;
    m.broken = broken;
    m.point_count = static_cast<std::uint8_t>(wear_um.size());
    for (std::size_t i = 0; i < wear_um.size(); ++i) m.wear_um[i] = wear_um[i];
    events.emplace_back(m);
    now_ns += 1'000'000;  // a cycle later than the last sample
    step();
  }
  void tool_change(std::int32_t t, bool sister) {
    tool = t;
    events.emplace_back(ToolChange{now_ns, t, sister});
    step();
  }
  [[nodiscard]] double z() const { return comp.channel_output_um(Channel::kZ); }
  [[nodiscard]] double x() const { return comp.channel_output_um(Channel::kX); }
  [[nodiscard]] std::size_t count(AlarmCode code) const {
    std::size_t n = 0;
    for (const auto& a : alarms) n += a.code == code ? 1U : 0U;
    return n;
  }
  /// Last value written to a register, NaN if never.
  [[nodiscard]] double last_write(std::uint16_t reg) const {
    double v = kNaN;
    for (const auto& w : writes) {
      if (w.register_index == reg) v = w.value_um;
    }
    return v;
  }
};

}  // namespace nccomp::core::creep::testing
