#include "daemon/commands/model.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <thread>

#include "client/protocol.hpp"
#include "daemon/loop.hpp"

namespace nccomp::daemon::commands {

namespace {

std::string describe(const sections::ModelRecord& r) {
  if (r.file.empty()) return "none";
  std::string s = r.file + " (hash " + (r.hash.empty() ? "unknown" : r.hash) + ")";
  if (!r.since_utc.empty()) s += ", live since " + r.since_utc;
  return s;
}

std::string handover_line(const HandoverStats& h) {
  return fmt::format(
      "  handovers: {} (registers rebased {}, not absorbed {}); last: largest trim change "
      "{:.3f} um, {:.3f} um through the limiter\n",
      h.handovers, h.rebases, h.unabsorbed, h.last_trim_change_um, h.last_unabsorbed_um);
}

std::string status_answer(const ModelState& m, const HandoverStats& h) {
  std::string s = fmt::format("ok model: {}\n", describe(m.live));
  if (!m.has_section) {
    s += "  the configuration has no [model] section\n";
  } else if (m.chosen) {
    s += fmt::format(
        "  chosen by nccomp model load / rollback, in place of the configuration's {}\n",
        m.configured);
  } else {
    s += "  the configuration's [model] file\n";
  }
  s += fmt::format("  previous (nccomp model rollback returns to it): {}\n", describe(m.previous));
  s += fmt::format("  configuration {}\n", m.generation);
  return s + handover_line(h);
}

}  // namespace

CommandAccess model_access(std::string_view args) noexcept {
  return args == "status" ? CommandAccess::kReadOnly : CommandAccess::kChangesMachine;
}

std::string handle_model_command(std::string_view args, CommandContext& ctx) {
  if (ctx.loop == nullptr || !ctx.model_state || !ctx.change_model) {
    return refuse(ctx, "this process takes no model commands");
  }
  if (args == "status") {
    return status_answer(ctx.model_state(), ctx.loop->stats().handover);
  }
  ModelAction action = ModelAction::kRollback;
  std::string file;
  if (args.starts_with("load ")) {
    action = ModelAction::kLoad;
    file = std::string(args.substr(5));
    if (file.empty() || file.front() != '/') {
      return refuse(ctx,
                    "model load: the file must be an absolute path (nccomp model load makes "
                    "it one), got '" +
                        file.substr(0, 200) + "'");
    }
  } else if (args != "rollback") {
    const std::string shown(args.substr(0, 40));
    return refuse(ctx, "model: unknown request '" + shown + (args.size() > 40 ? "...'" : "'") +
                           " (expected load PATH, rollback or status)");
  }
  const HandoverStats before = ctx.loop->stats().handover;
  const ModelChange change = ctx.change_model(action, file);
  const char* what = action == ModelAction::kLoad ? "load" : "rollback";
  if (!change.ok) {
    return refuse(ctx, fmt::format("model {}: refused, nothing changed:\n{}", what, change.error));
  }
  const ModelState& m = change.state;
  spdlog::info("model {}: {} live as configuration {} (previous: {})", what, describe(m.live),
               m.generation, describe(m.previous));
  std::string answer =
      fmt::format("ok model {}: {}\n  previous (nccomp model rollback returns to it): {}\n",
                  action == ModelAction::kLoad ? "loaded" : "rolled back to", describe(m.live),
                  describe(m.previous));
  if (!change.record_error.empty()) {
    answer +=
        "  warning: not recorded in the state directory (a restart returns to the model "
        "before): " +
        change.record_error + "\n";
  }
  // The loop swaps the configuration in at its next cycle and hands the trims over there; 3 s in
  // all, less than the client's 5 s.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(3);
  LoopStats st = ctx.loop->stats();
  while (st.config_generation < m.generation) {
    if (std::chrono::steady_clock::now() > deadline) {
      return answer + fmt::format(
                          "  configuration {} accepted; the loop has not swapped it in within 3 s "
                          "(in lock-step, waiting for the NC?): see nccomp model status\n",
                          m.generation);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
    st = ctx.loop->stats();
  }
  answer += fmt::format("  configuration {} running\n", m.generation);
  if (st.handover.handovers > before.handovers) {
    answer += handover_line(st.handover);
  } else {
    answer += "  no register's trims changed: nothing handed over\n";
  }
  return answer;
}

namespace {
[[maybe_unused]] const int kVerb =
    register_command_handler(std::string(client::kModelVerb), handle_model_command, &model_access);
}  // namespace

}  // namespace nccomp::daemon::commands
