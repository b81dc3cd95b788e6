#include "daemon/commands/warm_start.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <cstdint>
#include <thread>

#include "client/protocol.hpp"
#include "daemon/loop.hpp"

namespace nccomp::daemon::commands {

namespace {

std::uint32_t next_sequence() {
  static std::uint32_t seq = 0;  // the command thread only
  return ++seq;
}

}  // namespace

std::string handle_warm_start_command(std::string_view args, CommandContext& ctx) {
  if (ctx.bus == nullptr || ctx.loop == nullptr) {
    return refuse(ctx, "this process takes no operator commands");
  }
  std::int8_t code = 0;
  if (args.empty() || args == "now") {
    code = 0;
  } else if (args == "at-next-motion") {
    code = 1;
  } else {
    const std::string shown(args.substr(0, 40));
    return refuse(ctx, "warm-start: unknown argument '" + shown +
                           (args.size() > 40 ? "...'" : "'") +
                           " (expected nothing, 'now' or 'at-next-motion')");
  }
  core::OperatorCommand oc;
  oc.sequence = next_sequence();
  oc.kind = core::OperatorCommandKind::kWarmStart;
  oc.code = {code, 0, 0, 0};
  if (!ctx.bus->push(oc)) {
    return refuse(ctx, "warm-start: the loop does not take commands (its queue is full)");
  }
  // The loop runs it at its next cycle; the engine publishes the sequence it took last. 3 s:
  // less than the client's 5 s receive timeout.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(3);
  core::engine::EngineCounters e = ctx.loop->stats().engine;
  while (e.last_warm_start_sequence != oc.sequence) {
    if (std::chrono::steady_clock::now() > deadline) {
      return refuse(ctx,
                    "warm-start: no answer from the loop within 3 s (is it running, or in "
                    "lock-step waiting for the NC?)");
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
    e = ctx.loop->stats().engine;
  }
  spdlog::info("operator command #{}: warm-start {} (warm starts {}, warm-start commands {})",
               oc.sequence, code == 0 ? "now" : "at the next motion", e.warm_starts,
               e.warm_start_commands);
  const std::string what = code == 0
                               ? "warm start now: the measurement log's time_s counts from 0"
                               : "the machine is cold: its next axis motion is the warm start";
  return fmt::format(
      "ok {}\n  warm starts: {} (since the state began); warm-start commands taken: {}; operator "
      "commands refused by the daemon: {}\n",
      what, e.warm_starts, e.warm_start_commands, ctx.bus->refused());
}

namespace {
[[maybe_unused]] const int kVerb =
    register_command_handler(std::string(client::kWarmStartVerb), handle_warm_start_command);
}  // namespace

}  // namespace nccomp::daemon::commands
