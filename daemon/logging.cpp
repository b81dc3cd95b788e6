#include "daemon/logging.hpp"
#include "daemon/measurement_log_probe.hpp"
#include "daemon/status.hpp"

#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/sinks/systemd_sink.h>
#include <spdlog/spdlog.h>
#include <sys/stat.h>
#include <systemd/sd-daemon.h>
#include <systemd/sd-journal.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>

namespace nccomp::daemon {

namespace {
// Set once by setup_logging() before any thread logs: alarms then go to the journal with their
// code, name, subject and value as fields (journalctl NCCOMP_ALARM_CODE=54).
bool g_journal_fields = false;
}  // namespace

bool stderr_is_journal() {
  const char* js = std::getenv("JOURNAL_STREAM");
  if (js == nullptr || sd_booted() <= 0) {
    return false;
  }
  unsigned long long dev = 0;
  unsigned long long ino = 0;
  if (std::sscanf(js, "%llu:%llu", &dev, &ino) != 2) {
    return false;
  }
  struct stat st {};
  if (fstat(2, &st) != 0) {
    return false;
  }
  return static_cast<unsigned long long>(st.st_dev) == dev &&
         static_cast<unsigned long long>(st.st_ino) == ino;
}

std::string setup_logging(const config::LogSection& section) {
  const bool journal =
      section.target == "journal" || (section.target == "auto" && stderr_is_journal());
  std::shared_ptr<spdlog::logger> logger;
  if (journal) {
    auto sink = std::make_shared<spdlog::sinks::systemd_sink_mt>("nccompd");
    logger = std::make_shared<spdlog::logger>("nccompd", sink);
    logger->set_pattern("%v");  // journald stamps time, priority and unit itself
  } else {
    logger = std::make_shared<spdlog::logger>(
        "nccompd", std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
    logger->set_pattern("%Y-%m-%d %H:%M:%S.%e %^%l%$ %v");
  }
  logger->set_level(spdlog::level::from_str(section.level == "warning" ? "warn" : section.level));
  logger->flush_on(spdlog::level::info);
  spdlog::set_default_logger(logger);
  g_journal_fields = journal;
  return journal ? "journal" : "terminal";
}

std::string alarm_name(core::AlarmCode code) {
  using core::AlarmCode;
  switch (code) {
    case AlarmCode::kNone:
      return "none";
    case AlarmCode::kOffsetNonFinite:
      return "offset_non_finite";
    case AlarmCode::kOffsetBeyondAbsoluteLimit:
      return "offset_beyond_absolute_limit";
    case AlarmCode::kOffsetSlewLimited:
      return "offset_slew_limited";
    case AlarmCode::kCreepUnfinished:
      return "creep_unfinished";
    case AlarmCode::kToolLifeReached:
      return "tool_life_reached";
    case AlarmCode::kToolExcessivelyWorn:
      return "tool_excessively_worn";
    case AlarmCode::kToolBrokenOrMismeasured:
      return "tool_broken_or_mismeasured";
    case AlarmCode::kMeasurementDue:
      return "measurement_due";
    case AlarmCode::kMeasurementNoiseInconsistent:
      return "measurement_noise_inconsistent";
    case AlarmCode::kProbeImplausible:
      return "probe_implausible";
    case AlarmCode::kProbeOutlier:
      return "probe_outlier";
    case AlarmCode::kProbeInvalidInput:
      return "probe_invalid_input";
    case AlarmCode::kCheckpointRegisterMismatch:
      return "checkpoint_register_mismatch";
    case AlarmCode::kCheckpointMissed:
      return "checkpoint_missed";
    case AlarmCode::kRecalibrationImplausible:
      return "recalibration_implausible";
    case AlarmCode::kTouchScatter:
      return "touch_scatter";
    case AlarmCode::kRecalibrationDue:
      return "recalibration_due";
    case AlarmCode::kTouchSetIncomplete:
      return "touch_set_incomplete";
    case AlarmCode::kCalibrationOutOfRange:
      return "calibration_out_of_range";
    case AlarmCode::kTouchUnexpected:
      return "touch_unexpected";
    case AlarmCode::kTestGrindNotConverging:
      return "test_grind_not_converging";
    case AlarmCode::kRecalibrationApplied:
      return "recalibration_applied";
    case AlarmCode::kCalibrationComplete:
      return "calibration_complete";
    case AlarmCode::kCalibrationInvalidInput:
      return "calibration_invalid_input";
    case AlarmCode::kStateCorrupt:
      return "state_corrupt";
    case AlarmCode::kEventInvalid:
      return "event_invalid";
    case AlarmCode::kRegisterUnknown:
      return "register_unknown";
    case AlarmCode::kOffsetWriteDropped:
      return "offset_write_dropped";
    case AlarmCode::kBusAlarm:
      return "bus_alarm";
    case AlarmCode::kRegisterBeyondLimit:
      return "register_beyond_limit";
    case AlarmCode::kRegisterAdopted:
      return "register_adopted";
    case AlarmCode::kRegisterHeldWithoutState:
      return "register_held_without_state";
    case AlarmCode::kBusInputStale:
      return "bus_input_stale";
  }
  // No default above: -Wswitch (an error here) makes every new AlarmCode get its name. A value
  // outside the enum (a corrupt state, a newer peer) still prints usefully.
  return "code_" + std::to_string(static_cast<unsigned>(code));
}

const char* severity_name(core::Severity s) {
  switch (s) {
    case core::Severity::kInfo:
      return "info";
    case core::Severity::kWarning:
      return "warning";
    case core::Severity::kAlarm:
      return "alarm";
  }
  return "unknown";
}

EventLogger::~EventLogger() { stop(); }

void EventLogger::start() {
  stop_.store(false);
  thread_ = std::thread([this] { run(); });
}

void EventLogger::stop() {
  stop_.store(true, std::memory_order_release);
  if (thread_.joinable()) {
    thread_.join();
  }
}

std::vector<core::AlarmEvent> EventLogger::last_alarms() const {
  std::lock_guard<std::mutex> lock(mu_);
  return {last_.begin(), last_.end()};
}

void EventLogger::raise(const core::AlarmEvent& a) { log_alarm(a); }

namespace {

spdlog::level::level_enum level_of(core::Severity s) {
  return s == core::Severity::kAlarm     ? spdlog::level::err
         : s == core::Severity::kWarning ? spdlog::level::warn
                                         : spdlog::level::info;
}

core::TimeNs steady_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

bool identical(const core::AlarmEvent& a, const core::AlarmEvent& b) {
  // The value bit for bit: NaN equals NaN here, which is what a repeated NaN fault is.
  return a.severity == b.severity && a.code == b.code && a.subject == b.subject &&
         std::memcmp(&a.value, &b.value, sizeof a.value) == 0;
}

}  // namespace

bool AlarmBursts::add(const core::AlarmEvent& a, core::TimeNs now_ns, std::vector<Burst>& ended) {
  expire(now_ns, ended);
  if (a.severity == core::Severity::kInfo) {
    // An info ends the bursts of its code and subject (a clear ends the rise's burst).
    std::erase_if(open_, [&](const Burst& b) {
      if (b.alarm.code != a.code || b.alarm.subject != a.subject) {
        return false;
      }
      if (b.count > 1) {
        ended.push_back(b);
      }
      return true;
    });
    return true;
  }
  for (Burst& b : open_) {
    if (identical(b.alarm, a)) {
      ++b.count;
      b.last_ns = now_ns;
      return false;
    }
  }
  std::erase_if(open_, [&](const Burst& b) {
    if (b.alarm.code != a.code || b.alarm.subject != a.subject || b.alarm.severity == a.severity) {
      return false;
    }
    if (b.count > 1) {
      ended.push_back(b);
    }
    return true;
  });
  open_.push_back(Burst{a, 1, now_ns, now_ns});
  return true;
}

void AlarmBursts::expire(core::TimeNs now_ns, std::vector<Burst>& ended) {
  std::erase_if(open_, [&](const Burst& b) {
    if (now_ns - b.last_ns < kQuietNs && now_ns != std::numeric_limits<core::TimeNs>::max()) {
      return false;
    }
    if (b.count > 1) {
      ended.push_back(b);
    }
    return true;
  });
}

std::string burst_end_line(const AlarmBursts::Burst& b) {
  const core::AlarmEvent& a = b.alarm;
  return fmt::format(
      "end of burst: {} (code {}, {}) subject {} value {}: {} in {:.1f} s (only the first was "
      "logged)",
      alarm_name(a.code), static_cast<unsigned>(a.code), severity_name(a.severity), a.subject,
      a.value, b.count, static_cast<double>(b.last_ns - b.first_ns) / 1e9);
}

namespace {

// To the journal, the alarm's code, name, severity, subject and value go as fields too
// (journalctl -u nccompd NCCOMP_ALARM_CODE=54); the terminal gets the line only.
void log_alarm_line(const core::AlarmEvent& a) {
  const auto level = level_of(a.severity);
  if (!g_journal_fields || !spdlog::default_logger()->should_log(level)) {
    spdlog::log(level, "{} {} (code {}) subject {} value {}", severity_name(a.severity),
                alarm_name(a.code), static_cast<unsigned>(a.code), a.subject, a.value);
    return;
  }
  const std::string name = alarm_name(a.code);
  const int priority = a.severity == core::Severity::kAlarm     ? LOG_ERR
                       : a.severity == core::Severity::kWarning ? LOG_WARNING
                                                                : LOG_INFO;
  const std::string message =
      fmt::format("{} {} (code {}) subject {} value {}", severity_name(a.severity), name,
                  static_cast<unsigned>(a.code), a.subject, a.value);
  sd_journal_send("MESSAGE=%s", message.c_str(), "PRIORITY=%d", priority,
                  "SYSLOG_IDENTIFIER=nccompd", "NCCOMP_ALARM_CODE=%u",
                  static_cast<unsigned>(a.code), "NCCOMP_ALARM_NAME=%s", name.c_str(),
                  "NCCOMP_ALARM_SEVERITY=%s", severity_name(a.severity), "NCCOMP_ALARM_SUBJECT=%d",
                  static_cast<int>(a.subject), "NCCOMP_ALARM_VALUE=%g", a.value, nullptr);
}

}  // namespace

void EventLogger::log_alarm(const core::AlarmEvent& a) {
  std::vector<AlarmBursts::Burst> ended;
  bool log = false;
  {
    std::lock_guard<std::mutex> lock(mu_);
    last_.push_back(a);
    while (last_.size() > kKeepAlarms) {
      last_.pop_front();
    }
    log = bursts_.add(a, steady_ns(), ended);
  }
  for (const auto& b : ended) {
    spdlog::log(level_of(b.alarm.severity), "{}", burst_end_line(b));
  }
  if (log) {
    log_alarm_line(a);
  }
}

void EventLogger::end_bursts(core::TimeNs now_ns) {
  std::vector<AlarmBursts::Burst> ended;
  {
    std::lock_guard<std::mutex> lock(mu_);
    bursts_.expire(now_ns, ended);
  }
  for (const auto& b : ended) {
    spdlog::log(level_of(b.alarm.severity), "{}", burst_end_line(b));
  }
}

void EventLogger::drain() {
  core::AlarmEvent a;
  while (loop_.alarms().try_pop(a)) {
    log_alarm(a);
  }
  LoopNote n;
  while (loop_.notes().try_pop(n)) {
    switch (n.code) {
      case NoteCode::kOverrun:
        if (const std::uint64_t count = overruns_.add(n.time_ns); count > 0) {
          spdlog::warn(
              "loop overrun: woke {:.0f} us late, {} deadline(s) skipped ({} overrun(s) "
              "since the last message)",
              n.b, n.a, count);
        }
        break;
      case NoteCode::kConfigSwapped:
        if (n.b > 0.0) {
          spdlog::info(
              "configuration {} is running (swapped in at a cycle boundary, {:.0f} cycle(s) "
              "after the reload, waiting for the bus's receipts of the writes in flight)",
              n.a, n.b);
        } else {
          spdlog::info("configuration {} is running (swapped in at a cycle boundary)", n.a);
        }
        break;
      case NoteCode::kStateCarryFailed:
        spdlog::error("configuration {} could not take over the running state; it starts fresh",
                      n.a);
        break;
      case NoteCode::kStateExportFailed:
        spdlog::error("state export failed: the engine needs {} bytes", n.a);
        break;
      case NoteCode::kWriteDropped:
        if (const std::uint64_t count = writes_dropped_.add(n.time_ns); count > 0) {
          spdlog::warn(
              "offset write to register {} ({} um) dropped: bus TX ring full or no bus ({} "
              "dropped write(s) since the last message)",
              n.a, n.b, count);
        }
        break;
      case NoteCode::kDryRunEntered:
        spdlog::warn(
            "configuration {} is a DRY RUN: nothing is written to the NC from now on; the state "
            "file keeps the offsets the NC has now",
            n.a);
        break;
      case NoteCode::kDryRunLeft:
        spdlog::warn(
            "configuration {} ends the dry run: it starts from the state before the dry run (the "
            "dry run's offsets were never sent), through the limiters",
            n.a);
        break;
      case NoteCode::kFaceProbeRejected: {
        const std::int64_t reason = ((n.a % 8) + 8) % 8;
        spdlog::warn(
            "[measurement_log.face_probe]: the probe reading of point {} ({} um) gives no "
            "measurement row: {}",
            (n.a - reason) / 8, n.b, to_string(static_cast<FaceProbeReject>(reason)));
        break;
      }
    }
  }
}

std::vector<BusAlarmChange> BusAlarmWatch::update(const std::vector<std::string>& names,
                                                  const std::vector<drivers::BusStatus>& statuses,
                                                  core::TimeNs now_ns) {
  std::vector<BusAlarmChange> out;
  raised_.resize(statuses.size(), false);
  failed_seen_.resize(statuses.size(), 0);
  stale_raised_.resize(statuses.size(), false);
  stale_counters_.resize(statuses.size());
  stale_since_ns_.resize(statuses.size(), 0);
  for (std::size_t i = 0; i < statuses.size(); ++i) {
    const drivers::BusStatus& st = statuses[i];
    if (st.input_stale != stale_raised_[i]) {
      stale_raised_[i] = st.input_stale;
      const std::string name = i < names.size() ? names[i] : fmt::format("#{}", i);
      const auto& k = st.counters;
      BusAlarmChange c;
      c.event =
          core::AlarmEvent{now_ns, st.input_stale ? core::Severity::kAlarm : core::Severity::kInfo,
                           core::AlarmCode::kBusInputStale, static_cast<std::int32_t>(i),
                           st.input_stale ? 1.0 : 0.0};
      if (st.input_stale) {
        stale_counters_[i] = k;
        stale_since_ns_[i] = now_ns;
        c.message = fmt::format(
            "bus {}: ALARM: input from the NC is stale: the link not healthy or no valid axis "
            "sample for longer than degraded_alarm_after_s; positions and measurements are not "
            "arriving (link {}; frames rx {}, faults {}, malformed {}; its counters in `nccomp "
            "status`)",
            name, link_state_name(st.state), k.frames_rx, k.faults, k.malformed);
      } else {
        const auto& b = stale_counters_[i];
        c.message = fmt::format(
            "bus {}: input stale cleared after {:.1f} s (link {}; meanwhile faults {}, "
            "malformed {}, frames rx {})",
            name, static_cast<double>(now_ns - stale_since_ns_[i]) / 1e9, link_state_name(st.state),
            k.faults - b.faults, k.malformed - b.malformed, k.frames_rx - b.frames_rx);
      }
      out.push_back(std::move(c));
    }
    const bool failed_now = st.counters.offsets_failed > failed_seen_[i];
    failed_seen_[i] = st.counters.offsets_failed;
    if (st.alarm == raised_[i]) {
      continue;
    }
    raised_[i] = st.alarm;
    // fmt, not "literal" + std::string: GCC 12 at -O3 reports a false -Wrestrict on the latter.
    const std::string name = i < names.size() ? names[i] : fmt::format("#{}", i);
    const auto& k = st.counters;
    BusAlarmChange c;
    c.event = core::AlarmEvent{now_ns, st.alarm ? core::Severity::kAlarm : core::Severity::kInfo,
                               core::AlarmCode::kBusAlarm, static_cast<std::int32_t>(i),
                               st.alarm ? 1.0 : 0.0};
    if (st.alarm) {
      // Why, as far as the driver's status tells it: a write given up / refused since the last
      // look, else a link that is not up, else a write still undelivered.
      const char* why = failed_now ? "an offset write failed or was refused"
                        : st.state != drivers::LinkState::kUp
                            ? "the link is not up beyond alarm_after_s"
                            : "an offset write is undelivered beyond alarm_after_s";
      c.message = fmt::format(
          "bus {}: ALARM: offsets may not reach the NC: {} (link {}; offsets written {}, "
          "retried {}, failed {}; reconnects {})",
          name, why, link_state_name(st.state), k.offsets_written, k.offsets_retried,
          k.offsets_failed, k.reconnects);
    } else {
      c.message = fmt::format(
          "bus {}: alarm cleared (link {}; offsets written {}, retried {}, failed {}; reconnects "
          "{})",
          name, link_state_name(st.state), k.offsets_written, k.offsets_retried, k.offsets_failed,
          k.reconnects);
    }
    out.push_back(std::move(c));
  }
  return out;
}

void EventLogger::run() {
  for (;;) {
    const bool stopping = stop_.load(std::memory_order_acquire);
    drain();
    end_bursts(stopping ? std::numeric_limits<core::TimeNs>::max() : steady_ns());
    if (stopping) {
      // What the last second's summaries had not said yet.
      if (overruns_.pending() > 0) {
        spdlog::warn("loop overrun: {} more overrun(s) since the last message",
                     overruns_.pending());
      }
      if (writes_dropped_.pending() > 0) {
        spdlog::warn("offset writes dropped: {} more since the last message",
                     writes_dropped_.pending());
      }
      return;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
}

}  // namespace nccomp::daemon
