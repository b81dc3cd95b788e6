#include "daemon/sections/calibration/daemon_link.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <time.h>

#include <atomic>
#include <cctype>
#include <chrono>
#include <cmath>
#include <fstream>
#include <sstream>
#include <thread>
#include <variant>

#include "core/calib/state.hpp"
#include "core/rt/seqlock.hpp"
#include "tools/calibrate/render.hpp"
#include "tools/calibrate/script.hpp"

namespace nccomp::daemon::sections {

namespace cal = core::calib;
namespace tc = tools::calibrate;

namespace {

double clock_s(clockid_t id) {
  timespec ts{};
  clock_gettime(id, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

struct Clock {
  std::atomic<bool> set{false};
  std::atomic<double> offset_s{0.0};
};
Clock& clock_origin() {
  static Clock c;
  return c;
}

class SeqlockSink final : public cal::SnapshotSink {
 public:
  void publish(const cal::CalibSnapshot& s) noexcept override { lock_.store(s); }
  [[nodiscard]] cal::CalibSnapshot load() const noexcept { return lock_.load(); }

 private:
  core::rt::Seqlock<cal::CalibSnapshot> lock_;
};

SeqlockSink& sink() {
  static SeqlockSink s;
  return s;
}

// The newer of two states: the later calibration, then the later touch set.
bool newer(const cal::CalibState& a, const cal::CalibState& b) {
  const auto key = [](const cal::CalibState& s) {
    return std::pair{std::isfinite(s.result.time_s) ? s.result.time_s : -1e300,
                     std::isfinite(s.last_set_time_s) ? s.last_set_time_s : -1e300};
  };
  return key(a) > key(b);
}

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    throw std::invalid_argument("cannot be read");
  }
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

}  // namespace

double calibration_clock_offset_s() {
  auto& c = clock_origin();
  if (c.set.load()) {
    return c.offset_s.load();
  }
  return clock_s(CLOCK_REALTIME) - clock_s(CLOCK_MONOTONIC);
}

cal::SnapshotSink& calibration_snapshot_sink() { return sink(); }

cal::CalibSnapshot latest_calibration_snapshot() { return sink().load(); }

std::vector<std::string> calibration_startup(core::engine::Engine& engine,
                                             const RegisterReader& read, core::TimeNs now_ns,
                                             double wall_now_s) {
  std::vector<std::string> lines;
  // The loop's clock at start-up is now_ns: monotonic, or 0 in lock-step (the peer's clock).
  const double offset = wall_now_s - core::seconds(now_ns);
  clock_origin().offset_s.store(offset);
  clock_origin().set.store(true);
  for (std::size_t m = 0; m < engine.module_count(); ++m) {
    auto* mod = dynamic_cast<cal::CalibrationModule*>(&engine.module(m));
    if (mod == nullptr) continue;
    const std::string name(mod->name());
    mod->rebase_clock(offset);
    auto& c = mod->calibrator();
    const auto held = c.export_state();
    if (held.phase != cal::Phase::kUncalibrated) {
      lines.push_back(fmt::format(
          "{}: resumed phase {}, calibrated {}, last touch set {}, {} recalibrations in the "
          "history",
          name, cal::to_string(held.phase), tc::format_utc(held.result.time_s),
          tc::format_utc(held.last_set_time_s), held.history_count));
    }
    const std::string& file = c.config().state_file;
    if (!file.empty()) {
      try {
        const cal::CalibState offline = cal::from_text(read_text(file));
        cal::validate(offline);
        if (held.phase == cal::Phase::kUncalibrated || newer(offline, held)) {
          c.import_state(offline);
          mod->mark_changed();
          lines.push_back(fmt::format(
              "{}: adopted the calibration of {} (phase {}, calibrated {}, last touch set {})",
              name, file, cal::to_string(offline.phase), tc::format_utc(offline.result.time_s),
              tc::format_utc(offline.last_set_time_s)));
        } else {
          lines.push_back(fmt::format(
              "{}: {} is not newer than the calibration the daemon holds; kept the daemon's", name,
              file));
        }
      } catch (const std::exception& e) {
        lines.push_back(fmt::format("{}: state_file {} refused: {}; the daemon's own state is kept",
                                    name, file, e.what()));
      }
    }
    // What the NC holds: program-coordinate touches are corrected by it, and the limiter slews
    // from it (never from 0).
    const std::array<std::uint16_t, 3> reg{c.config().register_x, c.config().register_y,
                                           c.config().register_z};
    std::string back;
    for (std::size_t a = 0; a < 3; ++a) {
      const auto v = read ? read(reg[a]) : std::optional<double>{};
      if (v && std::isfinite(*v)) {
        c.sync_register(a, *v, now_ns);
        back += fmt::format(" {} {:+.3f}", tc::axis_name(static_cast<std::int32_t>(a)), *v);
      }
    }
    lines.push_back(back.empty()
                        ? name +
                              ": axis registers cannot be read back; the limiter continues "
                              "from the values saved in the state"
                        : name + ": axis registers read back from the NC:" + back + " um");
  }
  return lines;
}

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

std::string refused(CommandContext& ctx, const std::string& why, bool count = true) {
  if (count && ctx.bus != nullptr) ctx.bus->count_refused();
  spdlog::warn("operator command refused: {}", why);
  return "error: " + why + "\n";
}

std::string strip_line_prefix(std::string what) {
  if (what.rfind("line 1: ", 0) == 0) what.erase(0, 8);
  return what;
}

}  // namespace

std::string handle_calibrate_command(std::string_view args, CommandContext& ctx) {
  if (ctx.bus == nullptr) {
    return refused(ctx, "this process takes no operator commands");
  }
  if (args.size() > 400) {
    return refused(ctx, "calibrate: command longer than 400 characters");
  }
  const cal::CalibSnapshot before = sink().load();
  if (before.publishes == 0) {
    return refused(ctx,
                   "calibrate: no calibration module is running (no [calibration] section in the "
                   "daemon's configuration, or its loop has not started)",
                   false);
  }
  tc::Command cmd;
  try {
    cmd = tc::parse_line(args, 1);
  } catch (const tc::ScriptError& e) {
    return refused(ctx, "calibrate: " + strip_line_prefix(e.what()));
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
    return refused(ctx, "calibrate: '" + std::string(verb) +
                            "' is not a daemon command (time and temperature are offline only; "
                            "wait, await, facets-file, help and quit are handled by the client)");
  }
  if (!ctx.bus->push(oc)) {
    return refused(ctx, "calibrate: the loop does not take commands (its queue is full)");
  }
  // The loop runs it at its next cycle and publishes the outcome under its sequence number.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  cal::CalibSnapshot s = sink().load();
  while (s.last_command.sequence != oc.sequence) {
    if (std::chrono::steady_clock::now() > deadline) {
      return refused(ctx,
                     "calibrate: no answer from the loop within 5 s (is it running, or in "
                     "lock-step waiting for the NC?)");
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
    s = sink().load();
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
  // Words are case-insensitive in the script language (tools/calibrate/script.cpp).
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
[[maybe_unused]] const int kHook = register_startup_hook(
    "calibration",
    [](core::engine::Engine& engine, const RegisterReader& read, core::TimeNs now_ns) {
      return calibration_startup(engine, read, now_ns, clock_s(CLOCK_REALTIME));
    });
[[maybe_unused]] const int kVerb =
    register_command_handler("calibrate", handle_calibrate_command, &calibrate_access);
}  // namespace

}  // namespace nccomp::daemon::sections
