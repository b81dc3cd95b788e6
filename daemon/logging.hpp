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

  Loop& loop_;
  mutable std::mutex mu_;
  std::deque<core::AlarmEvent> last_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
  // Overrun notes are summarised: at most one message per second.
  std::int64_t overrun_log_ns_{0};
  std::uint64_t overruns_unlogged_{0};
};

/// One change of a bus's alarm flag (drivers::BusStatus::alarm), as the main thread reports it:
/// the alarm to raise (AlarmCode::kBusAlarm, subject = the bus's index, value 1 rising with
/// Severity::kAlarm, 0 clearing with Severity::kInfo) and the log line that says which bus, its
/// link state and why.
struct BusAlarmChange {
  core::AlarmEvent event{};
  std::string message;
};

/// Main thread (never the loop: it allocates): watches the buses' alarm flags and reports each
/// rise and each fall exactly once. A bus starts as "not in alarm".
class BusAlarmWatch {
 public:
  /// names[i] and statuses[i] are bus i (the daemon's bus order; same size on every call).
  [[nodiscard]] std::vector<BusAlarmChange> update(const std::vector<std::string>& names,
                                                   const std::vector<drivers::BusStatus>& statuses,
                                                   core::TimeNs now_ns);

 private:
  std::vector<bool> raised_;
  std::vector<std::uint64_t> failed_seen_;  // offsets_failed at the last look
};

}  // namespace nccomp::daemon
