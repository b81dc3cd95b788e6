// What the publisher takes from nccompd's status (`nccomp status --json`, read through the status
// socket): new alarms, new acknowledgements, changes of the model, and a summary for the
// heartbeat. The status shows the last 32 alarms; an alarm is new if its key (daemon pid, time_s,
// code, subject) was not in the previous poll's list. An acknowledgement is new when a module's
// `acknowledged` count grew. The model changes when the daemon's configuration generation or the
// model module's applied_terms changes (the seam for the model-management events to come).
// Not real-time.
#pragma once

#include <cstdint>
#include <map>
#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace nccomp::tools::mqtt {

struct StatusMessage {
  std::string kind;                // "alarms" or "model"
  nlohmann::ordered_json payload;  // without seq and machine (the publisher adds them)
};

/// What earlier polls saw (saved with the queue, so a restart does not publish again).
struct StatusMemory {
  std::set<std::string> alarm_keys;
  std::map<std::string, std::uint64_t> acknowledged;  // "pid:module" → count
  std::string model;                                  // fingerprint; "" = never seen
  [[nodiscard]] nlohmann::json to_json() const;
  static StatusMemory from_json(const nlohmann::json& j);
};

/// Digests one status answer. mono_now_s / real_now_ns: this host's CLOCK_MONOTONIC [s] and
/// CLOCK_REALTIME [ns] now, to turn the daemon's alarm times into UTC. Throws
/// nlohmann::json::exception for a status without the expected members.
[[nodiscard]] std::vector<StatusMessage> digest_status(const nlohmann::json& status,
                                                       StatusMemory& memory, double mono_now_s,
                                                       std::int64_t real_now_ns);

/// The heartbeat's daemon part: pid, hold, configuration generation, loop and log counters.
[[nodiscard]] nlohmann::ordered_json daemon_summary(const nlohmann::json& status);

}  // namespace nccomp::tools::mqtt
