// Logging (spdlog): journald when started by systemd, the terminal otherwise. The loop thread
// never logs: it pushes alarms and notes into SPSC rings, and the EventLogger thread turns them
// into messages and keeps the last alarms for `nccomp status`.
#pragma once

#include <atomic>
#include <cstdint>
#include <deque>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "core/common/types.hpp"
#include "daemon/config/builtin_sections.hpp"
#include "daemon/loop.hpp"

namespace nccomp::daemon {

/// True if stderr is connected to the journal ($JOURNAL_STREAM names stderr's device:inode, and
/// the system runs systemd).
[[nodiscard]] bool stderr_is_journal();

/// Installs the default logger. Returns "journal" or "terminal" (what was chosen).
std::string setup_logging(const config::LogSection& section);

[[nodiscard]] std::string alarm_name(core::AlarmCode code);
[[nodiscard]] const char* severity_name(core::Severity s);

/// What the log makes of repeated alarms (warnings and alarms; info lines are events of their
/// own and always logged): a burst of identical alarms (same severity, code, subject and value,
/// e.g. a measurement the NC keeps sending as NaN) is one line when it starts and, if more came,
/// one line when it ends, with how many there were. A burst ends when no identical alarm came for
/// kQuietNs, or when one with the same code and subject but another severity comes (a clear).
/// Not thread-safe (EventLogger holds its mutex); allocates (never on the loop thread).
class AlarmBursts {
 public:
  static constexpr core::TimeNs kQuietNs = 2'000'000'000;
  struct Burst {
    core::AlarmEvent alarm{};  // the first of the burst
    std::uint64_t count{0};
    core::TimeNs first_ns{0};  // arrival times (the caller's clock)
    core::TimeNs last_ns{0};
  };
  /// An alarm arrived at now_ns: true if it is to be logged (it starts a burst, or it is info).
  /// Bursts it ends with more than one alarm are appended to `ended`.
  bool add(const core::AlarmEvent& a, core::TimeNs now_ns, std::vector<Burst>& ended);
  /// Ends the bursts quiet for kQuietNs at now_ns (every burst at INT64_MAX); those with more
  /// than one alarm are appended to `ended`.
  void expire(core::TimeNs now_ns, std::vector<Burst>& ended);

 private:
  std::vector<Burst> open_;
};

/// The log line that ends a burst: "end of burst: NAME (code N, SEVERITY) subject S value V: C in
/// T s (only the first was logged)".
[[nodiscard]] std::string burst_end_line(const AlarmBursts::Burst& b);

/// Summarises a kind of loop note that can come every cycle (an overrun, a dropped offset
/// write): at most one log line per interval, carrying how many came since the last line, so
/// that a bus falling behind at 1 kHz does not flood the journal. Not thread-safe (the logger's
/// thread only).
class NoteThrottle {
 public:
  explicit NoteThrottle(core::TimeNs interval_ns = 1'000'000'000) : interval_ns_(interval_ns) {}
  /// Counts one note at `time_ns`; returns how many notes the line to log now stands for
  /// (this one included), or 0 when this one is only counted.
  std::uint64_t add(core::TimeNs time_ns) noexcept {
    ++unlogged_;
    if (logged_once_ && time_ns - last_ns_ < interval_ns_) {
      return 0;
    }
    logged_once_ = true;
    last_ns_ = time_ns;
    const std::uint64_t n = unlogged_;
    unlogged_ = 0;
    return n;
  }
  /// Notes counted but not yet logged (for a last line at stop).
  [[nodiscard]] std::uint64_t pending() const noexcept { return unlogged_; }

 private:
  core::TimeNs interval_ns_;
  core::TimeNs last_ns_{0};
  bool logged_once_{false};
  std::uint64_t unlogged_{0};
};

class EventLogger {
 public:
  static constexpr std::size_t kKeepAlarms = 32;

  explicit EventLogger(Loop& loop) : loop_(loop) {}
  ~EventLogger();
  void start();
  /// Drains what is queued, then stops. Idempotent.
  void stop();
  /// Any thread: the last alarms, newest last.
  [[nodiscard]] std::vector<core::AlarmEvent> last_alarms() const;
  /// Any thread: an alarm raised outside the loop (state corrupt at start).
  void raise(const core::AlarmEvent& a);

 private:
  void run();
  void drain();
  void log_alarm(const core::AlarmEvent& a);
  void end_bursts(core::TimeNs now_ns);

  Loop& loop_;
  mutable std::mutex mu_;
  std::deque<core::AlarmEvent> last_;
  AlarmBursts bursts_;  // under mu_
  std::atomic<bool> stop_{false};
  std::thread thread_;
  // Overrun and dropped-write notes are summarised: at most one message per second each.
  NoteThrottle overruns_;
  NoteThrottle writes_dropped_;
};

/// One change of a bus's alarm flag (drivers::BusStatus::alarm), as the main thread reports it:
/// the alarm to raise (AlarmCode::kBusAlarm, subject = the bus's index, value 1 rising with
/// Severity::kAlarm, 0 clearing with Severity::kInfo) and the log line that says which bus, its
/// link state and why.
struct BusAlarmChange {
  core::AlarmEvent event{};
  std::string message;
};

/// Main thread (never the loop: it allocates): watches the buses' alarm flags (BusStatus::alarm
/// → kBusAlarm, BusStatus::input_stale → kBusInputStale) and reports each rise and each fall
/// exactly once; the fall of input_stale says how long it lasted and the faults, malformed frames
/// and frames received meanwhile. A bus starts as "not in alarm".
class BusAlarmWatch {
 public:
  /// names[i] and statuses[i] are bus i (the daemon's bus order; same size on every call).
  [[nodiscard]] std::vector<BusAlarmChange> update(const std::vector<std::string>& names,
                                                   const std::vector<drivers::BusStatus>& statuses,
                                                   core::TimeNs now_ns);

 private:
  std::vector<bool> raised_;
  std::vector<std::uint64_t> failed_seen_;  // offsets_failed at the last look
  std::vector<bool> stale_raised_;
  std::vector<drivers::BusCounters> stale_counters_;  // at the rise of input_stale
  std::vector<core::TimeNs> stale_since_ns_;
};

}  // namespace nccomp::daemon
