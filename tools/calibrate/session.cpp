#include "tools/calibrate/session.hpp"

#include <fmt/format.h>
#include <cmath>

#include <variant>

#include "core/calib/state.hpp"

namespace nccomp::tools::calibrate {

namespace {

using core::AlarmCode;
using core::calib::Phase;
using core::calib::Slot;

const char* alarm_name(AlarmCode code) {
  switch (code) {
    case AlarmCode::kOffsetNonFinite:
      return "offset-non-finite";
    case AlarmCode::kOffsetBeyondAbsoluteLimit:
      return "offset-beyond-absolute-limit";
    case AlarmCode::kOffsetSlewLimited:
      return "offset-slew-limited";
    case AlarmCode::kRecalibrationImplausible:
      return "recalibration-implausible";
    case AlarmCode::kTouchScatter:
      return "touch-scatter";
    case AlarmCode::kRecalibrationDue:
      return "recalibration-due";
    case AlarmCode::kTouchSetIncomplete:
      return "touch-set-incomplete";
    case AlarmCode::kCalibrationOutOfRange:
      return "calibration-out-of-range";
    case AlarmCode::kTouchUnexpected:
      return "touch-unexpected";
    case AlarmCode::kTestGrindNotConverging:
      return "test-grind-not-converging";
    case AlarmCode::kRecalibrationApplied:
      return "recalibration-applied";
    case AlarmCode::kCalibrationComplete:
      return "calibration-complete";
    case AlarmCode::kCalibrationInvalidInput:
      return "calibration-invalid-input";
    default:
      return "other";
  }
}

const char* severity_name(core::Severity s) {
  switch (s) {
    case core::Severity::kInfo:
      return "info";
    case core::Severity::kWarning:
      return "WARNING";
    case core::Severity::kAlarm:
      return "ALARM";
  }
  return "?";
}

const char* axis_name(std::int32_t a) {
  switch (a) {
    case 0:
      return "X";
    case 1:
      return "Y";
    case 2:
      return "Z";
    default:
      return "-";
  }
}

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
    const std::int32_t subject = a.subject;
    out_ << fmt::format("  {} {} {}", severity_name(a.severity), static_cast<int>(a.code),
                        alarm_name(a.code));
    if (a.code == AlarmCode::kOffsetSlewLimited || a.code == AlarmCode::kOffsetNonFinite ||
        a.code == AlarmCode::kOffsetBeyondAbsoluteLimit) {
      out_ << fmt::format(" register {}: target {:+.3f} um", subject, a.value);
    } else if (a.code == AlarmCode::kRecalibrationDue) {
      out_ << fmt::format(": {:.0f} s since the last touch set", a.value);
    } else if (a.code == AlarmCode::kTouchSetIncomplete) {
      out_ << fmt::format(": {:.0f} touches discarded", a.value);
    } else {
      out_ << fmt::format(" axis {}: {:+.3f}", axis_name(subject), a.value);
    }
    if (a.code == AlarmCode::kRecalibrationImplausible || a.code == AlarmCode::kTouchScatter) {
      out_ << " um, nothing applied";
    }
    out_ << '\n';
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
            throw ScriptError(line_no,
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
          out_ << fmt::format(
              "[{:9.1f} s] waited {:.0f} s, {} register writes; X {:+.3f} Y {:+.3f} "
              "Z {:+.3f} um\n",
              time_s(), c.duration_s, pending_writes_, last_written_[0], last_written_[1],
              last_written_[2]);
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
          const auto& r = calib_.result();
          if (before == Phase::kReferenceTouches && calib_.phase() == Phase::kTestGrindLateral) {
            out_ << fmt::format(
                "  reference touches: dx lateral {:+.3f} um, dx axial {:+.3f} um (pivot D "
                "{:+.3f} um), dy {:+.3f} um, dz {:+.3f} um\n",
                r.dx_touch_lateral_um, r.dx_touch_axial_um,
                r.dx_touch_axial_um - r.dx_touch_lateral_um, r.dy_touch_um, r.dz_touch_um);
          }
          if (before == Phase::kNominalTouches && calib_.phase() == Phase::kReady) {
            out_ << "  nominals stored:";
            for (const auto s : {Slot::kXLateral, Slot::kXAxial, Slot::kY, Slot::kZ}) {
              out_ << fmt::format(" {:.4f}", calib_.nominal(s).position_mm);
            }
            out_ << " mm (X lateral, X axial, Y, Z)\n";
          }
        } else if constexpr (std::is_same_v<T, CmdFacets>) {
          output_.clear();
          const auto res =
              calib_.enter_facets(c.face, c.chord_plus_mm, c.chord_minus_mm, now_ns_, output_);
          out_ << fmt::format("[{:9.1f} s] facets {}: c+ {:.4f} mm, c- {:.4f} mm -> {}", t,
                              c.face == core::calib::Face::kLateral ? "lateral" : "end-face",
                              c.chord_plus_mm, c.chord_minus_mm,
                              core::calib::to_string(res.status));
          if (std::isfinite(res.error_um)) {
            out_ << fmt::format(", error {:+.3f} um ({} rule), grind {}", res.error_um,
                                core::calib::to_string(calib_.config().facet_rule), res.grinds);
          }
          if (res.status == core::calib::FacetStatus::kGrindAgain) {
            out_ << fmt::format("; grind again with dx {:+.3f} um", res.correction_um);
          } else if (res.status == core::calib::FacetStatus::kConverged) {
            out_ << fmt::format("; {} = {:+.3f} um",
                                c.face == core::calib::Face::kLateral ? "dxR" : "dxA",
                                res.correction_um);
          }
          out_ << '\n';
          report(false);
          if (calib_.phase() == Phase::kNominalTouches) {
            const auto& r = calib_.result();
            out_ << fmt::format(
                "  calibration: dxR {:+.3f} um, dxA {:+.3f} um, dy {:+.3f} um, dz {:+.3f} um; "
                "probe lateral {:+.3f} um, probe axial {:+.3f} um, pivot D {:+.3f} um; grinds "
                "{} + {}\n",
                r.dx_r_um, r.dx_a_um, r.dy_um, r.dz_um, r.probe_lateral_um, r.probe_axial_um,
                r.pivot_um, r.lateral_grinds, r.end_face_grinds);
          }
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

std::string Session::hint() const {
  const auto& cfg = calib_.config();
  const auto p = calib_.touch_progress();
  const auto progress = [&] {
    return fmt::format("X lateral {}/{}, X axial {}/{}, Y {}/{}, Z {}/{}", p.count[0], p.required,
                       p.count[1], p.required, p.count[2], p.required, p.count[3], p.required);
  };
  switch (calib_.phase()) {
    case Phase::kUncalibrated:
      return "not calibrated: 'begin' starts an initial calibration";
    case Phase::kReferenceTouches:
      return "touch the reference disk with the reference probe (" + progress() + ")";
    case Phase::kTestGrindLateral:
      return fmt::format(
          "grind the blank from +X and -X with dx {:+.3f} um, then 'facets "
          "lateral <c+ mm> <c- mm>'",
          calib_.grind_correction_um());
    case Phase::kTestGrindEndFace:
      return fmt::format(
          "grind the end face from +X and -X with dx {:+.3f} um, then 'facets "
          "end-face <c+ mm> <c- mm>'",
          calib_.grind_correction_um());
    case Phase::kNominalTouches:
      return "touch the test body with the machine probe, X twice (A at 90 deg for axial) (" +
             progress() + ")";
    case Phase::kReady:
      return fmt::format("calibrated; machine-probe touches recalibrate (set: {}; interval {} s)",
                         progress(), cfg.recalibration_interval_s);
  }
  return "";
}

void Session::print_status() {
  const auto& r = calib_.result();
  out_ << fmt::format("[{:9.1f} s] phase {}\n", time_s(), core::calib::to_string(calib_.phase()));
  out_ << fmt::format("  calibration: dxR {:+.3f} dxA {:+.3f} dy {:+.3f} dz {:+.3f} um\n",
                      r.dx_r_um, r.dx_a_um, r.dy_um, r.dz_um);
  const char* names[] = {"X lateral", "X axial", "Y", "Z"};
  for (std::size_t s = 0; s < core::calib::kSlotCount; ++s) {
    const auto slot = static_cast<Slot>(s);
    const auto& n = calib_.nominal(slot);
    const auto& m = calib_.model(slot);
    if (n.valid == 1) {
      out_ << fmt::format(
          "  {:9}: nominal {:.4f} mm, last drift {:+.3f} um ({} sets), predicted {:+.3f} um, "
          "in force {:+.3f} um",
          names[s], n.position_mm, m.anchor_drift_um, m.touch_sets,
          calib_.predicted_drift_um(slot, now_ns_), calib_.drift_correction_um(slot, now_ns_));
      if (std::isfinite(n.temp_c)) {
        out_ << fmt::format(", slope {:+.3f} um/degC (nominal at {:.2f} degC)", m.slope_um_per_c,
                            n.temp_c);
      }
      out_ << '\n';
    }
  }
  for (std::size_t a = 0; a < 3; ++a) {
    out_ << fmt::format("  register {} ({}): target {:+.3f} um, written {:+.3f} um\n",
                        a == 0 ? calib_.config().register_x
                               : (a == 1 ? calib_.config().register_y : calib_.config().register_z),
                        axis_name(static_cast<std::int32_t>(a)), calib_.target_um(a, now_ns_),
                        calib_.written_um(a));
  }
}

}  // namespace nccomp::tools::calibrate
