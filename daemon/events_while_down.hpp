// Events the NC published while nccompd was down (docs/daemon.md, "Events while nccompd was
// down"): at start-up the engine's event cursors, restored from the state file, go to the buses
// before they start; what each bus's first read found is then reported once. Main thread only
// (it allocates), never the loop thread.
#pragma once

#include <array>
#include <string>
#include <utility>
#include <vector>

#include "core/engine/cursors.hpp"
#include "drivers/bus.hpp"

namespace nccomp::daemon {

/// One line for the daemon's log; `warning` when events were lost or the NC restarted.
struct EventsLine {
  bool warning{false};
  std::string text;
};

/// "tool_measurement", "probe_measurement", "calibration_touch", "tool_change",
/// "program_event" (the Modbus map's group names) for a core::numbered_kind() index.
[[nodiscard]] const char* numbered_kind_name(std::size_t kind) noexcept;

class EventsWhileDownLog {
 public:
  /// (name, bus) in the loop's bus order: bus i takes the engine's cursors of index i.
  using Buses = std::vector<std::pair<std::string, drivers::Bus*>>;

  /// Start-up, after the state import and before the buses start: hands every bus its cursors;
  /// one line per bus says what it will do with them.
  [[nodiscard]] std::vector<EventsLine> resume(const core::engine::EventCursors& cursors,
                                               const Buses& buses);
  /// Periodically: one line per bus and event kind whose first read after resume() happened
  /// since the last call.
  [[nodiscard]] std::vector<EventsLine> poll(const Buses& buses);

 private:
  std::vector<std::array<bool, core::kNumberedKinds>> reported_;
};

}  // namespace nccomp::daemon
