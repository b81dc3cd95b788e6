// Start-up of the S1 modules (docs/checkpoints.md, "Persistence and restart"): after the state
// was restored and before the loop steps the engine, the NC's checkpoint registers are read back
// and compared with the learned table (CheckpointCompensator::reconcile()), and the live
// register's limiter starts from the NC's value (reset_live()). Not real-time; call only while
// no other thread steps the engine.
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
  /// next part start anyway, and the live register's limiter starts from the restored value).
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
