#include "sim/ncsim/modbus_link.hpp"

#include <cmath>
#include <span>
#include <type_traits>

namespace nccomp::sim::ncsim {

namespace mb = drivers::modbus;
using modbus_nc::Tables;

namespace {

modbus_nc::ServerConfig server_config(const mb::ModbusConfig& map, int port) {
  modbus_nc::ServerConfig s;
  s.bind_address = "127.0.0.1";
  s.port = static_cast<std::uint16_t>(port < 0 ? map.port : port);
  s.unit_id = map.unit_id;
  return s;
}

void put(Tables& t, const mb::SignalMap& s, double value) {
  if (!s.mapped) {
    return;
  }
  switch (s.table) {
    case mb::Table::kCoil:
      t.coils[s.address] = std::fabs(value) > 0.0 ? 1 : 0;
      return;
    case mb::Table::kDiscreteInput:
      t.discrete_inputs[s.address] = std::fabs(value) > 0.0 ? 1 : 0;
      return;
    case mb::Table::kHolding:
      (void)mb::encode(value, s.encoding, t.holding.subspan(s.address, mb::width(s.encoding.type)));
      return;
    case mb::Table::kInput:
      (void)mb::encode(value, s.encoding, t.input.subspan(s.address, mb::width(s.encoding.type)));
      return;
  }
}

std::size_t group_of(const core::Event& e) {
  return std::visit(
      [](const auto& v) -> std::size_t {
        using T = std::decay_t<decltype(v)>;
        if constexpr (std::is_same_v<T, core::ToolMeasurement>) {
          return static_cast<std::size_t>(mb::Group::kToolMeasurement);
        } else if constexpr (std::is_same_v<T, core::ProbeMeasurement>) {
          return static_cast<std::size_t>(mb::Group::kProbeMeasurement);
        } else if constexpr (std::is_same_v<T, core::CalibrationTouch>) {
          return static_cast<std::size_t>(mb::Group::kCalibrationTouch);
        } else if constexpr (std::is_same_v<T, core::ToolChange>) {
          return static_cast<std::size_t>(mb::Group::kToolChange);
        } else if constexpr (std::is_same_v<T, core::ProgramEvent>) {
          return static_cast<std::size_t>(mb::Group::kProgramEvent);
        } else {
          return static_cast<std::size_t>(mb::Group::kAxis);  // state, not an event
        }
      },
      e);
}

void put_event(Tables& t, const mb::GroupMap& g, const core::Event& e) {
  const auto& f = g.fields;
  if (const auto* tm = std::get_if<core::ToolMeasurement>(&e)) {
    put(t, f[mb::tool_meas_field::kTool], tm->tool);
    const mb::SignalMap& w = f[mb::tool_meas_field::kWear];
    for (std::size_t i = 0; i < w.count; ++i) {
      mb::SignalMap one = w;
      one.address = static_cast<std::uint16_t>(w.address + i * mb::width(w.encoding.type));
      one.count = 1;
      put(t, one, tm->wear_um[std::min<std::size_t>(i, tm->point_count - 1U)]);
    }
    put(t, f[mb::tool_meas_field::kBroken], tm->broken ? 1.0 : 0.0);
  } else if (const auto* pm = std::get_if<core::ProbeMeasurement>(&e)) {
    put(t, f[mb::probe_field::kPart], pm->part);
    put(t, f[mb::probe_field::kCheckpoint], pm->checkpoint);
    put(t, f[mb::probe_field::kDeviation], pm->raw_deviation_um);
    put(t, f[mb::probe_field::kAngle], pm->wall_angle_deg);
    put(t, f[mb::probe_field::kBallRadius], pm->ball_radius_mm);
    put(t, f[mb::probe_field::kX], pm->position_mm[0]);
    put(t, f[mb::probe_field::kY], pm->position_mm[1]);
    put(t, f[mb::probe_field::kZ], pm->position_mm[2]);
  } else if (const auto* ct = std::get_if<core::CalibrationTouch>(&e)) {
    put(t, f[mb::touch_field::kProbe], static_cast<double>(ct->probe));
    put(t, f[mb::touch_field::kAxis], ct->axis);
    put(t, f[mb::touch_field::kDirection], ct->direction);
    put(t, f[mb::touch_field::kVariant], ct->variant);
    put(t, f[mb::touch_field::kPosition], ct->trigger_position_mm);
  } else if (const auto* tc = std::get_if<core::ToolChange>(&e)) {
    put(t, f[mb::tool_change_field::kTool], tc->tool);
    put(t, f[mb::tool_change_field::kSister], tc->sister ? 1.0 : 0.0);
  } else if (const auto* pe = std::get_if<core::ProgramEvent>(&e)) {
    put(t, f[mb::program_field::kKind], static_cast<double>(pe->kind));
    put(t, f[mb::program_field::kPart], pe->part);
  }
}

}  // namespace

ModbusLink::ModbusLink(mb::ModbusConfig map, int port, double limit_um)
    : map_(std::move(map)), limit_um_(limit_um), server_(server_config(map_, port)) {
  server_.set_write_filter([this](const modbus_nc::WriteRecord& w) { return filter(w); });
}

void ModbusLink::start() { server_.start(); }
void ModbusLink::stop() { server_.stop(); }

bool ModbusLink::filter(const modbus_nc::WriteRecord& w) {
  // Decode every offset register the request covers; refuse the whole request if one is out of
  // range or only half-written (a 32-bit value split over two requests would tear).
  std::vector<ReceivedOffset> got;
  const std::uint32_t first = w.address;
  const std::uint32_t end = first + static_cast<std::uint32_t>(w.values.size());
  if (w.function == 5 || w.function == 15) {
    return true;  // coils: no offsets there
  }
  bool ok = true;
  for (const mb::OffsetMap& om : map_.offsets) {
    const std::uint32_t a = om.address;
    const std::uint32_t b = a + mb::width(om.encoding.type);
    if (b <= first || a >= end) {
      continue;
    }
    if (a < first || b > end) {
      ok = false;
      break;
    }
    const double v =
        mb::decode(std::span<const std::uint16_t>(w.values).subspan(a - first, b - a), om.encoding);
    if (!std::isfinite(v) || std::fabs(v) > limit_um_) {
      ok = false;
      break;
    }
    got.push_back({om.register_index, v});
  }
  const std::lock_guard<std::mutex> lock(mutex_);
  if (!ok) {
    ++refused_;
    return false;
  }
  writes_.insert(writes_.end(), got.begin(), got.end());
  return true;
}

void ModbusLink::preset_offsets(const std::vector<std::pair<std::uint16_t, double>>& values) {
  server_.update([&](Tables& t) {
    for (const auto& [index, value] : values) {
      for (const mb::OffsetMap& om : map_.offsets) {
        if (om.register_index == index) {
          (void)mb::encode(value, om.encoding,
                           t.holding.subspan(om.address, mb::width(om.encoding.type)));
        }
      }
    }
  });
}

std::vector<ReceivedOffset> ModbusLink::take_writes() {
  const std::lock_guard<std::mutex> lock(mutex_);
  std::vector<ReceivedOffset> out;
  out.swap(writes_);
  return out;
}

std::uint64_t ModbusLink::writes_refused() const {
  const std::lock_guard<std::mutex> lock(mutex_);
  return refused_;
}

bool ModbusLink::events_pending() const {
  for (const auto& q : queue_) {
    if (!q.empty()) {
      return true;
    }
  }
  return false;
}

void ModbusLink::publish(const core::AxisSample& axis, const std::array<double, 2>& temperatures_c,
                         const std::vector<core::Event>& events, double hold_s) {
  for (const core::Event& e : events) {
    const std::size_t g = group_of(e);
    if (g == static_cast<std::size_t>(mb::Group::kAxis) || !map_.groups[g].present) {
      ++unmapped_;
      continue;
    }
    queue_[g].push_back(e);
  }
  const auto now = std::chrono::steady_clock::now();
  server_.update([&](Tables& t) {
    const auto& f = map_.groups[static_cast<std::size_t>(mb::Group::kAxis)].fields;
    put(t, f[mb::axis_field::kX], axis.position_mm[0]);
    put(t, f[mb::axis_field::kY], axis.position_mm[1]);
    put(t, f[mb::axis_field::kZ], axis.position_mm[2]);
    put(t, f[mb::axis_field::kPath],
        std::isfinite(axis.program_path_mm) ? axis.program_path_mm : 0.0);
    put(t, f[mb::axis_field::kTool], axis.tool);
    // No normal known (not cutting, the trip to the laser): all three 0, the map's "no normal".
    const std::array<double, 3> n = axis.has_normal ? axis.normal : std::array{0.0, 0.0, 0.0};
    put(t, f[mb::axis_field::kNormalX], n[0]);
    put(t, f[mb::axis_field::kNormalY], n[1]);
    put(t, f[mb::axis_field::kNormalZ], n[2]);
    put(t, f[mb::axis_field::kCutting], axis.cutting ? 1.0 : 0.0);
    for (const mb::TemperatureMap& tm : map_.temperatures) {
      if (tm.sensor < temperatures_c.size()) {
        put(t, tm.value, temperatures_c[tm.sensor]);
      }
    }
    for (std::size_t g = 1; g < mb::kGroupCount; ++g) {
      if (queue_[g].empty()) {
        continue;
      }
      if (hold_s > 0.0 && now - last_put_[g] < std::chrono::duration<double>(hold_s)) {
        continue;
      }
      const mb::GroupMap& gm = map_.groups[g];
      put_event(t, gm, queue_[g].front());
      queue_[g].pop_front();
      // Values first, then the counter (reference-nc-modbus.toml): one update() is atomic
      // for the poller anyway.
      sequence_[g] = static_cast<std::uint16_t>(sequence_[g] + 1U);
      put(t, gm.fields[0], sequence_[g]);
      last_put_[g] = now;
    }
  });
}

}  // namespace nccomp::sim::ncsim
