#include "tools/calibrate/session.hpp"

#include <fmt/format.h>
#include <cmath>

#include <variant>

#include "core/calib/snapshot.hpp"
#include "core/calib/state.hpp"
#include "formats/calib/facet_import.hpp"
#include "formats/calib/render.hpp"

namespace nccomp::tools::calibrate {

namespace {

using core::AlarmCode;
using core::calib::Phase;

}  // namespace

Session::Session(const core::calib::CalibrationConfig& config, double wall_clock_at_zero_s,
                 std::ostream& out)
    : out_(out) {
  calib_.configure(config);
  calib_.set_clock_offset_s(wall_clock_at_zero_s);
  last_written_.fill(core::kNaN);
}

void Session::import_state_text(const std::string& text) {
  calib_.import_state(core::calib::from_text(text));
  // Offline there is no NC to read back: assume it holds the corrections the saved state
  // implies, so the session does not slew the registers from zero again.
  for (std::size_t a = 0; a < 3; ++a) {
    if (std::isfinite(calib_.target_um(a, now_ns_))) {
      calib_.sync_register(a, calib_.target_um(a, now_ns_), now_ns_);
    }
  }
}

std::string Session::export_state_text() const {
  return core::calib::to_text(calib_.export_state());
}

void Session::step(std::span<const core::Event> events) {
  output_.clear();
  calib_.step(now_ns_, events, output_);
}

void Session::report(bool summarise_writes) {
  const auto& cfg = calib_.config();
  for (const auto& a : output_.alarms) {
    if (a.severity == core::Severity::kAlarm) {
      ++alarms_;
    }
    out_ << alarm_line(a);
  }
  for (const auto& r : output_.records) {
    const auto axis = static_cast<std::size_t>(r.point);
    out_ << fmt::format("  record calib {} trigger {:.4f} mm measured {:+.3f} um",
                        axis_name(r.point), r.position_mm[axis], r.measured_um);
    if (std::isfinite(r.temp_c)) {
      out_ << fmt::format(" at {:.2f} degC", r.temp_c);
    }
    out_ << '\n';
  }
  const std::array<std::uint16_t, 3> reg{cfg.register_x, cfg.register_y, cfg.register_z};
  for (const auto& w : output_.writes) {
    if (cfg.request_register >= 0 &&
        w.register_index == static_cast<std::uint16_t>(cfg.request_register)) {
      const auto code = static_cast<core::calib::RequestCode>(static_cast<int>(w.value_um));
      out_ << fmt::format("  request register {} = {} ({})\n", w.register_index, w.value_um,
                          core::calib::to_string(code));
      continue;
    }
    for (std::size_t a = 0; a < 3; ++a) {
      if (w.register_index == reg[a]) {
        last_written_[a] = w.value_um;
      }
    }
    if (summarise_writes) {
      ++pending_writes_;
    } else {
      out_ << fmt::format("  write register {} = {:+.3f} um\n", w.register_index, w.value_um);
    }
  }
}

bool Session::run(const Command& command, std::size_t line_no) {
  const double t = time_s();
  return std::visit(
      [&](const auto& c) -> bool {
        using T = std::decay_t<decltype(c)>;
        if constexpr (std::is_same_v<T, CmdEmpty>) {
          return true;
        } else if constexpr (std::is_same_v<T, CmdTime>) {
          if (c.time_s < t) {
            throw ScriptError(line_no, 0,
                              fmt::format("time {} s is before the current {} s", c.time_s, t));
          }
          now_ns_ = core::from_seconds(c.time_s);
          step({});
          report(false);
        } else if constexpr (std::is_same_v<T, CmdWait>) {
          pending_writes_ = 0;
          const auto end = now_ns_ + core::from_seconds(c.duration_s);
          while (now_ns_ < end) {
            now_ns_ = std::min(end, now_ns_ + core::from_seconds(1.0));
            step({});
            report(true);
          }
          // "-" for a register not written yet (a test grind writes X only).
          const auto um = [](double v) {
            return std::isfinite(v) ? fmt::format("{:+.3f}", v) : std::string("-");
          };
          out_ << fmt::format(
              "[{:9.1f} s] waited {:.0f} s, {} register writes; X {} Y {} Z {} um\n", time_s(),
              c.duration_s, pending_writes_, um(last_written_[0]), um(last_written_[1]),
              um(last_written_[2]));
          return true;
        } else if constexpr (std::is_same_v<T, CmdTemperature>) {
          const core::Event e = core::TemperatureSample{now_ns_, c.sensor, c.temperature_c};
          step({&e, 1});
          out_ << fmt::format("[{:9.1f} s] temperature sensor {} = {:.2f} degC{}\n", t, c.sensor,
                              c.temperature_c,
                              static_cast<int>(c.sensor) == calib_.config().temperature_sensor
                                  ? ""
                                  : " (not the mapped sensor, ignored)");
          report(false);
        } else if constexpr (std::is_same_v<T, CmdBegin>) {
          output_.clear();
          calib_.begin_calibration(now_ns_, output_);
          out_ << fmt::format("[{:9.1f} s] initial calibration started\n", t);
          report(false);
        } else if constexpr (std::is_same_v<T, CmdTouch>) {
          const Phase before = calib_.phase();
          core::CalibrationTouch touch = c.touch;
          touch.time_ns = now_ns_;
          const core::Event e = touch;
          step({&e, 1});
          out_ << fmt::format(
              "[{:9.1f} s] touch {} {}{} {} at {:.4f} mm\n", t,
              touch.probe == core::ProbeKind::kReferenceProbe ? "reference" : "machine",
              axis_name(touch.axis), touch.direction > 0 ? "+" : "-",
              touch.variant == 1 ? "axial" : "lateral", touch.trigger_position_mm);
          report(false);
          if (before == Phase::kReferenceTouches && calib_.phase() == Phase::kTestGrindLateral) {
            out_ << reference_line(calib_.result());
          }
          if (before == Phase::kNominalTouches && calib_.phase() == Phase::kReady) {
            out_ << nominals_line(calib_.export_state());
          }
        } else if constexpr (std::is_same_v<T, CmdFacets>) {
          enter_facets(c.face, c.chord_plus_mm, c.chord_minus_mm);
        } else if constexpr (std::is_same_v<T, CmdFacetsFile>) {
          std::vector<FacetMeasurement> rows;
          try {
            rows = read_facet_export(c.path);
          } catch (const std::invalid_argument& e) {
            throw ScriptError(line_no, 0, e.what());
          }
          if (c.row > rows.size()) {
            throw ScriptError(line_no, 0,
                              fmt::format("{}: has {} rows, not {}", c.path, rows.size(), c.row));
          }
          const FacetMeasurement& m = rows[c.row == 0 ? rows.size() - 1 : c.row - 1];
          out_ << fmt::format("[{:9.1f} s] from {} line {}:\n", t, c.path, m.line);
          enter_facets(m.face, m.chord_plus_mm, m.chord_minus_mm);
        } else if constexpr (std::is_same_v<T, CmdRecalibrate>) {
          const bool ok = calib_.request_recalibration();
          out_ << fmt::format("[{:9.1f} s] recalibration {}\n", t,
                              ok ? "requested: the next machine-probe touch set recalibrates"
                                 : "refused: not calibrated (phase " +
                                       std::string(core::calib::to_string(calib_.phase())) + ")");
          step({});
          report(false);
        } else if constexpr (std::is_same_v<T, CmdAwait>) {
          throw ScriptError(line_no, 0,
                            "await needs --daemon (offline the clock moves only with time and "
                            "wait)");
        } else if constexpr (std::is_same_v<T, CmdStatus>) {
          print_status();
        } else if constexpr (std::is_same_v<T, CmdDiscard>) {
          calib_.discard_touch_set();
          out_ << fmt::format("[{:9.1f} s] touch set discarded\n", t);
        } else if constexpr (std::is_same_v<T, CmdHelp>) {
          out_ << script_help();
        } else if constexpr (std::is_same_v<T, CmdQuit>) {
          return false;
        }
        return true;
      },
      command);
}

void Session::enter_facets(core::calib::Face face, double chord_plus_mm, double chord_minus_mm) {
  output_.clear();
  const auto res = calib_.enter_facets(face, chord_plus_mm, chord_minus_mm, now_ns_, output_);
  out_ << fmt::format("[{:9.1f} s] ", time_s())
       << facet_line(face, chord_plus_mm, chord_minus_mm, res, calib_.config().facet_rule);
  report(false);
  if (calib_.phase() == Phase::kNominalTouches) {
    out_ << calibration_line(calib_.result());
  }
}

core::calib::CalibSnapshot Session::snapshot() const {
  core::calib::CalibSnapshot s;
  core::calib::make_snapshot(calib_, now_ns_, s);
  return s;
}

std::string Session::hint() const { return calibrate::hint(snapshot()); }

void Session::print_status() {
  out_ << status_block(snapshot(), fmt::format("[{:9.1f} s]", time_s()));
}

}  // namespace nccomp::tools::calibrate
