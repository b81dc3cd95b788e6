// One `nccomp calibrate` session: runs commands (script.hpp) against a core Calibrator on a
// simulated clock and reports every result, alarm, register write and measurement record to a
// stream. The same code serves the interactive prompt and script files.
#pragma once

#include <array>
#include <cstddef>
#include <ostream>
#include <string>

#include "core/calib/calibrator.hpp"
#include "core/calib/snapshot.hpp"
#include "core/common/output.hpp"
#include "formats/calib/script.hpp"

namespace nccomp::tools::calibrate {

// The command language, its errors and the operator text are formats (formats/calib), shared with
// the daemon's calibrate verb.
using namespace formats::calib;

class Session {
 public:
  /// wall_clock_at_zero_s: the wall-clock time [Unix s] of the session's time 0 (state times).
  Session(const core::calib::CalibrationConfig& config, double wall_clock_at_zero_s,
          std::ostream& out);

  /// Adopts a state saved by an earlier session or the daemon (throws std::invalid_argument).
  void import_state_text(const std::string& text);
  [[nodiscard]] std::string export_state_text() const;

  /// Runs one command; throws ScriptError(line_no, ...) for a command that cannot run now
  /// (time going backwards). Returns false after quit.
  bool run(const Command& command, std::size_t line_no);

  /// What the operator should do next, one line.
  [[nodiscard]] std::string hint() const;
  /// The calibrator as the daemon would publish it (the renderer's input).
  [[nodiscard]] core::calib::CalibSnapshot snapshot() const;
  [[nodiscard]] const core::calib::Calibrator& calibrator() const noexcept { return calib_; }
  [[nodiscard]] double time_s() const noexcept { return core::seconds(now_ns_); }
  /// Alarms (severity alarm) reported so far.
  [[nodiscard]] std::size_t alarm_count() const noexcept { return alarms_; }

 private:
  void step(std::span<const core::Event> events);
  void report(bool summarise_writes);
  void print_status();
  void enter_facets(core::calib::Face face, double chord_plus_mm, double chord_minus_mm);

  core::calib::Calibrator calib_;
  std::ostream& out_;
  core::TimeNs now_ns_{0};
  core::StepOutput output_;
  std::size_t alarms_{0};
  // Writes during a wait are summarised: count and last value per register.
  std::size_t pending_writes_{0};
  std::array<double, 3> last_written_{};
};

}  // namespace nccomp::tools::calibrate
