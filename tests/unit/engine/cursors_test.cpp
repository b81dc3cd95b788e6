// The engine's event cursors (core/engine/cursors.hpp; docs/daemon.md, "Events while nccompd was
// down"): GIVEN numbered events of several buses and kinds, WHEN the engine is stepped with them,
// THEN it keeps the counter of the last one of each bus and kind (also of an event it refuses and
// of a counter_only one, which no module sees), saves them with its state and restores them.
#include "core/engine/cursors.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <string_view>
#include <vector>

#include "core/engine/engine.hpp"
#include "tests/support/alloc_counter.hpp"

namespace nccomp::core::engine {
namespace {

constexpr TimeNs kMs = 1'000'000;

// Counts the events it is stepped with.
class CountingModule final : public Module {
 public:
  std::string_view name() const noexcept override { return "counting"; }
  void attach(const RegisterTable& /*registers*/) override {}
  void step(TimeNs /*now_ns*/, std::span<const Event> events,
            StepOutput& /*out*/) noexcept override {
    seen += events.size();
  }
  std::size_t seen{0};
};

struct Rig {
  Engine engine;
  CountingModule* module{nullptr};
  StepOutput out;
  Rig() {
    auto m = std::make_unique<CountingModule>();
    module = m.get();
    std::vector<std::unique_ptr<Module>> mods;
    mods.push_back(std::move(m));
    engine.configure({RegisterSpec{"a", RegisterKind::kToolLengthWear, LimiterConfig{}}},
                     std::move(mods));
  }
};

ToolMeasurement measurement(EventOrigin origin, double wear_um = 5.0) {
  ToolMeasurement m;
  m.tool = 1;
  m.wear_um[0] = wear_um;
  m.origin = origin;
  return m;
}

TEST(EngineCursors, TheLastNumberedEventOfEachBusAndKindIsKeptAndSavedWithTheState) {
  Rig r;
  EXPECT_FALSE(r.engine.event_cursors().any());
  ProgramEvent part_start;
  part_start.origin = EventOrigin{7, 1, true, false};
  ToolChange counter_only;
  counter_only.origin = EventOrigin{2, 0, true, true};
  const std::vector<Event> events{
      measurement({3, 0, true, false}),
      part_start,
      counter_only,
      measurement({}),  // not numbered (CAN, a test): no cursor
      measurement({4, 0, true, false}, std::numeric_limits<double>::quiet_NaN()),  // refused
      measurement({9, kCursorBuses, true, false}),  // a bus beyond the kept ones
  };
  const std::uint64_t g0 = r.engine.state_generation();
  r.engine.step(kMs, events, r.out);
  // The module saw the three valid events (and the one beyond the kept buses): not the
  // counter_only one, not the refused one.
  EXPECT_EQ(r.module->seen, 4U);
  EXPECT_EQ(r.engine.counters().events_invalid, 1U);
  EXPECT_EQ(r.engine.counters().events_accepted, 4U);
  const EventCursorSet bus0 = r.engine.event_cursors().bus(0);
  const EventCursorSet bus1 = r.engine.event_cursors().bus(1);
  EXPECT_TRUE(bus0[0].known);
  EXPECT_EQ(bus0[0].sequence, 4U);  // the refused one was taken too: it is not delivered again
  EXPECT_TRUE(bus0[3].known);
  EXPECT_EQ(bus0[3].sequence, 2U);
  EXPECT_FALSE(bus0[4].known);
  EXPECT_TRUE(bus1[4].known);
  EXPECT_EQ(bus1[4].sequence, 7U);
  EXPECT_FALSE(bus1[0].known);
  for (std::size_t b = 2; b <= kCursorBuses; ++b) {
    for (const EventCursor& c : r.engine.event_cursors().bus(b)) {
      EXPECT_FALSE(c.known) << b;
    }
  }
  EXPECT_GT(r.engine.state_generation(), g0);

  // The same counters again move nothing: the state need not be written again for them.
  const std::uint64_t g1 = r.engine.event_cursors().generation();
  r.engine.step(2 * kMs, std::vector<Event>{measurement({4, 0, true, false})}, r.out);
  EXPECT_EQ(r.engine.event_cursors().generation(), g1);

  // A restart: a fresh engine takes them from the exported state.
  std::vector<std::byte> buf(r.engine.state_capacity());
  const std::size_t n = r.engine.export_state(buf);
  ASSERT_GT(n, 0U);
  Rig restarted;
  std::size_t skipped = 99;
  ASSERT_TRUE(
      restarted.engine.import_state(std::span<const std::byte>(buf.data(), n), 0, &skipped));
  EXPECT_EQ(skipped, 0U);
  for (std::size_t b = 0; b < kCursorBuses; ++b) {
    const EventCursorSet want = r.engine.event_cursors().bus(b);
    const EventCursorSet got = restarted.engine.event_cursors().bus(b);
    for (std::size_t k = 0; k < kNumberedKinds; ++k) {
      EXPECT_EQ(got[k].known, want[k].known) << b << "/" << k;
      EXPECT_EQ(got[k].sequence, want[k].sequence) << b << "/" << k;
    }
  }
}

TEST(EngineCursors, AnInvalidCursorEntryIsSkippedAndLeavesThemUnknown) {
  Rig r;
  r.engine.step(kMs, std::vector<Event>{measurement({3, 0, true, false})}, r.out);
  std::vector<std::byte> buf(r.engine.state_capacity());
  const std::size_t n = r.engine.export_state(buf);
  ASSERT_GT(n, 0U);
  // The entry: its name, a 4-byte length, then the version byte.
  const std::string_view name = "@cursors";
  const auto* begin = reinterpret_cast<const char*>(buf.data());
  const std::string_view bytes(begin, n);
  const std::size_t at = bytes.find(name);
  ASSERT_NE(at, std::string_view::npos);
  buf[at + name.size() + 4] = std::byte{99};
  Rig restarted;
  std::size_t skipped = 0;
  ASSERT_TRUE(
      restarted.engine.import_state(std::span<const std::byte>(buf.data(), n), 0, &skipped));
  EXPECT_EQ(skipped, 1U);
  EXPECT_FALSE(restarted.engine.event_cursors().any());
}

TEST(EngineCursors, TakingAndSavingCursorsAllocatesNothing) {
  Rig r;
  ProgramEvent pe;
  pe.origin = EventOrigin{1, 0, true, false};
  std::vector<Event> events{measurement({1, 0, true, false}), pe};
  std::vector<std::byte> buf(r.engine.state_capacity());
  r.engine.step(0, events, r.out);  // warm-up
  const nccomp::test::AllocationScope scope;
  for (std::uint32_t k = 2; k < 200; ++k) {
    std::get<ToolMeasurement>(events[0]).origin.sequence = k;
    r.engine.step(k * kMs, events, r.out);
    const std::size_t n = r.engine.export_state(buf);
    (void)r.engine.import_state(std::span<const std::byte>(buf.data(), n), k * kMs);
  }
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_EQ(r.engine.event_cursors().bus(0)[0].sequence, 199U);
}

}  // namespace
}  // namespace nccomp::core::engine
