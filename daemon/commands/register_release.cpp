#include "daemon/commands/register_release.hpp"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <cmath>
#include <thread>
#include <vector>

#include "client/protocol.hpp"
#include "daemon/loop.hpp"

namespace nccomp::daemon::commands {

namespace {

namespace eng = core::engine;

std::uint32_t next_sequence() {
  static std::uint32_t seq = 0;  // the status thread only
  return ++seq;
}

/// What a held register waits for, as the answer and the log say it.
std::string held_text(const eng::RegisterState& r) {
  if (r.hold == eng::RegisterHold::kBeyondLimit) {
    return fmt::format("held beyond max_abs_um (the NC holds {:.3f} um)", r.output_um);
  }
  return "held without state";
}

/// What the release does to it.
std::string release_text(const eng::RegisterState& r) {
  if (r.hold == eng::RegisterHold::kBeyondLimit) {
    return r.has_target || r.has_trim
               ? fmt::format("{:.3f} um is written in one move", r.target_um + r.trim_um)
               : std::string("the next value is written from the limit");
  }
  return r.has_target
             ? fmt::format("moves to {:.3f} um through the limiter", r.target_um + r.trim_um)
             : std::string("written when its module computes a value");
}

}  // namespace

std::string handle_register_command(std::string_view args, CommandContext& ctx) {
  if (ctx.bus == nullptr || ctx.loop == nullptr || !ctx.register_names) {
    return refuse(ctx, "this process takes no operator commands");
  }
  constexpr std::string_view kRelease = "release";
  if (args.substr(0, kRelease.size()) != kRelease ||
      (args.size() > kRelease.size() && args[kRelease.size()] != ' ')) {
    const std::string shown(args.substr(0, 40));
    return refuse(ctx, "register: unknown argument '" + shown + (args.size() > 40 ? "...'" : "'") +
                           " (expected 'release NAME' or 'release all')");
  }
  std::string_view what = args.substr(std::min(args.size(), kRelease.size()));
  while (!what.empty() && what.front() == ' ') what.remove_prefix(1);
  if (what.empty()) {
    return refuse(ctx, "register release: name the register (or 'all')");
  }
  const std::vector<std::string> names = ctx.register_names();
  int index = -1;
  if (what != "all") {
    for (std::size_t i = 0; i < names.size(); ++i) {
      if (names[i] == what) index = static_cast<int>(i);
    }
    if (index < 0) {
      const std::string shown(what.substr(0, 60));
      return refuse(ctx, "register release: no register named '" + shown + "' in [[registers]]");
    }
  }
  // What is held now (the loop publishes every 10 cycles; the engine decides again when it
  // takes the command, so a register released meanwhile is simply not counted).
  const RegisterSnapshot before = ctx.loop->registers();
  core::OperatorCommand oc;
  oc.sequence = next_sequence();
  oc.kind = core::OperatorCommandKind::kRegisterRelease;
  oc.value = {static_cast<double>(index), 0.0};
  if (!ctx.bus->push(oc)) {
    return refuse(ctx, "register release: the loop does not take commands (its queue is full)");
  }
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(3);
  LoopStats st = ctx.loop->stats();
  while (st.engine.last_release_sequence != oc.sequence) {
    if (std::chrono::steady_clock::now() > deadline) {
      return refuse(ctx,
                    "register release: no answer from the loop within 3 s (is it running, or in "
                    "lock-step waiting for the NC?)");
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
    st = ctx.loop->stats();
  }
  std::vector<std::string> lines;
  for (std::size_t i = 0; i < before.count && i < names.size(); ++i) {
    const auto& r = before.regs[i];
    if (r.hold == eng::RegisterHold::kNone ||
        (index >= 0 && i != static_cast<std::size_t>(index))) {
      continue;
    }
    lines.push_back(fmt::format("{} ({}): was {}; {}", names[i], i, held_text(r), release_text(r)));
  }
  const std::string target =
      index < 0 ? std::string("all") : names[static_cast<std::size_t>(index)];
  const std::uint32_t count = st.engine.last_release_count;
  spdlog::info("operator command #{}: register release {}: {} register(s) released{}{}",
               oc.sequence, target, count, count > 0 && !lines.empty() ? ": " : "",
               count > 0 ? fmt::format("{}", fmt::join(lines, "; ")) : std::string{});
  if (count == 0) {
    return fmt::format("ok register release {}: nothing is held, nothing to release\n", target);
  }
  std::string answer = fmt::format("ok released {} register(s)\n", count);
  for (const auto& l : lines) answer += "  " + l + "\n";
  answer += fmt::format("  release commands taken by the loop: {}\n", st.engine.release_commands);
  return answer;
}

namespace {
[[maybe_unused]] const int kVerb =
    register_command_handler(std::string(client::kRegisterVerb), handle_register_command);
}  // namespace

}  // namespace nccomp::daemon::commands
