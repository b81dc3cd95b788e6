#include "daemon/commands/calibrate.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <cctype>
#include <chrono>
#include <thread>
#include <type_traits>
#include <variant>

#include "client/protocol.hpp"
#include "core/calib/state.hpp"
#include "daemon/sections/calibration/daemon_link.hpp"
#include "formats/calib/render.hpp"
#include "formats/calib/script.hpp"

namespace nccomp::daemon::commands {

namespace cal = core::calib;
namespace tc = formats::calib;

namespace {

using core::OperatorCommand;
using core::OperatorCommandKind;

std::uint32_t next_sequence() {
  static std::uint32_t seq = 0;  // the command thread only
  return ++seq;
}

std::string first_line(const cal::CalibSnapshot& s) {
  return fmt::format("ok {} {}\n", cal::to_string(s.state.phase), cal::to_string(s.request));
}

}  // namespace

std::string handle_calibrate_command(std::string_view args, CommandContext& ctx) {
  if (ctx.bus == nullptr) {
    return refuse(ctx, "this process takes no operator commands");
  }
  if (args.size() > 400) {
    return refuse(ctx, "calibrate: command longer than 400 characters");
  }
  const cal::CalibSnapshot before = sections::latest_calibration_snapshot();
  if (before.publishes == 0) {
    return refuse(ctx,
                  "calibrate: no calibration module is running (no [calibration] section in the "
                  "daemon's configuration, or its loop has not started)",
                  false);
  }
  tc::Command cmd;
  try {
    cmd = tc::parse_line(args, 1);
  } catch (const tc::ScriptError& e) {
    return refuse(ctx, "calibrate: " + e.diagnostic().message);
  }
  OperatorCommand oc;
  oc.sequence = next_sequence();
  std::string echo;
  const std::string_view verb = args.substr(0, args.find(' '));
  bool handled = std::visit(
      [&](const auto& c) -> bool {
        using T = std::decay_t<decltype(c)>;
        if constexpr (std::is_same_v<T, tc::CmdEmpty>) {
          oc.kind = OperatorCommandKind::kCalibrationStatus;
          return true;
        } else if constexpr (std::is_same_v<T, tc::CmdBegin>) {
          oc.kind = OperatorCommandKind::kCalibrationBegin;
          echo = "initial calibration started\n";
          return true;
        } else if constexpr (std::is_same_v<T, tc::CmdFacets>) {
          oc.kind = OperatorCommandKind::kCalibrationFacets;
          oc.code[0] = c.face == cal::Face::kLateral ? 0 : 1;
          oc.value = {c.chord_plus_mm, c.chord_minus_mm};
          return true;
        } else if constexpr (std::is_same_v<T, tc::CmdDiscard>) {
          oc.kind = OperatorCommandKind::kCalibrationDiscard;
          echo = "touch set discarded\n";
          return true;
        } else if constexpr (std::is_same_v<T, tc::CmdRecalibrate>) {
          oc.kind = OperatorCommandKind::kCalibrationRecalibrate;
          return true;
        } else if constexpr (std::is_same_v<T, tc::CmdTouch>) {
          oc.kind = OperatorCommandKind::kCalibrationTouch;
          const auto& t = c.touch;
          oc.code = {static_cast<std::int8_t>(t.probe == core::ProbeKind::kReferenceProbe ? 1 : 0),
                     static_cast<std::int8_t>(t.axis), t.direction,
                     static_cast<std::int8_t>(t.variant)};
          oc.value = {t.trigger_position_mm, 0.0};
          echo = fmt::format("touch {} {}{} {} at {:.4f} mm\n",
                             t.probe == core::ProbeKind::kReferenceProbe ? "reference" : "machine",
                             tc::axis_name(t.axis), t.direction > 0 ? "+" : "-",
                             t.variant == 1 ? "axial" : "lateral", t.trigger_position_mm);
          return true;
        } else if constexpr (std::is_same_v<T, tc::CmdStatus>) {
          oc.kind = OperatorCommandKind::kCalibrationStatus;
          return true;
        } else {
          return false;  // time, wait, temperature, facets-file, await, help, quit
        }
      },
      cmd);
  if (!handled) {
    return refuse(ctx, "calibrate: '" + std::string(verb) +
                           "' is not a daemon command (time and temperature are offline only; "
                           "wait, await, facets-file, help and quit are handled by the client)");
  }
  if (!ctx.bus->push(oc)) {
    return refuse(ctx, "calibrate: the loop does not take commands (its queue is full)");
  }
  // The loop runs it at its next cycle and publishes the outcome under its sequence number.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  cal::CalibSnapshot s = sections::latest_calibration_snapshot();
  while (s.last_command.sequence != oc.sequence) {
    if (std::chrono::steady_clock::now() > deadline) {
      return refuse(ctx,
                    "calibrate: no answer from the loop within 5 s (is it running, or in "
                    "lock-step waiting for the NC?)");
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
    s = sections::latest_calibration_snapshot();
  }
  const auto& o = s.last_command;
  std::string body;
  const auto phase_now = s.state.phase;
  if (o.status == cal::CommandStatus::kOk) {
    if (oc.kind == OperatorCommandKind::kCalibrationFacets) {
      body += tc::facet_line(oc.code[0] == 0 ? cal::Face::kLateral : cal::Face::kEndFace,
                             oc.value[0], oc.value[1], o.facet, s.facet_rule);
    } else if (oc.kind == OperatorCommandKind::kCalibrationRecalibrate) {
      body +=
          "recalibration requested: the next machine-probe touch set recalibrates (request "
          "register: " +
          std::string(cal::to_string(s.request)) + ")\n";
    } else {
      body += echo;
    }
    if (std::holds_alternative<tc::CmdStatus>(cmd)) {
      body += tc::status_block(s, "[" + tc::format_utc(s.wall_time_s) + "]");
      body += fmt::format(
          "  commands: {} taken by the calibrator, {} refused by it, {} refused by the daemon\n",
          s.commands_taken, s.commands_refused, ctx.bus->refused());
    }
  }
  for (std::uint32_t i = 0; i < o.alarm_count && i < o.alarms.size(); ++i) {
    body += tc::alarm_line(o.alarms[i]);
  }
  if (o.phase_before == cal::Phase::kReferenceTouches &&
      phase_now == cal::Phase::kTestGrindLateral) {
    body += tc::reference_line(s.state.result);
  }
  if ((o.phase_before == cal::Phase::kTestGrindLateral ||
       o.phase_before == cal::Phase::kTestGrindEndFace) &&
      phase_now == cal::Phase::kNominalTouches) {
    body += tc::calibration_line(s.state.result);
  }
  if (o.phase_before == cal::Phase::kNominalTouches && phase_now == cal::Phase::kReady) {
    body += tc::nominals_line(s.state);
  }
  const std::string line(args);
  if (o.status != cal::CommandStatus::kOk) {
    std::string why = fmt::format("calibrate {}: {} (phase {})", line, cal::to_string(o.status),
                                  cal::to_string(o.phase_before));
    if (oc.kind == OperatorCommandKind::kCalibrationFacets &&
        o.status == cal::CommandStatus::kInvalidInput) {
      why += ": chords must be finite and in (0, 2 x blank_radius_mm]";
    }
    spdlog::warn("operator command #{} refused by the calibrator: {}", oc.sequence, why);
    return "error: " + why + "\n" + body + "-- " + tc::hint(s) + "\n";
  }
  if (oc.kind != OperatorCommandKind::kCalibrationStatus) {
    spdlog::info("operator command #{}: calibrate {} -> phase {}", oc.sequence, line,
                 cal::to_string(phase_now));
  }
  return first_line(s) + body + "-- " + tc::hint(s) + "\n";
}

CommandAccess calibrate_access(std::string_view args) noexcept {
  // Words are case-insensitive in the script language (formats/calib/script.cpp).
  const auto is_status = [](std::string_view a) {
    constexpr std::string_view kStatus = "status";
    if (a.size() != kStatus.size()) return false;
    for (std::size_t i = 0; i < a.size(); ++i) {
      if (std::tolower(static_cast<unsigned char>(a[i])) != kStatus[i]) return false;
    }
    return true;
  };
  return args.empty() || is_status(args) ? CommandAccess::kReadOnly
                                         : CommandAccess::kChangesMachine;
}

namespace {
[[maybe_unused]] const int kVerb = register_command_handler(
    std::string(client::kCalibrateVerb), handle_calibrate_command, &calibrate_access);
}  // namespace

}  // namespace nccomp::daemon::commands
