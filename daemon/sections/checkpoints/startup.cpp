#include "daemon/sections/checkpoints/startup.hpp"

#include <cmath>
#include <cstdio>
#include <vector>

#include "core/checkpoint/module.hpp"

namespace nccomp::daemon::sections {

std::vector<ReconcileOutcome> reconcile_checkpoints(core::engine::Engine& engine,
                                                    const RegisterReader& read,
                                                    core::TimeNs now_ns) {
  std::vector<ReconcileOutcome> out;
  for (std::size_t m = 0; m < engine.module_count(); ++m) {
    auto* cp = dynamic_cast<core::checkpoint::CheckpointModule*>(&engine.module(m));
    if (cp == nullptr) continue;
    auto& comp = cp->compensator();
    const auto& config = comp.config();
    const std::size_t n = comp.plan().size();
    ReconcileOutcome o;
    o.module = std::string(cp->name());
    std::vector<double> values(n);
    std::size_t unreadable = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const auto v = read ? read(static_cast<std::uint16_t>(config.register_base + i))
                          : std::optional<double>{};
      if (!v) {
        ++unreadable;
        continue;
      }
      values[i] = *v;
    }
    char line[384];
    if (unreadable > 0) {
      std::snprintf(line, sizeof line,
                    "%s: %zu of %zu checkpoint registers cannot be read back from the NC; the "
                    "learned table is written again at the next part start",
                    o.module.c_str(), unreadable, n);
      o.message = line;
      out.push_back(std::move(o));
      continue;
    }
    // The engine's limiters start from what the NC holds (the register may have been edited, or
    // the NC may have lost it): the next writes move from there, never more than max_step_um.
    for (std::size_t i = 0; i < n; ++i) {
      (void)engine.anchor_register(config.register_base + i, values[i], now_ns);
    }
    const auto rep = comp.reconcile(values);
    if (rep.adopted_nc) {
      // Adopted values are the registers' targets from now on, before the compensator publishes
      // them (32 table registers per cycle): the engine must not pull a register toward the
      // restored target in between. A value the compensator could not adopt is left to it.
      for (std::size_t i = 0; i < n; ++i) {
        if (std::fabs(comp.register_value_um(i) - values[i]) <= config.reconcile_tolerance_um) {
          (void)engine.adopt_register(config.register_base + i, values[i], now_ns);
        }
      }
    }
    o.read_back = true;
    o.compared = rep.compared;
    o.mismatched = rep.mismatched;
    o.max_difference_um = rep.max_difference_um;
    o.adopted_nc = rep.adopted_nc;
    if (config.active_register >= 0) {
      if (const auto live = read(static_cast<std::uint16_t>(config.active_register))) {
        comp.reset_live(*live, now_ns);
        (void)engine.anchor_register(static_cast<std::size_t>(config.active_register), *live,
                                     now_ns);
      }
    }
    if (rep.mismatched == 0) {
      std::snprintf(line, sizeof line, "%s: the NC's %zu checkpoint registers agree with the table",
                    o.module.c_str(), rep.compared);
    } else {
      std::snprintf(line, sizeof line,
                    "%s: %zu of %zu checkpoint registers differ from the table (max %.3f um); %s%s",
                    o.module.c_str(), rep.mismatched, rep.compared, rep.max_difference_um,
                    rep.adopted_nc ? "the NC's values are adopted (reconcile_prefer = \"nc\")"
                                   : "the table is written again (reconcile_prefer = \"daemon\")",
                    rep.adopted_nc && rep.rewritten > 0
                        ? "; some could not be adopted (non-finite or beyond the limit): those "
                          "are written again"
                        : "");
    }
    o.message = line;
    out.push_back(std::move(o));
  }
  return out;
}

namespace {
[[maybe_unused]] const int kRegistered = register_startup_hook(
    "checkpoints",
    [](core::engine::Engine& engine, const RegisterReader& read, core::TimeNs now_ns) {
      std::vector<std::string> lines;
      for (const auto& o : reconcile_checkpoints(engine, read, now_ns)) lines.push_back(o.message);
      return lines;
    });
}  // namespace

}  // namespace nccomp::daemon::sections
