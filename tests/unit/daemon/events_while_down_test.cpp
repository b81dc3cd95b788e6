// What nccompd logs of the events an NC published while it was down (daemon/events_while_down.hpp,
// docs/daemon.md): GIVEN buses that do or do not number their events and what their first reads
// found, THEN one line per bus at start-up and one per kind once its first read happened, a
// warning where events were lost or the NC restarted, each line once.
#include "daemon/events_while_down.hpp"

#include <gtest/gtest.h>

#include <string>
#include <vector>

namespace nccomp::daemon {
namespace {

class FakeBus final : public drivers::Bus {
 public:
  explicit FakeBus(bool numbers) : numbers_(numbers), rx_(4), tx_(4) {}
  void start() override {}
  void stop() override {}
  core::rt::SpscRing<core::Event>& rx() override { return rx_; }
  core::rt::SpscRing<core::OffsetWrite>& tx() override { return tx_; }
  [[nodiscard]] drivers::BusStatus status() const override { return {}; }
  bool resume_events(const core::EventCursorSet& cursors) override {
    given = cursors;
    return numbers_;
  }
  [[nodiscard]] std::size_t events_while_down(
      std::span<drivers::EventsWhileDown> out) const override {
    const std::size_t n = std::min(out.size(), found.size());
    std::copy_n(found.begin(), n, out.begin());
    return n;
  }
  core::EventCursorSet given{};
  std::vector<drivers::EventsWhileDown> found;

 private:
  bool numbers_;
  core::rt::SpscRing<core::Event> rx_;
  core::rt::SpscRing<core::OffsetWrite> tx_;
};

std::vector<std::string> texts(const std::vector<EventsLine>& lines, bool warnings) {
  std::vector<std::string> out;
  for (const EventsLine& l : lines) {
    if (l.warning == warnings) out.push_back(l.text);
  }
  return out;
}

TEST(EventsWhileDown, EachBusGetsItsCursorsAndEveryFirstReadIsLoggedOnce) {
  // GIVEN cursors for bus 0 (tool measurement #4, program event #9) and none for bus 1
  core::engine::EventCursors cursors;
  core::ToolMeasurement m;
  m.origin = core::EventOrigin{4, 0, true, false};
  cursors.take(m);
  core::ProgramEvent p;
  p.origin = core::EventOrigin{9, 0, true, false};
  cursors.take(p);
  FakeBus modbus(true);
  FakeBus other(true);
  FakeBus can(false);
  const EventsWhileDownLog::Buses buses{{"modbus", &modbus}, {"other", &other}, {"can", &can}};
  EventsWhileDownLog w;
  const auto start = w.resume(cursors, buses);
  EXPECT_TRUE(modbus.given[0].known);
  EXPECT_EQ(modbus.given[0].sequence, 4U);
  EXPECT_EQ(modbus.given[4].sequence, 9U);
  EXPECT_FALSE(other.given[0].known);
  EXPECT_TRUE(texts(start, true).empty());
  EXPECT_EQ(texts(start, false),
            (std::vector<std::string>{
                "bus modbus: event counters resume from the state (tool_measurement #4, "
                "program_event #9): of the events the NC published while nccompd was down the "
                "newest of each kind is delivered at the first poll",
                "bus other: no event counters in the state (first start, or a state file of an "
                "older nccompd): the first poll takes the NC's counters as they are, events "
                "published before it are not delivered",
                "bus can: events sent while nccompd was down are not recovered (this bus does "
                "not number its events)"}));
  // Nothing read yet: nothing to say.
  EXPECT_TRUE(w.poll(buses).empty());
  // WHEN the first reads happened
  modbus.found = {
      {0, 4, 7, 3, false, true},   // three tool measurements: the newest delivered
      {4, 9, 2, 2, true, true},    // the NC restarted, two program events since
      {3, 1, 1, 0, false, false},  // no tool change
  };
  other.found = {{1, 6, 7, 1, false, false}};  // one probe measurement, its values refused
  const auto first = w.poll(buses);
  EXPECT_EQ(texts(first, true),
            (std::vector<std::string>{
                "bus modbus: 3 events of tool_measurement happened while nccompd was down "
                "(counter #4 -> #7): the newest delivered, 2 lost",
                "bus modbus: the program_event counter went back from #9 to #2 while nccompd was "
                "down: the NC restarted; 2 events since its restart: the newest delivered, 1 "
                "lost; events between nccompd's stop and the NC's restart are unknown",
                "bus other: 1 event of probe_measurement happened while nccompd was down "
                "(counter #6 -> #7): the newest dropped, its values are invalid or out of "
                "range"}));
  EXPECT_EQ(texts(first, false),
            (std::vector<std::string>{
                "bus modbus: no tool_change event while nccompd was down (counter #1)"}));
  // THEN each is said once.
  EXPECT_TRUE(w.poll(buses).empty());
}

}  // namespace
}  // namespace nccomp::daemon
