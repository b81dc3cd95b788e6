#include "daemon/events_while_down.hpp"

#include <sstream>

namespace nccomp::daemon {

const char* numbered_kind_name(std::size_t kind) noexcept {
  static constexpr std::array<const char*, core::kNumberedKinds> kNames = {
      "tool_measurement", "probe_measurement", "calibration_touch", "tool_change", "program_event"};
  return kind < kNames.size() ? kNames[kind] : "unknown";
}

std::vector<EventsLine> EventsWhileDownLog::resume(const core::engine::EventCursors& cursors,
                                                   const Buses& buses) {
  std::vector<EventsLine> lines;
  reported_.assign(buses.size(), {});
  for (std::size_t b = 0; b < buses.size(); ++b) {
    const core::EventCursorSet set = cursors.bus(b);
    std::ostringstream line;
    line << "bus " << buses[b].first << ": ";
    if (!buses[b].second->resume_events(set)) {
      line << "events sent while nccompd was down are not recovered (this bus does not number "
              "its events)";
      lines.push_back({false, line.str()});
      continue;
    }
    std::ostringstream known;
    for (std::size_t k = 0; k < set.size(); ++k) {
      if (set[k].known) {
        known << (known.tellp() > 0 ? ", " : "") << numbered_kind_name(k) << " #"
              << set[k].sequence;
      }
    }
    if (known.tellp() > 0) {
      line << "event counters resume from the state (" << known.str()
           << "): of the events the NC published while nccompd was down the newest of each "
              "kind is delivered at the first poll";
    } else {
      line << "no event counters in the state (first start, or a state file of an older "
              "nccompd): the first poll takes the NC's counters as they are, events published "
              "before it are not delivered";
    }
    lines.push_back({false, line.str()});
  }
  return lines;
}

std::vector<EventsLine> EventsWhileDownLog::poll(const Buses& buses) {
  std::vector<EventsLine> lines;
  std::array<drivers::EventsWhileDown, core::kNumberedKinds> found{};
  for (std::size_t b = 0; b < buses.size() && b < reported_.size(); ++b) {
    const std::size_t n = buses[b].second->events_while_down(found);
    for (std::size_t i = 0; i < n; ++i) {
      const drivers::EventsWhileDown& f = found[i];
      if (f.kind >= core::kNumberedKinds || reported_[b][f.kind]) {
        continue;
      }
      reported_[b][f.kind] = true;
      const char* kind = numbered_kind_name(f.kind);
      std::ostringstream line;
      line << "bus " << buses[b].first << ": ";
      const std::uint32_t lost = f.events > 0 ? f.events - 1U : 0U;
      if (f.nc_restarted) {
        line << "the " << kind << " counter went back from #" << f.cursor << " to #" << f.counter
             << " while nccompd was down: the NC restarted; " << f.events
             << (f.events == 1 ? " event" : " events") << " since its restart";
      } else if (f.events == 0) {
        line << "no " << kind << " event while nccompd was down (counter #" << f.counter << ")";
        lines.push_back({false, line.str()});
        continue;
      } else {
        line << f.events << (f.events == 1 ? " event of " : " events of ") << kind
             << " happened while nccompd was down (counter #" << f.cursor << " -> #" << f.counter
             << ")";
      }
      if (f.events > 0) {
        line << (f.delivered ? (lost > 0 ? ": the newest delivered" : ": delivered")
                             : ": the newest dropped, its values are invalid or out of range");
        if (lost > 0) {
          line << ", " << lost << " lost";
        }
      }
      if (f.nc_restarted) {
        line << "; events between nccompd's stop and the NC's restart are unknown";
      }
      lines.push_back({f.nc_restarted || lost > 0 || !f.delivered, line.str()});
    }
  }
  return lines;
}

}  // namespace nccomp::daemon
