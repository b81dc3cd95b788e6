#include "tools/mqtt/status_digest.hpp"

#include <cmath>

#include "formats/measurement_log/measurement_log.hpp"

namespace nccomp::tools::mqtt {

nlohmann::json StatusMemory::to_json() const {
  return nlohmann::json{
      {"alarm_keys", alarm_keys}, {"acknowledged", acknowledged}, {"model", model}};
}

StatusMemory StatusMemory::from_json(const nlohmann::json& j) {
  StatusMemory m;
  if (!j.is_object()) return m;
  m.alarm_keys = j.value("alarm_keys", std::set<std::string>{});
  m.acknowledged = j.value("acknowledged", std::map<std::string, std::uint64_t>{});
  m.model = j.value("model", std::string{});
  return m;
}

std::vector<StatusMessage> digest_status(const nlohmann::json& status, StatusMemory& memory,
                                         double mono_now_s, std::int64_t real_now_ns) {
  std::vector<StatusMessage> out;
  const std::string pid = std::to_string(status.at("daemon").at("pid").get<long long>());
  // Alarms: the ones not in the previous list, oldest first.
  std::set<std::string> keys;
  for (const auto& a : status.at("alarms")) {
    const double t_s = a.at("time_s").is_number() ? a.at("time_s").get<double>() : 0.0;
    char time_text[40];
    std::snprintf(time_text, sizeof time_text, "%.6f", t_s);
    const std::string key =
        pid + ":" + time_text + ":" + a.at("code").dump() + ":" + a.at("subject").dump();
    keys.insert(key);
    if (memory.alarm_keys.count(key) != 0) continue;
    nlohmann::ordered_json p;
    p["utc"] = formats::measurement_log::format_utc(
        real_now_ns - static_cast<std::int64_t>(std::llround((mono_now_s - t_s) * 1e9)));
    p["event"] = "alarm";
    p["time_s"] = a.at("time_s");
    p["severity"] = a.at("severity");
    p["code"] = a.at("code");
    p["name"] = a.at("name");
    p["subject"] = a.at("subject");
    p["value"] = a.at("value");
    p["daemon_pid"] = std::stoll(pid);
    out.push_back({"alarms", std::move(p)});
  }
  memory.alarm_keys = std::move(keys);
  // Acknowledgements: a module's count grew (a new daemon starts from its own count).
  const std::string now_utc = formats::measurement_log::format_utc(real_now_ns);
  nlohmann::json model = nullptr;
  for (const auto& m : status.at("modules")) {
    const std::string name = m.at("name").get<std::string>();
    const auto& st = m.at("status");
    if (name == "model") model = st;
    if (!st.contains("acknowledged") || !st.at("acknowledged").is_number()) continue;
    const auto count = static_cast<std::uint64_t>(st.at("acknowledged").get<double>());
    const std::string key = pid + ":" + name;
    const auto it = memory.acknowledged.find(key);
    const std::uint64_t before = it == memory.acknowledged.end() ? 0 : it->second;
    if (count > before) {
      nlohmann::ordered_json p;
      p["utc"] = now_utc;
      p["event"] = "acknowledge";
      p["module"] = name;
      p["acknowledged"] = count;
      p["cleared"] =
          st.contains("last_acknowledge") ? st.at("last_acknowledge") : nlohmann::json(nullptr);
      p["daemon_pid"] = std::stoll(pid);
      out.push_back({"alarms", std::move(p)});
    }
    memory.acknowledged[key] = count;
  }
  for (auto it = memory.acknowledged.begin(); it != memory.acknowledged.end();) {
    it = it->first.rfind(pid + ":", 0) == 0 ? std::next(it) : memory.acknowledged.erase(it);
  }
  // Model: published when what status says about it changes.
  const auto& d = status.at("daemon");
  const nlohmann::json generation =
      d.contains("config_generation") ? d.at("config_generation") : nlohmann::json(nullptr);
  const std::string terms = model.is_object() && model.contains("applied_terms")
                                ? model.at("applied_terms").dump()
                                : "none";
  const std::string fingerprint = pid + ":" + generation.dump() + ":" + terms;
  if (fingerprint != memory.model) {
    nlohmann::ordered_json p;
    p["utc"] = now_utc;
    p["event"] = "configuration";
    p["config_generation"] = generation;
    p["applied_terms"] = model.is_object() && model.contains("applied_terms")
                             ? model.at("applied_terms")
                             : nlohmann::json(nullptr);
    p["daemon_pid"] = std::stoll(pid);
    out.push_back({"model", std::move(p)});
    memory.model = fingerprint;
  }
  return out;
}

nlohmann::ordered_json daemon_summary(const nlohmann::json& status) {
  nlohmann::ordered_json s;
  const auto& d = status.at("daemon");
  s["pid"] = d.at("pid");
  s["config_generation"] = d.value("config_generation", nlohmann::json(nullptr));
  s["hold"] = d.value("hold", nlohmann::json(nullptr));
  s["dry_run"] = d.value("dry_run", nlohmann::json(nullptr));
  s["state_problem"] = d.value("state_problem", nlohmann::json(nullptr));
  if (status.contains("loop")) {
    const auto& l = status.at("loop");
    s["cycles"] = l.value("cycles", nlohmann::json(nullptr));
    s["overruns"] = l.value("overruns", nlohmann::json(nullptr));
    if (l.contains("latency_us"))
      s["latency_us_p99_9"] = l.at("latency_us").value("p99_9", nlohmann::json(nullptr));
    s["records_dropped"] = l.value("records_dropped", nlohmann::json(nullptr));
  }
  if (status.contains("measurement_log") && status.at("measurement_log").is_object()) {
    const auto& m = status.at("measurement_log");
    s["log_rows"] = m.value("rows", nlohmann::json(nullptr));
    s["log_errors"] = m.value("errors", nlohmann::json(nullptr));
  }
  s["alarms"] = status.contains("alarms") ? status.at("alarms").size() : 0;
  return s;
}

}  // namespace nccomp::tools::mqtt
