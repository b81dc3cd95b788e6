// Operator commands on the status socket (docs/daemon.md, "Operator commands"). A request line
// whose first word is a registered verb ("calibrate begin", ...) goes to that verb's handler
// instead of the status renderer. Handlers run on the status thread (one request at a time) and
// reach the loop only through the CommandBus: an SPSC ring of core events that the loop drains
// like a bus's receive ring, so the loop thread takes commands without allocation or locks.
// Not real-time (except CommandBus::rx(), which the loop uses).
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include "core/rt/spsc_ring.hpp"
#include "drivers/bus.hpp"

namespace nccomp::daemon {

class Loop;

/// The command channel into the loop: an extra "bus" in the loop's list whose receive ring the
/// status thread fills. It takes no offset writes (no register is mapped to it).
class CommandBus final : public drivers::Bus {
 public:
  explicit CommandBus(std::size_t capacity = 64);
  void start() override {}
  void stop() override {}
  core::rt::SpscRing<core::Event>& rx() override { return rx_; }
  core::rt::SpscRing<core::OffsetWrite>& tx() override { return tx_; }
  [[nodiscard]] drivers::BusStatus status() const override;

  /// The single producer (the status thread): queues an event for the loop's next cycle.
  /// False if the ring is full (the loop is not running).
  bool push(const core::Event& e);
  /// Commands queued, and refused (malformed or the ring full) by the handlers.
  [[nodiscard]] std::uint64_t pushed() const noexcept { return pushed_.load(); }
  [[nodiscard]] std::uint64_t refused() const noexcept { return refused_.load(); }
  void count_refused() noexcept { refused_.fetch_add(1); }

 private:
  core::rt::SpscRing<core::Event> rx_;
  core::rt::SpscRing<core::OffsetWrite> tx_;
  std::atomic<std::uint64_t> pushed_{0};
  std::atomic<std::uint64_t> refused_{0};
};

struct CommandContext {
  CommandBus* bus{nullptr};
  const Loop* loop{nullptr};
  /// The running configuration's register names, by index (a reload may change them).
  std::function<std::vector<std::string>()> register_names;
};

/// args: the request line after the verb, trimmed. Returns the answer (lines ending in '\n'):
/// the first line is "ok ..." or "error: <what>".
using CommandHandler = std::function<std::string(std::string_view args, CommandContext& ctx)>;

/// Registers a verb (static initialisation of a section's object file). Throws on a duplicate.
int register_command_handler(std::string verb, CommandHandler handler);

/// Set by run_daemon before the status server starts, cleared after it stopped.
void set_command_context(const CommandContext& context);

/// If the first word of line is a registered verb, runs its handler into answer and returns
/// true. Exceptions of a handler become "error: ..." answers (counted as refused).
bool dispatch_command(std::string_view line, std::string& answer);

}  // namespace nccomp::daemon
