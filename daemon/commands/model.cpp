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

std::string hash_or_unknown(const std::string& file) {
  try {
    return sections::model_file_hash(file);
  } catch (const std::exception&) {
    return "unknown";
  }
}

std::string score_text(const sections::ModelScore& s) {
  if (s.parts == 0) return "no part scored yet";
  return fmt::format("{} parts ({} rows), mean squared error {:.4g} um^2 (rms {:.3f} um)", s.parts,
                     s.rows, s.mse_um2(), s.rms_um());
}

std::string shadow_lines(const sections::ShadowStatus& sh) {
  std::string s = fmt::format("  live model's score: {}\n", score_text(sh.live));
  const auto& o = sh.options;
  switch (sh.phase) {
    case sections::ShadowPhase::kNone:
      s += "  shadow: no candidate (nccomp model candidate FILE puts one beside the live model)\n";
      break;
    case sections::ShadowPhase::kCandidate:
    case sections::ShadowPhase::kAnnounced:
      s += fmt::format("  candidate{}: {}\n    score: {}\n",
                       sh.phase == sections::ShadowPhase::kAnnounced
                           ? " (better: nccomp model promote makes it live)"
                           : "",
                       sh.other_file, score_text(sh.other));
      break;
    case sections::ShadowPhase::kWatch:
      s += fmt::format("  watching the model the promotion replaced: {}\n    score: {}\n",
                       sh.other_file, score_text(sh.other));
      break;
  }
  if (sh.phase != sections::ShadowPhase::kNone) {
    const auto& w = sh.window;
    s += fmt::format(
        "    paired parts {} of {}: other better on {}, live better on {}, ties {}, sign test "
        "p = {:.4g} (alpha {}), rms live {:.3f} um, other {:.3f} um\n",
        w.parts, o.min_parts, w.challenger_better, w.incumbent_better, w.ties, w.p_value, o.alpha,
        w.incumbent_rms_um, w.challenger_rms_um);
  }
  s += fmt::format("  rule: min_parts {}, alpha {}, margin_um {}, promote {}\n", o.min_parts,
                   o.alpha, o.margin_um,
                   o.promote == sections::ShadowPromote::kAuto ? "auto" : "operator");
  s += fmt::format("  history ({} decisions):\n", sh.history.size());
  for (const auto& d : sh.history) s += "    " + sections::describe(d) + "\n";
  return s;
}

}  // namespace

std::string model_status_text(const ModelState& m, const HandoverStats& h) {
  std::string s = fmt::format("ok model: {}\n", describe(m.live));
  if (m.pending) {
    s += fmt::format(
        "  pending: {} (configuration {}), not live yet: the loop swaps it in at a cycle in "
        "which the bus has confirmed every write in flight; waited {} cycles\n",
        m.pending_model.file.empty() ? std::string("no model") : describe(m.pending_model),
        m.pending_generation, m.pending_cycles);
  }
  // Where the newest model (the pending one, if any) comes from.
  const std::string& newest = m.pending ? m.pending_model.file : m.live.file;
  if (!m.has_section) {
    s += "  the configuration has no [model] section\n";
  } else if (m.chosen && newest != m.configured) {
    s += fmt::format(
        "  chosen by nccomp model load / rollback, in place of the configuration's {}\n",
        m.configured);
  } else if (m.chosen) {
    // A rollback (or a load) back to the configured file: the choice is still recorded, for the
    // model it keeps to roll back to.
    s += "  the configuration's [model] file, chosen again by nccomp model load / rollback\n";
  } else {
    s += "  the configuration's [model] file\n";
  }
  s += fmt::format("  previous (nccomp model rollback returns to it): {}\n", describe(m.previous));
  s += fmt::format("  configuration {}\n", m.generation);
  return s + handover_line(h) + shadow_lines(m.shadow);
}

CommandAccess model_access(std::string_view args) noexcept {
  // candidate changes no offset, but what may become live: the admin group's too.
  return args == "status" ? CommandAccess::kReadOnly : CommandAccess::kChangesMachine;
}

std::string handle_model_command(std::string_view args, CommandContext& ctx) {
  if (ctx.loop == nullptr || !ctx.model_state || !ctx.change_model) {
    return refuse(ctx, "this process takes no model commands");
  }
  if (args == "status") {
    return model_status_text(ctx.model_state(), ctx.loop->stats().handover);
  }
  ModelAction action = ModelAction::kRollback;
  std::string file;
  const bool load = args.starts_with("load ");
  if (load || args.starts_with("candidate ")) {
    action = load ? ModelAction::kLoad : ModelAction::kCandidate;
    file = std::string(args.substr(load ? 5 : 10));
    if (file.empty() || file.front() != '/') {
      return refuse(ctx, fmt::format("model {}: the file must be an absolute path (nccomp model {} "
                                     "makes it one), got '{}'",
                                     load ? "load" : "candidate", load ? "load" : "candidate",
                                     file.substr(0, 200)));
    }
  } else if (args == "promote") {
    action = ModelAction::kPromote;
  } else if (args != "rollback") {
    const std::string shown(args.substr(0, 40));
    return refuse(ctx, "model: unknown request '" + shown + (args.size() > 40 ? "...'" : "'") +
                           " (expected load PATH, candidate PATH, promote, rollback or status)");
  }
  const HandoverStats before = ctx.loop->stats().handover;
  const ModelChange change = ctx.change_model(action, file, ctx.who);
  const char* what = action == ModelAction::kLoad        ? "load"
                     : action == ModelAction::kCandidate ? "candidate"
                     : action == ModelAction::kPromote   ? "promote"
                                                         : "rollback";
  if (!change.ok) {
    return refuse(ctx, fmt::format("model {}: refused, nothing changed:\n{}", what, change.error));
  }
  const ModelState& m = change.state;
  if (action == ModelAction::kCandidate) {  // logged by the daemon with the shadow's history
    return fmt::format(
        "ok model candidate: {} (hash {}) scored in shadow beside the live model {}\n  the rule "
        "decides after {} parts scored by both\n",
        file, hash_or_unknown(file), describe(m.live), m.shadow.options.min_parts);
  }
  // The loop swaps the configuration in at a cycle in which the bus has confirmed every write
  // in flight, and hands the trims over there; until then the model is pending (3 s here, less
  // than the client's 5 s).
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(3);
  LoopStats st = ctx.loop->stats();
  while (st.config_generation < m.generation && std::chrono::steady_clock::now() <= deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
    st = ctx.loop->stats();
  }
  const bool swapped = st.config_generation >= m.generation;
  // Once swapped, the view carries the time of the swap.
  sections::ModelRecord shown = swapped ? ctx.model_state().live : m.live;
  if (!swapped) shown.since_utc.clear();
  spdlog::info("model {}: {} {} as configuration {} (previous: {}; by {})", what, describe(shown),
               swapped ? "live" : "pending", m.generation, describe(m.previous), ctx.who);
  std::string answer =
      fmt::format("ok model {}: {}\n  previous (nccomp model rollback returns to it): {}\n",
                  action == ModelAction::kLoad      ? "loaded"
                  : action == ModelAction::kPromote ? "promoted"
                                                    : "rolled back to",
                  describe(shown), describe(m.previous));
  if (!change.record_error.empty()) {
    answer +=
        "  warning: not recorded in the state directory (a restart returns to the model "
        "before): " +
        change.record_error + "\n";
  }
  if (!swapped) {
    return answer + fmt::format(
                        "  configuration {} accepted, pending: the loop has not swapped it in "
                        "within 3 s ({} cycles waiting for the bus to confirm the writes in "
                        "flight; in lock-step, for the NC): see nccomp model status\n",
                        m.generation, st.swap_waiting);
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
