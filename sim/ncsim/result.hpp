// The machined result directory (contract C3): result.json, surface.csv / walls.csv +
// checkpoints.csv / touches.csv, measurements.csv, writes.csv, end_state.toml. Not real-time.
#pragma once

#include <string>
#include <vector>

#include "sim/ncsim/simulation.hpp"

namespace nccomp::sim::ncsim {

struct RunInfo {
  ProgramKind program{ProgramKind::kMouldFace};
  BusKind bus{BusKind::kModbus};
  /// Writes the bus side refused before they reached the registers (Modbus exception 3).
  std::uint64_t refused_on_bus{0};
};

/// Writes every file of the result into dir (created if missing). Throws std::runtime_error.
void write_result(const std::string& dir, const Simulation& sim, const RunInfo& info);

/// `ncsim --continue DIR`: the --set overrides that start a run where the run in DIR ended
/// (DIR/end_state.toml: ncsim.first_part, ncsim.tool_cut_path_mm). Throws formats::DiagnosticsError
/// naming the file and the key.
std::vector<std::string> continuation_overrides(const std::string& dir);

/// The effects as result.json shows them: {"wear": {"enabled": true, ...}, ...}.
std::string effects_json(const EffectsConfig& e);

}  // namespace nccomp::sim::ncsim
