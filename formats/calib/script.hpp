// The `nccomp calibrate` command language: one command per line, the same typed at the
// interactive prompt or read from a script file (docs/calibration.md, "Script commands").
//
//   time <s>                                    set the clock [s] (never backwards)
//   wait <s>                                    let time pass, stepping once per second
//   temperature <sensor> <°C>                   a temperature sample
//   begin                                       start an initial calibration
//   touch reference|machine x|y|z +|- [lateral|axial] <trigger_mm>
//   facets lateral|end-face <chord_plus_mm> <chord_minus_mm>
//   facets-file <path> [row]                    chords from a measuring device's export
//   recalibrate                                 ask for a recalibration touch cycle now
//   await <phase> [timeout_s]                   (--daemon) wait until the daemon is in <phase>
//   status | discard | help | quit
//
// '#' starts a comment; blank lines are ignored.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <variant>

#include "core/calib/calibrator.hpp"
#include "core/common/types.hpp"
#include "formats/toml/diagnostics.hpp"

namespace nccomp::formats::calib {

struct CmdTime {
  double time_s{0.0};
};
struct CmdWait {
  double duration_s{0.0};
};
struct CmdTemperature {
  std::uint8_t sensor{0};
  double temperature_c{0.0};
};
struct CmdBegin {};
struct CmdTouch {
  core::CalibrationTouch touch{};
};
struct CmdFacets {
  core::calib::Face face{core::calib::Face::kLateral};
  double chord_plus_mm{0.0};
  double chord_minus_mm{0.0};
};
/// A measuring device's export (facet_import.hpp); row 0 = the last row, else 1-based.
struct CmdFacetsFile {
  std::string path;
  std::size_t row{0};
};
struct CmdRecalibrate {};
struct CmdAwait {
  core::calib::Phase phase{core::calib::Phase::kReady};
  double timeout_s{600.0};
};
struct CmdStatus {};
struct CmdDiscard {};
struct CmdHelp {};
struct CmdQuit {};
struct CmdEmpty {};

using Command =
    std::variant<CmdEmpty, CmdTime, CmdWait, CmdTemperature, CmdBegin, CmdTouch, CmdFacets,
                 CmdStatus, CmdDiscard, CmdHelp, CmdQuit, CmdFacetsFile, CmdRecalibrate, CmdAwait>;

/// A malformed line, or a command that cannot run now, as the one diagnostics type: one
/// Diagnostic with the line, the column of the offending word (0 where the whole line is meant)
/// and the reason, and no file: the caller names the script with in_file(). what() is "line N,
/// column C: reason" (for a prompt, which has no file).
class ScriptError : public formats::DiagnosticsError {
 public:
  ScriptError(std::size_t line, std::size_t column, std::string why);
  [[nodiscard]] const formats::Diagnostic& diagnostic() const noexcept;
  /// "file:line:column: reason".
  [[nodiscard]] std::string in_file(std::string_view file) const;
  [[nodiscard]] const char* what() const noexcept override { return text_.c_str(); }

 private:
  std::string text_;
};

/// Parses one line; throws ScriptError naming the line and the offending word's column.
Command parse_line(std::string_view line, std::size_t line_no);

/// The help text listing the commands.
const char* script_help() noexcept;

/// Phase by its name ("ready", "test-grind-lateral", ...); false if unknown.
bool parse_phase(std::string_view name, core::calib::Phase& out) noexcept;

}  // namespace nccomp::formats::calib
