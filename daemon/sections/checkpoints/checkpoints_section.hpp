// The daemon's `[checkpoints]` section (docs/checkpoints.md): parsed by
// formats::checkpoints::parse_checkpoints() (the loader `nccomp plan` uses, so the daemon and the
// probing program always agree on the plan), registers checked against [[registers]] in
// cross_check(), one CheckpointModule added to the engine. Not real-time.
#pragma once

#include <memory>

#include "daemon/config/config.hpp"
#include "formats/checkpoints/checkpoints_toml.hpp"
#include "formats/toml/key_positions.hpp"

namespace nccomp::daemon::sections {

struct CheckpointsSection final : config::Section {
  formats::checkpoints::CheckpointsConfig config;
  /// Number of checkpoints of the plan (the registers register_base .. + count − 1).
  std::size_t checkpoint_count{0};
  formats::Where where;
  formats::KeyPositions key_positions;
};

/// Parses one `[checkpoints]` node; contour_csv is relative to the file holding the table.
std::unique_ptr<CheckpointsSection> parse_checkpoints_section(const toml::node& node,
                                                              formats::Diagnostics& diag);

/// The [checkpoints] section of a loaded config (nullptr if absent).
const CheckpointsSection* checkpoints_section(const config::Config& config);

}  // namespace nccomp::daemon::sections
