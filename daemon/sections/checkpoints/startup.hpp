// Start-up of the S1 modules (docs/checkpoints.md, "Persistence and restart"): after the state
// was restored and before the loop steps the engine, the NC's checkpoint registers are read back
// and compared with the learned table (CheckpointCompensator::reconcile()). The engine's limiter
// of every register read back starts from the NC's value (Engine::anchor_register()), so the
// table is rewritten (prefer = "daemon") from what the NC holds in steps of at most max_step_um;
// with prefer = "nc" the adopted values become the registers' targets at once
// (Engine::adopt_register()), so an operator's edit of any size stays in the NC. The live
// register's limiters (the compensator's, reset_live(), and the engine's) start from the NC's
// value too. Not real-time; call only while no other thread steps the engine.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/common/types.hpp"
#include "core/engine/engine.hpp"
#include "daemon/daemon.hpp"

namespace nccomp::daemon::sections {

struct ReconcileOutcome {
  std::string module;
  /// False: some register could not be read; nothing was compared (the table is rewritten at the
  /// next part start anyway, and the limiters of the registers not read back start from the
  /// restored values).
  bool read_back{false};
  std::size_t compared{0};
  std::size_t mismatched{0};
  double max_difference_um{0.0};
  bool adopted_nc{false};
  /// One line for the log.
  std::string message;
};

/// Reconciles every CheckpointModule of the engine with the registers `read` returns (nccompd
/// runs it as the "checkpoints" start-up hook, daemon/daemon.hpp).
std::vector<ReconcileOutcome> reconcile_checkpoints(core::engine::Engine& engine,
                                                    const RegisterReader& read,
                                                    core::TimeNs now_ns);

}  // namespace nccomp::daemon::sections
