// The event cursors the engine keeps with its state: per bus and numbered event kind, the NC's
// counter of the last event the engine took (core::EventOrigin). They are saved in the same
// export as the modules' states, so an event's effect and its cursor reach the state file
// together: after a restart the bus delivers what the NC counted beyond the cursor (the newest
// event once, the rest counted lost) and nothing twice (docs/daemon.md, "Events while nccompd
// was down").
//
// Real-time: take(), save() and load() allocate nothing (fixed arrays).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>

#include "core/common/types.hpp"

namespace nccomp::core::engine {

/// Buses whose cursors are kept (the loop's bus index); events of a bus beyond are not tracked.
inline constexpr std::size_t kCursorBuses = 8;

class EventCursors {
 public:
  /// Real-time safe. Records e's origin if the event is numbered.
  void take(const Event& e) noexcept;
  /// The cursors of bus `bus` (all unknown beyond kCursorBuses).
  [[nodiscard]] EventCursorSet bus(std::size_t bus) const noexcept;
  /// True if any cursor is known.
  [[nodiscard]] bool any() const noexcept;

  /// Bytes of save()'s output (fixed): version, bus and kind counts, then per cursor a known
  /// flag and the counter.
  static constexpr std::size_t kStateBytes = 3 + kCursorBuses * kNumberedKinds * 5;
  /// Real-time safe. Returns kStateBytes, or 0 if buf is too small.
  std::size_t save(std::span<std::byte> buf) const noexcept;
  /// Real-time safe. false (and nothing changed) if the bytes are not a valid state.
  bool load(std::span<const std::byte> bytes) noexcept;
  /// Advances whenever a cursor moves.
  [[nodiscard]] std::uint64_t generation() const noexcept { return generation_; }

 private:
  std::array<EventCursorSet, kCursorBuses> cursors_{};
  std::uint64_t generation_{0};
};

}  // namespace nccomp::core::engine
