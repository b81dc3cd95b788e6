// Shared pieces of the Modbus HIL tests: config text, driver start, draining rx().
#pragma once

#include <gtest/gtest.h>

#include <cstdint>
#include <memory>
#include <string>
#include <variant>
#include <vector>

#include "drivers/modbus/modbus_bus.hpp"
#include "tests/hil/modbus/hil_support.hpp"

namespace nccomp::test::modbus {

namespace mb = nccomp::drivers::modbus;

/// The [modbus] header with test timings: short timeouts and back-off so faults resolve fast.
inline std::string tcp_header(std::uint16_t port, const std::string& extra = "") {
  return "[modbus]\ntransport = \"tcp\"\nhost = \"127.0.0.1\"\nport = " + std::to_string(port) +
         "\npoll_rate_hz = 200\nresponse_timeout_s = 0.1\nbyte_timeout_s = 0.05\n"
         "reconnect_min_s = 0.02\nreconnect_max_s = 0.1\nalarm_after_s = 0.3\n" +
         extra + "\n";
}

inline std::string rtu_header(const std::string& device, const std::string& extra = "") {
  return "[modbus]\ntransport = \"rtu\"\ndevice = \"" + device +
         "\"\nbaud = 115200\nparity = \"none\"\npoll_rate_hz = 20\nresponse_timeout_s = 0.2\n"
         "byte_timeout_s = 0.05\nreconnect_min_s = 0.02\nreconnect_max_s = 0.1\n"
         "alarm_after_s = 0.3\n" +
         extra + "\n";
}

inline std::unique_ptr<mb::ModbusBus> make_bus(const std::string& toml) {
  return std::make_unique<mb::ModbusBus>(mb::parse_modbus_config(toml, "test.toml"));
}

/// Collects everything the driver decoded (the loop thread's side).
struct Collected {
  std::vector<core::AxisSample> axis;
  std::vector<core::ToolMeasurement> tool_measurements;
  std::vector<core::ToolChange> tool_changes;
  std::vector<core::TemperatureSample> temperatures;
  std::size_t other{0};
  // Counters consumed without an event (core::EventOrigin::counter_only): for the engine's
  // cursors only, not events.
  std::size_t counter_only{0};

  void drain(mb::ModbusBus& bus) {
    core::Event e;
    while (bus.rx().try_pop(e)) {
      if (const core::EventOrigin* o = core::origin_of(e); o != nullptr && o->counter_only) {
        ++counter_only;
      } else if (auto* a = std::get_if<core::AxisSample>(&e)) {
        axis.push_back(*a);
      } else if (auto* t = std::get_if<core::ToolMeasurement>(&e)) {
        tool_measurements.push_back(*t);
      } else if (auto* c = std::get_if<core::ToolChange>(&e)) {
        tool_changes.push_back(*c);
      } else if (auto* s = std::get_if<core::TemperatureSample>(&e)) {
        temperatures.push_back(*s);
      } else {
        ++other;
      }
    }
  }
};

inline void push_offset(mb::ModbusBus& bus, std::uint16_t index, double value_um) {
  ASSERT_TRUE(bus.tx().try_push(core::OffsetWrite{0, index, value_um}));
}

}  // namespace nccomp::test::modbus
