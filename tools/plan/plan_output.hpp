// Text outputs of `nccomp plan`: the plan as CSV and the probing program as Fanuc-style G-code.
#pragma once

#include <ostream>

#include "core/checkpoint/plan.hpp"
#include "formats/checkpoints/checkpoints_toml.hpp"

namespace nccomp::tools::checkpoints {

using formats::checkpoints::CheckpointsConfig;
using formats::checkpoints::GcodeConfig;

/// One row per checkpoint in machining order (header first).
void write_plan_csv(std::ostream& os, const core::checkpoint::Plan& plan,
                    const CheckpointsConfig& cfg);

/// The probing program: per checkpoint a clearance move, the descent beside the wall and one
/// G65 call of the measuring macro (argument letters in docs/checkpoints.md).
void write_probing_gcode(std::ostream& os, const core::checkpoint::Plan& plan,
                         const CheckpointsConfig& cfg);

/// A few lines summarising the plan, each starting with '#'.
void write_plan_summary(std::ostream& os, const core::checkpoint::Plan& plan,
                        const CheckpointsConfig& cfg);

}  // namespace nccomp::tools::checkpoints
