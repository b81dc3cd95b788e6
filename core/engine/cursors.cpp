#include "core/engine/cursors.hpp"

#include <cstring>

namespace nccomp::core::engine {

namespace {
constexpr std::uint8_t kVersion = 1;
}  // namespace

void EventCursors::take(const Event& e) noexcept {
  const EventOrigin* o = origin_of(e);
  const int kind = numbered_kind(e);
  if (o == nullptr || !o->numbered || kind < 0 || o->bus >= kCursorBuses) {
    return;
  }
  EventCursor& c = cursors_[o->bus][static_cast<std::size_t>(kind)];
  if (!c.known || c.sequence != o->sequence) {
    c = EventCursor{true, o->sequence};
    ++generation_;
  }
}

EventCursorSet EventCursors::bus(std::size_t bus) const noexcept {
  return bus < kCursorBuses ? cursors_[bus] : EventCursorSet{};
}

bool EventCursors::any() const noexcept {
  for (const EventCursorSet& set : cursors_) {
    for (const EventCursor& c : set) {
      if (c.known) {
        return true;
      }
    }
  }
  return false;
}

std::size_t EventCursors::save(std::span<std::byte> buf) const noexcept {
  if (buf.size() < kStateBytes) {
    return 0;
  }
  std::size_t at = 0;
  buf[at++] = std::byte{kVersion};
  buf[at++] = static_cast<std::byte>(kCursorBuses);
  buf[at++] = static_cast<std::byte>(kNumberedKinds);
  for (const EventCursorSet& set : cursors_) {
    for (const EventCursor& c : set) {
      buf[at++] = std::byte{c.known ? std::uint8_t{1} : std::uint8_t{0}};
      std::memcpy(buf.data() + at, &c.sequence, sizeof c.sequence);
      at += sizeof c.sequence;
    }
  }
  return at;
}

bool EventCursors::load(std::span<const std::byte> bytes) noexcept {
  if (bytes.size() != kStateBytes || bytes[0] != std::byte{kVersion} ||
      bytes[1] != static_cast<std::byte>(kCursorBuses) ||
      bytes[2] != static_cast<std::byte>(kNumberedKinds)) {
    return false;
  }
  std::array<EventCursorSet, kCursorBuses> next{};
  std::size_t at = 3;
  for (EventCursorSet& set : next) {
    for (EventCursor& c : set) {
      const auto known = static_cast<std::uint8_t>(bytes[at++]);
      if (known > 1) {
        return false;
      }
      c.known = known == 1;
      std::memcpy(&c.sequence, bytes.data() + at, sizeof c.sequence);
      at += sizeof c.sequence;
      if (!c.known && c.sequence != 0) {
        return false;
      }
    }
  }
  cursors_ = next;
  ++generation_;
  return true;
}

}  // namespace nccomp::core::engine
