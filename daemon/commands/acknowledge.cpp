#include "daemon/commands/acknowledge.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <cmath>
#include <cstdint>
#include <thread>

#include "client/protocol.hpp"
#include "daemon/logging.hpp"
#include "daemon/loop.hpp"

namespace nccomp::daemon::commands {

namespace {

std::uint32_t next_sequence() {
  static std::uint32_t seq = 0;  // the command thread only
  return ++seq;
}

const core::engine::StatusValue* find(const ModuleSnapshot& m, std::string_view key) {
  for (std::uint32_t i = 0; i < m.count && i < m.values.size(); ++i) {
    if (m.values[i].key != nullptr && key == m.values[i].key) return &m.values[i];
  }
  return nullptr;
}

/// A module's alarm code value (0 none, -1 unknown; anything not a code = none).
int code_of(double v) {
  return std::isfinite(v) && v >= -1.0 && v <= 65535.0 ? static_cast<int>(std::lround(v)) : 0;
}

/// "tool_broken_or_mismeasured 23" from a module's code (0 none, -1 unknown).
std::string code_text(double value) {
  const int code = code_of(value);
  if (code == 0) return "none";
  if (code < 0) {
    return "of unknown cause (raised before this process started or with the tool out of the "
           "spindle; see the log)";
  }
  return fmt::format("{} {}", alarm_name(static_cast<core::AlarmCode>(code)), code);
}

/// What one module's last acknowledgement cleared, from its published status.
std::string cleared(const ModuleSnapshot& m, const core::engine::StatusValue& last) {
  const std::string what = last.text != nullptr ? last.text : "acknowledged";
  std::string s = fmt::format("{}: {}", m.name.data(), what);
  if (code_of(last.value) != 0) {
    const bool alarm = what.find("alarm") != std::string::npos;
    s += fmt::format(" ({} {})", alarm ? "alarm" : "warning", code_text(last.value));
  }
  return s;
}

}  // namespace

std::string handle_acknowledge_command(std::string_view args, CommandContext& ctx) {
  if (ctx.bus == nullptr || ctx.loop == nullptr) {
    return refuse(ctx, "this process takes no operator commands");
  }
  if (!args.empty() && args != "all") {
    const std::string shown(args.substr(0, 40));
    return refuse(ctx, "acknowledge: unknown argument '" + shown +
                           (args.size() > 40 ? "...'" : "'") + " (expected nothing or 'all')");
  }
  core::OperatorCommand oc;
  oc.sequence = next_sequence();
  oc.kind = core::OperatorCommandKind::kAcknowledge;
  oc.code = {0, 0, 0, 0};  // every module
  if (!ctx.bus->push(oc)) {
    return refuse(ctx, "acknowledge: the loop does not take commands (its queue is full)");
  }
  // The loop runs it at its next cycle (every module steps with it in that cycle); the engine
  // publishes the sequence it took last. 3 s in all: less than the client's 5 s timeout.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(3);
  const auto no_answer = [&] {
    return refuse(ctx,
                  "acknowledge: no answer from the loop within 3 s (is it running, or in "
                  "lock-step waiting for the NC?)");
  };
  LoopStats st = ctx.loop->stats();
  while (st.engine.last_acknowledge_sequence != oc.sequence) {
    if (std::chrono::steady_clock::now() > deadline) return no_answer();
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
    st = ctx.loop->stats();
  }
  // The modules' status is published every 10 cycles: wait for one taken after the command.
  const std::uint64_t taken = st.cycles;
  while (ctx.loop->stats().cycles < taken + 11) {
    if (std::chrono::steady_clock::now() > deadline) return no_answer();
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  const ModulesSnapshot mods = ctx.loop->modules();
  std::string summary;
  std::string details;
  for (std::uint32_t i = 0; i < mods.count && i < mods.modules.size(); ++i) {
    const ModuleSnapshot& m = mods.modules[i];
    const auto* last = find(m, "last_acknowledge");
    if (last == nullptr) continue;  // this module latches nothing
    summary += (summary.empty() ? "" : "; ") + cleared(m, *last);
    const auto* halted = find(m, "halted");
    const auto* latched = find(m, "latched_alarm");
    const auto* count = find(m, "acknowledged");
    details += fmt::format("  {}: now halted {}, latched alarm {}", m.name.data(),
                           halted != nullptr ? static_cast<int>(halted->value) : 0,
                           latched != nullptr ? code_text(latched->value) : "none");
    if (count != nullptr) {
      details +=
          fmt::format(", acknowledgements taken {}", static_cast<std::uint64_t>(count->value));
    }
    details += '\n';
  }
  if (summary.empty()) {
    summary = "no module of this configuration latches alarms (nothing to clear)";
  }
  spdlog::info("operator command #{}: acknowledge: {}", oc.sequence, summary);
  return fmt::format(
      "ok acknowledged: {}\n{}  acknowledge commands taken by the loop: {}; operator commands "
      "refused by the daemon: {}\n",
      summary, details, st.engine.acknowledge_commands, ctx.bus->refused());
}

namespace {
[[maybe_unused]] const int kVerb =
    register_command_handler(std::string(client::kAcknowledgeVerb), handle_acknowledge_command);
}  // namespace

}  // namespace nccomp::daemon::commands
