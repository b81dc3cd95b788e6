#include "daemon/status.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <span>
#include <sstream>
#include <string_view>
#include <system_error>

#include "client/protocol.hpp"
#include "daemon/commands/command.hpp"

namespace nccomp::daemon {

namespace {

[[noreturn]] void sys_fail(const std::string& what) {
  throw std::system_error(errno, std::generic_category(), what);
}

std::string json_escape(const std::string& s) {
  std::string o;
  for (char ch : s) {
    const auto c = static_cast<unsigned char>(ch);
    if (c == '"' || c == '\\') {
      o += '\\';
      o += ch;
    } else if (c < 0x20) {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\u%04x", c);
      o += buf;
    } else {
      o += ch;
    }
  }
  return o;
}

// "null" for an empty string, else the JSON string. (Built with +=: GCC 12 warns falsely about
// `"\"" + std::string` at -O3.)
std::string string_or_null(const std::string& v) {
  if (v.empty()) {
    return "null";
  }
  std::string q;
  q += '"';
  q += json_escape(v);
  q += '"';
  return q;
}

std::string num(double v) {
  if (!std::isfinite(v)) {
    return "null";
  }
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.6g", v);
  return buf;
}

struct View {
  LoopStats s;
  RegisterSnapshot r;
  ModulesSnapshot m;
  std::vector<std::string> names;
  std::vector<core::engine::RegisterSpec> specs;
  double rate_hz{0.0};
  double measured_rate_hz{0.0};
  double p50{0}, p99{0}, p999{0}, max_us{0};
  std::string problem;
};

View gather(const StatusContext& c) {
  View v;
  v.s = c.loop->stats();
  v.r = c.loop->registers();
  v.m = c.loop->modules();
  v.names = c.register_names ? c.register_names() : std::vector<std::string>{};
  v.specs = c.register_specs ? c.register_specs() : std::vector<core::engine::RegisterSpec>{};
  v.rate_hz = v.s.period_ns > 0 ? 1e9 / static_cast<double>(v.s.period_ns) : 0.0;
  const double span_s = core::seconds(v.s.last_wake_ns - v.s.started_ns);
  v.measured_rate_hz = span_s > 0 ? static_cast<double>(v.s.cycles - 1) / span_s : 0.0;
  const auto& h = c.loop->latency();
  v.p50 = h.quantile_us(0.5);
  v.p99 = h.quantile_us(0.99);
  v.p999 = h.quantile_us(0.999);
  v.max_us = static_cast<double>(h.max_ns()) / 1000.0;
  v.problem = c.state_problem ? c.state_problem() : std::string{};
  return v;
}

std::string reg_name(const View& v, std::size_t i) {
  return i < v.names.size() ? v.names[i] : "register_" + std::to_string(i);
}

}  // namespace

const char* link_state_name(drivers::LinkState s) {
  switch (s) {
    case drivers::LinkState::kStopped:
      return "stopped";
    case drivers::LinkState::kConnecting:
      return "connecting";
    case drivers::LinkState::kUp:
      return "up";
    case drivers::LinkState::kDegraded:
      return "degraded";
    case drivers::LinkState::kDown:
      return "down";
  }
  return "unknown";
}

std::string render_json(const StatusContext& c) {
  const View v = gather(c);
  const auto& s = v.s;
  std::ostringstream o;
  o << "{\"daemon\":{\"pid\":" << ::getpid() << ",\"config\":\"" << json_escape(c.config_path)
    << "\",\"config_generation\":" << s.config_generation
    << ",\"config_since_cycle\":" << s.config_since_cycle
    << ",\"swap_waiting_cycles\":" << s.swap_waiting << ",\"reloads\":" << s.reloads
    << ",\"dry_run\":" << (s.dry_run ? "true" : "false")
    << ",\"hold\":" << (s.hold ? "true" : "false")
    << ",\"state_problem\":" << string_or_null(v.problem) << "},";
  o << "\"loop\":{\"rate_hz\":" << num(v.rate_hz)
    << ",\"measured_rate_hz\":" << num(v.measured_rate_hz) << ",\"cycles\":" << s.cycles
    << ",\"overruns\":" << s.overruns << ",\"missed_deadlines\":" << s.missed_deadlines
    << ",\"latency_us\":{\"p50\":" << num(v.p50) << ",\"p99\":" << num(v.p99)
    << ",\"p99_9\":" << num(v.p999) << ",\"max\":" << num(v.max_us)
    << ",\"last\":" << num(static_cast<double>(s.last_latency_ns) / 1000.0)
    << "},\"max_cycle_us\":" << num(static_cast<double>(s.max_step_ns) / 1000.0)
    << ",\"minor_faults_after_warmup\":" << s.minor_faults_after_warmup
    << ",\"major_faults_after_warmup\":" << s.major_faults_after_warmup
    << ",\"allocations_after_warmup\":" << s.allocations_after_warmup
    << ",\"frees_after_warmup\":" << s.frees_after_warmup << ",\"events_in\":" << s.events_in
    << ",\"writes_sent\":" << s.writes_sent << ",\"writes_dry_run\":" << s.writes_dry_run
    << ",\"writes_dropped\":" << s.writes_dropped << ",\"alarms\":" << s.alarms
    << ",\"alarms_dropped\":" << s.alarms_dropped << ",\"records\":" << s.records
    << ",\"records_dropped\":" << s.records_dropped
    << ",\"face_probe_rejected\":" << s.face_probe_rejected
    << ",\"state_exports\":" << s.state_exports
    << ",\"state_export_busy\":" << s.state_export_busy
    << ",\"state_export_failed\":" << s.state_export_failed << "},";
  const auto& e = s.engine;
  o << "\"engine\":{\"events_accepted\":" << e.events_accepted
    << ",\"events_invalid\":" << e.events_invalid << ",\"events_overflow\":" << e.events_overflow
    << ",\"writes_forwarded\":" << e.writes_forwarded
    << ",\"writes_rejected\":" << e.writes_rejected
    << ",\"writes_unknown_register\":" << e.writes_unknown_register
    << ",\"writes_held\":" << e.writes_held << ",\"output_overflows\":" << e.output_overflows
    << ",\"writes_deferred\":" << e.writes_deferred << ",\"writes_blocked\":" << e.writes_blocked
    << ",\"writes_awaiting_nc\":" << e.writes_awaiting_nc
    << ",\"release_commands\":" << e.release_commands << "},";
  const auto& h = s.handover;
  o << "\"handover\":{\"handovers\":" << h.handovers << ",\"rebased\":" << h.rebases
    << ",\"unabsorbed\":" << h.unabsorbed
    << ",\"last_trim_change_um\":" << num(h.last_trim_change_um)
    << ",\"last_unabsorbed_um\":" << num(h.last_unabsorbed_um) << "},";
  if (c.model) {
    // What `nccomp model status` names: the live model and the one rollback returns to.
    const ModelState m = c.model();
    const auto record = [&](const sections::ModelRecord& r) {
      o << "{\"file\":\"" << json_escape(r.file) << "\",\"hash\":\"" << json_escape(r.hash)
        << "\",\"since_utc\":\"" << json_escape(r.since_utc) << "\"}";
    };
    o << "\"model\":{\"live\":";
    record(m.live);
    o << ",\"previous\":";
    record(m.previous);
    // Accepted, not swapped in by the loop yet (live is the model still in force).
    o << ",\"pending\":";
    if (m.pending) {
      record(m.pending_model);
    } else {
      o << "null";
    }
    o << ",\"pending_generation\":" << m.pending_generation
      << ",\"pending_cycles\":" << m.pending_cycles;
    o << ",\"chosen\":" << (m.chosen ? "true" : "false") << ",\"generation\":" << m.generation
      << "},";
  }
  if (c.shadow) {
    // docs/closing-the-loop.md, "A candidate in shadow".
    const sections::ShadowStatus sh = c.shadow();
    o << "\"shadow\":{\"phase\":\"" << sections::phase_name(sh.phase) << "\",\"promote\":\""
      << (sh.options.promote == sections::ShadowPromote::kAuto ? "auto" : "operator")
      << "\",\"live\":{\"file\":\"" << json_escape(sh.live_file) << "\",\"parts\":" << sh.live.parts
      << ",\"mse_um2\":" << num(sh.live.mse_um2()) << "},\"other\":{\"file\":\""
      << json_escape(sh.other_file) << "\",\"parts\":" << sh.other.parts
      << ",\"mse_um2\":" << num(sh.other.mse_um2()) << "},\"paired_parts\":" << sh.window.parts
      << ",\"other_better\":" << sh.window.challenger_better
      << ",\"live_better\":" << sh.window.incumbent_better << ",\"ties\":" << sh.window.ties
      << ",\"p_value\":" << num(sh.window.p_value) << ",\"rows_scored\":" << sh.rows_scored
      << ",\"rows_skipped\":" << sh.rows_skipped << ",\"decisions\":" << sh.history.size() << "},";
  }
  o << "\"registers\":[";
  for (std::size_t i = 0; i < v.r.count; ++i) {
    const auto& r = v.r.regs[i];
    o << (i ? "," : "") << "{\"index\":" << i << ",\"name\":\"" << json_escape(reg_name(v, i))
      << "\",\"output_um\":" << num(r.output_um)
      << ",\"target_um\":" << (r.has_target ? num(r.target_um) : "null")
      << ",\"slewing\":" << (r.slewing ? "true" : "false")
      << ",\"awaiting_nc\":" << (r.awaiting_nc ? "true" : "false");
    if (i < v.specs.size()) {
      // What the limiter allows this register (a flag: only max_abs_um applies).
      const auto& spec = v.specs[i];
      o << ",\"kind\":\"" << core::engine::to_string(spec.kind)
        << "\",\"max_abs_um\":" << num(spec.limits.max_abs_um)
        << ",\"max_step_um\":" << num(spec.limits.max_step_um)
        << ",\"max_rate_um_per_s\":" << num(spec.limits.max_rate_um_per_s);
    }
    o << ",\"hold\":"
      << (r.hold == core::engine::RegisterHold::kNone
              ? std::string("null")
              : "\"" + std::string(core::engine::to_string(r.hold)) + "\"")
      << "}";
  }
  o << "],\"modules\":[";
  for (std::size_t i = 0; i < v.m.count; ++i) {
    const auto& m = v.m.modules[i];
    o << (i ? "," : "") << "{\"name\":\"" << json_escape(m.name.data()) << "\",\"status\":{";
    for (std::size_t k = 0; k < m.count; ++k) {
      const auto& sv = m.values[k];
      o << (k ? "," : "") << "\"" << json_escape(sv.key) << "\":";
      if (sv.text != nullptr) {
        o << "\"" << json_escape(sv.text) << "\"";
      } else {
        o << num(sv.value);
      }
    }
    o << "}}";
  }
  o << "],\"buses\":[";
  for (std::size_t i = 0; i < c.buses.size(); ++i) {
    const auto st = c.buses[i].second->status();
    const auto& k = st.counters;
    o << (i ? "," : "") << "{\"name\":\"" << json_escape(c.buses[i].first) << "\",\"state\":\""
      << link_state_name(st.state) << "\",\"alarm\":" << (st.alarm ? "true" : "false")
      << ",\"input_stale\":" << (st.input_stale ? "true" : "false")
      << ",\"frames_rx\":" << k.frames_rx << ",\"frames_tx\":" << k.frames_tx
      << ",\"events_decoded\":" << k.events_decoded << ",\"events_dropped\":" << k.events_dropped
      << ",\"malformed\":" << k.malformed << ",\"offsets_written\":" << k.offsets_written
      << ",\"offsets_retried\":" << k.offsets_retried << ",\"offsets_failed\":" << k.offsets_failed
      << ",\"reconnects\":" << k.reconnects << ",\"faults\":" << k.faults;
    std::array<drivers::BusCounterValue, drivers::kMaxBusExtraCounters> extra{};
    const std::size_t n_extra = std::min(c.buses[i].second->extra_counters(extra), extra.size());
    o << ",\"counters\":{";
    for (std::size_t x = 0; x < n_extra; ++x) {
      o << (x ? "," : "") << "\"" << json_escape(extra[x].name) << "\":" << extra[x].value;
    }
    o << "}}";
  }
  o << "],\"state\":{\"path\":\"" << json_escape(c.state_path) << "\"";
  if (c.persister != nullptr) {
    const auto ps = c.persister->stats();
    o << ",\"writes\":" << ps.writes << ",\"failures\":" << ps.failures
      << ",\"sequence\":" << ps.sequence << ",\"last_error\":" << string_or_null(ps.last_error);
  }
  o << "},\"measurement_log\":";
  if (c.measurement_log != nullptr) {
    o << "{\"path\":\"" << json_escape(c.measurement_log->current_path())
      << "\",\"rows\":" << c.measurement_log->rows()
      << ",\"rotations\":" << c.measurement_log->rotations()
      << ",\"errors\":" << c.measurement_log->errors() << "}";
  } else {
    o << "null";
  }
  o << ",\"status_server\":";
  if (c.server != nullptr) {
    o << "{\"clients\":" << c.server->clients.load()
      << ",\"timed_out\":" << c.server->timed_out.load()
      << ",\"turned_away\":" << c.server->turned_away.load()
      << ",\"bad_requests\":" << c.server->bad_requests.load() << "}";
  } else {
    o << "null";
  }
  o << ",\"alarms\":[";
  if (c.logger != nullptr) {
    const auto alarms = c.logger->last_alarms();
    for (std::size_t i = 0; i < alarms.size(); ++i) {
      const auto& a = alarms[i];
      o << (i ? "," : "") << "{\"time_s\":" << num(core::seconds(a.time_ns)) << ",\"severity\":\""
        << severity_name(a.severity) << "\",\"code\":" << static_cast<unsigned>(a.code)
        << ",\"name\":\"" << alarm_name(a.code) << "\",\"subject\":" << a.subject
        << ",\"value\":" << num(a.value) << "}";
    }
  }
  o << "]}\n";
  return o.str();
}

std::string render_text(const StatusContext& c) {
  const View v = gather(c);
  const auto& s = v.s;
  std::ostringstream o;
  char buf[256];
  o << "nccompd pid " << ::getpid() << ", config " << c.config_path << " (generation "
    << s.config_generation << ", " << s.reloads << " reload(s))" << (s.dry_run ? ", DRY RUN" : "")
    << "\n";
  if (s.hold) {
    o << "HOLD: offsets are held, nothing is written to the NC"
      << (v.problem.empty() ? "" : ": " + v.problem) << "\n";
  }
  std::snprintf(buf, sizeof buf,
                "loop:    %.1f Hz configured, %.1f Hz measured, %llu cycles, %llu overruns "
                "(%llu deadlines missed)\n",
                v.rate_hz, v.measured_rate_hz, static_cast<unsigned long long>(s.cycles),
                static_cast<unsigned long long>(s.overruns),
                static_cast<unsigned long long>(s.missed_deadlines));
  o << buf;
  std::snprintf(buf, sizeof buf,
                "latency: p50 %.0f us, p99 %.0f us, p99.9 %.0f us, max %.0f us; longest cycle "
                "%.0f us\n",
                v.p50, v.p99, v.p999, v.max_us, static_cast<double>(s.max_step_ns) / 1000.0);
  o << buf;
  o << "faults:  " << s.minor_faults_after_warmup << " minor, " << s.major_faults_after_warmup
    << " major page faults on the loop thread after warm-up";
  if (s.allocations_after_warmup >= 0) {
    // Only when an allocation counter is linked or preloaded (bench/daemon/alloc_preload).
    o << "; " << s.allocations_after_warmup << " allocations, " << s.frees_after_warmup << " frees";
  }
  o << "\n";
  o << "engine:  " << s.engine.events_accepted << " events (" << s.engine.events_invalid
    << " invalid), " << s.engine.writes_forwarded << " writes (" << s.engine.writes_rejected
    << " rejected, " << s.engine.writes_held << " held), " << s.writes_dropped
    << " dropped at the bus, " << s.engine.writes_awaiting_nc << " waits for the NC\n";
  if (s.handover.handovers > 0) {
    // A model loaded, replaced or taken out (docs/closing-the-loop.md, "handover").
    std::snprintf(buf, sizeof buf,
                  "handover: %llu (registers rebased %llu, not absorbed %llu); last: largest "
                  "trim change %.3f um, %.3f um through the limiter\n",
                  static_cast<unsigned long long>(s.handover.handovers),
                  static_cast<unsigned long long>(s.handover.rebases),
                  static_cast<unsigned long long>(s.handover.unabsorbed),
                  s.handover.last_trim_change_um, s.handover.last_unabsorbed_um);
    o << buf;
  }
  if (c.shadow) {
    const sections::ShadowStatus sh = c.shadow();
    const auto mse = [](const sections::ModelScore& m) {
      return m.parts == 0 ? std::string("-") : num(m.mse_um2()) + " um^2";
    };
    o << "model scores: live " << sh.live.parts << " parts, mse " << mse(sh.live);
    if (sh.phase != sections::ShadowPhase::kNone) {
      o << "; " << sections::phase_name(sh.phase) << " " << sh.other_file << " " << sh.other.parts
        << " parts, mse " << mse(sh.other) << ", p " << num(sh.window.p_value);
    }
    o << "\n";
  }
  o << "registers:\n";
  for (std::size_t i = 0; i < v.r.count; ++i) {
    const auto& r = v.r.regs[i];
    std::snprintf(buf, sizeof buf, "  %2zu %-24s %10.3f um", i, reg_name(v, i).c_str(),
                  r.output_um);
    o << buf;
    if (r.has_target) {
      std::snprintf(buf, sizeof buf, "  target %10.3f um%s", r.target_um,
                    r.slewing ? "  (slewing)" : "");
      o << buf;
    }
    // The bus has not confirmed the last write yet; the next one waits for it.
    if (r.awaiting_nc) {
      o << "  (waiting for the NC)";
    }
    // Held at start-up: nothing is written until `nccomp register release NAME`.
    if (r.hold == core::engine::RegisterHold::kBeyondLimit) {
      o << "  BLOCKED: the NC holds a value beyond max_abs_um";
    } else if (r.hold == core::engine::RegisterHold::kWithoutState) {
      o << "  HELD: no usable state";
    }
    o << "\n";
  }
  if (v.r.count < v.names.size()) {
    o << "  ... " << v.names.size() - v.r.count << " more (status shows the first "
      << kMaxSnapshotRegisters << ")\n";
  }
  for (std::size_t i = 0; i < v.m.count; ++i) {
    const auto& m = v.m.modules[i];
    o << "module " << m.name.data() << ":";
    for (std::size_t k = 0; k < m.count; ++k) {
      const auto& sv = m.values[k];
      o << (k ? ", " : " ") << sv.key << " ";
      if (sv.text != nullptr) {
        o << sv.text;
      } else {
        o << num(sv.value);
      }
    }
    o << "\n";
  }
  o << "buses:\n";
  for (const auto& [name, bus] : c.buses) {
    const auto st = bus->status();
    const auto& k = st.counters;
    std::snprintf(
        buf, sizeof buf,
        "  %-10s %-10s%s%s rx %llu, tx %llu, events %llu (dropped %llu, malformed "
        "%llu), offsets %llu (failed %llu), reconnects %llu, faults %llu\n",
        name.c_str(), link_state_name(st.state), st.alarm ? " ALARM" : "",
        st.input_stale ? " INPUT STALE" : "", static_cast<unsigned long long>(k.frames_rx),
        static_cast<unsigned long long>(k.frames_tx),
        static_cast<unsigned long long>(k.events_decoded),
        static_cast<unsigned long long>(k.events_dropped),
        static_cast<unsigned long long>(k.malformed),
        static_cast<unsigned long long>(k.offsets_written),
        static_cast<unsigned long long>(k.offsets_failed),
        static_cast<unsigned long long>(k.reconnects), static_cast<unsigned long long>(k.faults));
    o << buf;
    // Driver-specific counters, only the non-zero ones (a healthy bus prints none).
    std::array<drivers::BusCounterValue, drivers::kMaxBusExtraCounters> extra{};
    const std::size_t n_extra = std::min(bus->extra_counters(extra), extra.size());
    bool any = false;
    for (std::size_t e = 0; e < n_extra; ++e) {
      if (extra[e].value == 0) continue;
      o << (any ? ", " : "             ") << extra[e].name << " " << extra[e].value;
      any = true;
    }
    if (any) o << "\n";
  }
  o << "state:   " << c.state_path;
  if (c.persister != nullptr) {
    const auto ps = c.persister->stats();
    o << ", " << ps.writes << " writes, " << ps.failures << " failures"
      << (ps.last_error.empty() ? "" : " (last: " + ps.last_error + ")");
  }
  o << "\n";
  if (c.measurement_log != nullptr) {
    o << "measurements: " << c.measurement_log->current_path() << ", " << c.measurement_log->rows()
      << " rows, " << s.records_dropped << " dropped";
    if (s.face_probe_rejected > 0) {
      o << ", " << s.face_probe_rejected << " face probe reading(s) without a row";
    }
    o << "\n";
  }
  if (c.server != nullptr) {
    o << "clients: " << c.server->clients.load() << " served, " << c.server->timed_out.load()
      << " cut off at their deadline, " << c.server->turned_away.load() << " turned away (busy), "
      << c.server->bad_requests.load() << " bad requests\n";
  }
  o << "alarms (last " << EventLogger::kKeepAlarms << "):\n";
  if (c.logger != nullptr) {
    const auto alarms = c.logger->last_alarms();
    if (alarms.empty()) {
      o << "  none\n";
    }
    for (const auto& a : alarms) {
      std::snprintf(buf, sizeof buf, "  %12.3f s  %-7s %-30s subject %d value %g\n",
                    core::seconds(a.time_ns), severity_name(a.severity), alarm_name(a.code).c_str(),
                    a.subject, a.value);
      o << buf;
    }
  }
  return o.str();
}

namespace {

// A sample value in the Prometheus text format (NaN and infinities spelled its way).
std::string prom_num(double v) {
  if (std::isnan(v)) return "NaN";
  if (std::isinf(v)) return v > 0 ? "+Inf" : "-Inf";
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.10g", v);
  return buf;
}

// Edges [µs] of the wake-up latency histogram: bucket edges of LatencyHistogram, so the counts
// are exact (StatusMetrics.LatencyEdgesAreBucketEdges).
constexpr std::array<std::uint64_t, 14> kLatencyEdgesUs = {
    10, 20, 50, 100, 200, 500, 1000, 2000, 4000, 8000, 16000, 32000, 64000, 128000};

// A label value in the Prometheus text format: backslash, double quote and newline escaped.
std::string prom_label(std::string_view v) {
  std::string out;
  out.reserve(v.size());
  for (const char ch : v) {
    if (ch == '\\' || ch == '"') {
      out += '\\';
      out += ch;
    } else if (ch == '\n') {
      out += "\\n";
    } else {
      out += ch;
    }
  }
  return out;
}

}  // namespace

std::string sigma_estimate_key(std::string_view key) {
  constexpr std::string_view kEstimateSigma = "_estimate_sigma_um";
  constexpr std::string_view kSigma = "_sigma_um";
  if (key.size() > kEstimateSigma.size() && key.ends_with(kEstimateSigma)) {
    return std::string(key.substr(0, key.size() - kEstimateSigma.size())) + "_estimate_um";
  }
  if (key.size() > kSigma.size() && key.ends_with(kSigma)) {
    return std::string(key.substr(0, key.size() - kSigma.size())) + "_estimate_um";
  }
  return {};
}

namespace {

/// A derived sensor's status key `sensor_N_<what>`: {"N", what}; empty strings for another key.
std::pair<std::string, std::string> derived_sensor_key(std::string_view key) {
  constexpr std::string_view kPrefix = "sensor_";
  if (!key.starts_with(kPrefix)) return {};
  key.remove_prefix(kPrefix.size());
  const std::size_t digits = key.find_first_not_of("0123456789");
  if (digits == 0 || digits == std::string_view::npos || key[digits] != '_') return {};
  return {std::string(key.substr(0, digits)), std::string(key.substr(digits + 1))};
}

}  // namespace

std::pair<std::string, std::string> input_lag_key(std::string_view key) {
  auto k = derived_sensor_key(key);
  if (k.second != "lag" && k.second != "input") return {};
  return k;
}

std::string input_sum_key(std::string_view key) {
  auto k = derived_sensor_key(key);
  return k.second == "sum" ? k.first : std::string();
}

std::span<const std::uint64_t> prometheus_latency_edges_us() { return kLatencyEdgesUs; }

std::string render_prometheus(const StatusContext& c) {
  const View v = gather(c);
  const auto& s = v.s;
  std::ostringstream o;
  auto family = [&](const std::string& name, const char* type, const std::string& help) {
    o << "# HELP nccompd_" << name << " " << help << "\n# TYPE nccompd_" << name << " " << type
      << "\n";
  };
  auto counter = [&](const char* name, const char* help, std::uint64_t value) {
    family(name, "counter", help);
    o << "nccompd_" << name << " " << value << "\n";
  };
  counter("loop_cycles_total", "Loop cycles run.", s.cycles);
  counter("loop_overruns_total", "Cycles that finished after the next deadline.", s.overruns);
  counter("loop_missed_deadlines_total", "Deadlines skipped after overruns.", s.missed_deadlines);
  counter("offset_writes_total", "Offset writes queued to a bus.", s.writes_sent);
  counter("offset_writes_dropped_total", "Offset writes the bus could not take.", s.writes_dropped);
  counter("face_probe_rejected_total",
          "Face probe readings that gave no measurement row ([measurement_log.face_probe]).",
          s.face_probe_rejected);
  counter("engine_events_invalid_total", "Events rejected by validation.", s.engine.events_invalid);
  counter("engine_writes_rejected_total", "Targets refused by a limiter.",
          s.engine.writes_rejected);
  counter("engine_writes_awaiting_nc_total",
          "Register cycles whose next write waited for the NC to take the last one.",
          s.engine.writes_awaiting_nc);
  counter("alarms_total", "Alarms and warnings raised.", s.alarms);
  counter("handovers_total", "Model handovers (a model loaded, replaced or taken out).",
          s.handover.handovers);
  counter("handover_rebased_total", "Registers whose writing module took a handover's change.",
          s.handover.rebases);
  counter("handover_unabsorbed_total",
          "Registers whose total moved by a handover's change, through the limiter.",
          s.handover.unabsorbed);
  family("config_swap_waiting_cycles", "gauge",
         "Cycles an accepted configuration (a model loaded, promoted, rolled back) has waited "
         "for the bus to confirm every write in flight before the loop swaps it in (0: none).");
  o << "nccompd_config_swap_waiting_cycles " << s.swap_waiting << "\n";
  family("last_handover_trim_change_meters", "gauge",
         "Largest change of a register's trims at the last handover.");
  o << "nccompd_last_handover_trim_change_meters "
    << prom_num(s.handover.last_trim_change_um * 1e-6) << "\n";
  family("last_handover_unabsorbed_meters", "gauge",
         "Largest change no module absorbed at the last handover.");
  o << "nccompd_last_handover_unabsorbed_meters " << prom_num(s.handover.last_unabsorbed_um * 1e-6)
    << "\n";
  if (c.shadow) {
    const sections::ShadowStatus sh = c.shadow();
    family("shadow_parts_scored", "gauge",
           "Parts scored by the live model (since it became live) and by the other model in "
           "shadow (since it came in).");
    o << "nccompd_shadow_parts_scored{model=\"live\"} " << sh.live.parts << "\n";
    o << "nccompd_shadow_parts_scored{model=\"other\"} " << sh.other.parts << "\n";
    family("shadow_mean_squared_error_square_meters", "gauge",
           "Mean over parts of each part's mean squared prediction error.");
    o << "nccompd_shadow_mean_squared_error_square_meters{model=\"live\"} "
      << prom_num(sh.live.mse_um2() * 1e-12) << "\n";
    o << "nccompd_shadow_mean_squared_error_square_meters{model=\"other\"} "
      << prom_num(sh.other.mse_um2() * 1e-12) << "\n";
    family("shadow_sign_test_p_value", "gauge",
           "One-sided sign test of the other model against the live one over the paired parts.");
    o << "nccompd_shadow_sign_test_p_value " << prom_num(sh.window.p_value) << "\n";
    family("shadow_decisions", "gauge", "Decisions in the shadow's history.");
    o << "nccompd_shadow_decisions " << sh.history.size() << "\n";
  }
  if (c.server != nullptr) {
    counter("status_clients_timed_out_total", "Status clients cut off at their deadline.",
            c.server->timed_out.load());
    counter("status_clients_turned_away_total", "Status clients refused as busy.",
            c.server->turned_away.load());
  }
  family("loop_rate_hertz", "gauge", "Measured loop rate since start.");
  o << "nccompd_loop_rate_hertz " << prom_num(v.measured_rate_hz) << "\n";
  {
    const auto& h = c.loop->latency();
    std::array<std::uint64_t, kLatencyEdgesUs.size()> below{};
    std::uint64_t total = 0;
    h.count_below_us(kLatencyEdgesUs, below, total);
    family("loop_wake_latency_seconds", "histogram",
           "Wake-up latency of the loop thread after its deadline, since start.");
    for (std::size_t i = 0; i < kLatencyEdgesUs.size(); ++i) {
      o << "nccompd_loop_wake_latency_seconds_bucket{le=\""
        << prom_num(static_cast<double>(kLatencyEdgesUs[i]) / 1e6) << "\"} " << below[i] << "\n";
    }
    o << "nccompd_loop_wake_latency_seconds_bucket{le=\"+Inf\"} " << total << "\n"
      << "nccompd_loop_wake_latency_seconds_sum " << prom_num(h.sum_s()) << "\n"
      << "nccompd_loop_wake_latency_seconds_count " << total << "\n";
    family("loop_wake_latency_max_seconds", "gauge", "Largest wake-up latency since start.");
    o << "nccompd_loop_wake_latency_max_seconds " << prom_num(static_cast<double>(h.max_ns()) / 1e9)
      << "\n";
  }
  family("hold", "gauge", "1 while offsets are held (state corrupt).");
  o << "nccompd_hold " << (s.hold ? 1 : 0) << "\n";
  family("register_output_meters", "gauge", "Offset last sent per register.");
  for (std::size_t i = 0; i < v.r.count; ++i) {
    o << "nccompd_register_output_meters{register=\"" << reg_name(v, i) << "\"} "
      << prom_num(v.r.regs[i].output_um * 1e-6) << "\n";
  }
  family("register_held", "gauge", "1 while a register is held at start-up (nothing written).");
  for (std::size_t i = 0; i < v.r.count; ++i) {
    o << "nccompd_register_held{register=\"" << reg_name(v, i) << "\"} "
      << (v.r.regs[i].hold == core::engine::RegisterHold::kNone ? 0 : 1) << "\n";
  }
  family("module_value", "gauge", "A compensation module's status value (unit in the key).");
  for (std::size_t i = 0; i < v.m.count; ++i) {
    const auto& m = v.m.modules[i];
    for (std::size_t k = 0; k < m.count; ++k) {
      const auto& sv = m.values[k];
      if (sv.text == nullptr && std::isfinite(sv.value)) {
        o << "nccompd_module_value{module=\"" << m.name.data() << "\",key=\"" << sv.key << "\"} "
          << prom_num(sv.value) << "\n";
      }
    }
  }
  // A text value (a phase, a mode, where a value comes from) is a label of a gauge that is 1.
  family("module_text", "gauge",
         "A compensation module's status text (the label text; the value is always 1).");
  for (std::size_t i = 0; i < v.m.count; ++i) {
    const auto& m = v.m.modules[i];
    for (std::size_t k = 0; k < m.count; ++k) {
      const auto& sv = m.values[k];
      if (sv.text != nullptr) {
        o << "nccompd_module_text{module=\"" << m.name.data() << "\",key=\"" << sv.key
          << "\",text=\"" << prom_label(sv.text) << "\"} 1\n";
      }
    }
  }
  // The uncertainty of an estimated compensation value: a status key <stem>_sigma_um is the
  // standard deviation of <stem>_estimate_um (S0: wear_sigma_um of wear_estimate_um), and
  // <stem>_estimate_sigma_um that of <stem>_estimate_um (S3: x_estimate_sigma_um of
  // x_estimate_um), in metres as the registers' outputs.
  family("module_sigma_meters", "gauge",
         "Standard deviation of a module's estimated compensation value (the key).");
  for (std::size_t i = 0; i < v.m.count; ++i) {
    const auto& m = v.m.modules[i];
    for (std::size_t k = 0; k < m.count; ++k) {
      const auto& sv = m.values[k];
      const std::string estimate_key = sigma_estimate_key(sv.key);
      if (sv.text == nullptr && std::isfinite(sv.value) && !estimate_key.empty()) {
        o << "nccompd_module_sigma_meters{module=\"" << m.name.data() << "\",key=\"" << estimate_key
          << "\"} " << prom_num(sv.value * 1e-6) << "\n";
      }
    }
  }
  // [[input_lags]]: each lag's value and its input's, labelled by the lag's sensor (the module's
  // keys sensor_N_lag and sensor_N_input), in the input's unit.
  {
    std::string lag_values;
    std::string lag_inputs;
    for (std::size_t i = 0; i < v.m.count; ++i) {
      const auto& m = v.m.modules[i];
      if (std::string_view(m.name.data()) != "input_lags") continue;
      for (std::size_t k = 0; k < m.count; ++k) {
        const auto& sv = m.values[k];
        if (sv.text != nullptr || !std::isfinite(sv.value)) continue;
        const auto [sensor, what] = input_lag_key(sv.key);
        if (sensor.empty()) continue;
        (what == "lag" ? lag_values : lag_inputs) +=
            std::string(what == "lag" ? "nccompd_input_lag_value"
                                      : "nccompd_input_lag_input_value") +
            "{sensor=\"" + sensor + "\"} " + prom_num(sv.value) + "\n";
      }
    }
    if (!lag_values.empty()) {
      family("input_lag_value", "gauge",
             "An [[input_lags]] lag's value now (labelled by the sensor it is published on), in "
             "its input's unit.");
      o << lag_values;
    }
    if (!lag_inputs.empty()) {
      family("input_lag_input_value", "gauge",
             "The last sample of an [[input_lags]] lag's input sensor (labelled by the lag's "
             "sensor).");
      o << lag_inputs;
    }
  }
  // [[input_sums]]: each sum's value, labelled by its sensor (the module's keys sensor_N_sum).
  {
    std::string sum_values;
    for (std::size_t i = 0; i < v.m.count; ++i) {
      const auto& m = v.m.modules[i];
      if (std::string_view(m.name.data()) != "input_sums") continue;
      for (std::size_t k = 0; k < m.count; ++k) {
        const auto& sv = m.values[k];
        if (sv.text != nullptr || !std::isfinite(sv.value)) continue;
        const std::string sensor = input_sum_key(sv.key);
        if (sensor.empty()) continue;
        sum_values +=
            "nccompd_input_sum_value{sensor=\"" + sensor + "\"} " + prom_num(sv.value) + "\n";
      }
    }
    if (!sum_values.empty()) {
      family("input_sum_value", "gauge",
             "An [[input_sums]] sum's value now, offset + the weighted sum of its inputs "
             "(labelled by the sensor it is published on).");
      o << sum_values;
    }
  }
  family("bus_up", "gauge", "1 while the bus link is up.");
  for (const auto& [name, bus] : c.buses) {
    o << "nccompd_bus_up{bus=\"" << name << "\"} "
      << (bus->status().state == drivers::LinkState::kUp ? 1 : 0) << "\n";
  }
  family("bus_input_stale", "gauge",
         "1 while the bus's input is stale (no usable sample for longer than "
         "degraded_alarm_after_s).");
  for (const auto& [name, bus] : c.buses) {
    o << "nccompd_bus_input_stale{bus=\"" << name << "\"} " << (bus->status().input_stale ? 1 : 0)
      << "\n";
  }
  family("bus_faults_total", "counter", "Bus faults.");
  for (const auto& [name, bus] : c.buses) {
    o << "nccompd_bus_faults_total{bus=\"" << name << "\"} " << bus->status().counters.faults
      << "\n";
  }
  // Driver-specific values: the counts as one counter family (event = the driver's name); each
  // gauge as its own family (nccompd_bus_<name>, milliseconds as seconds), its samples for every
  // bus together.
  std::string counts;
  struct Gauge {
    std::string family, help, samples;
  };
  std::vector<Gauge> gauges;
  for (const auto& [name, bus] : c.buses) {
    std::array<drivers::BusCounterValue, drivers::kMaxBusExtraCounters> extra{};
    const std::size_t n_extra = std::min(bus->extra_counters(extra), extra.size());
    for (std::size_t e = 0; e < n_extra; ++e) {
      const std::string_view key = extra[e].name;
      if (!extra[e].gauge) {
        counts += "nccompd_bus_events_total{bus=\"" + name + "\",event=\"" + std::string(key) +
                  "\"} " + std::to_string(extra[e].value) + "\n";
        continue;
      }
      const bool ms = key.ends_with("_ms");
      const std::string family_name =
          "bus_" + std::string(ms ? key.substr(0, key.size() - 3) : key) + (ms ? "_seconds" : "");
      const double value = static_cast<double>(extra[e].value) * (ms ? 1e-3 : 1.0);
      auto it = std::find_if(gauges.begin(), gauges.end(),
                             [&](const Gauge& g) { return g.family == family_name; });
      if (it == gauges.end()) {
        it = gauges.insert(
            gauges.end(),
            Gauge{family_name, "The driver's " + family_name.substr(4) + " now.", {}});
      }
      it->samples += "nccompd_" + family_name + "{bus=\"" + name + "\"} " + prom_num(value) + "\n";
    }
  }
  family("bus_events_total", "counter", "Driver-specific bus events (fault kinds, rejects).");
  o << counts;
  for (const Gauge& g : gauges) {
    family(g.family, "gauge", g.help);
    o << g.samples;
  }
  return o.str();
}

namespace {

using Clock = std::chrono::steady_clock;

constexpr std::size_t kUnixRequestBytes = 512;   // one line, the newline included
constexpr std::size_t kHttpRequestBytes = 4096;  // the request line and headers
constexpr std::size_t kMaxCommandsWaiting = 8;   // queued or running on the command thread

// The caller as the kernel recorded it at connect(): SO_PEERGROUPS, not /proc/<pid>/status (the
// pid may have exited and been reused by then) nor getgrouplist(uid) (the group database, not
// the process: it would grant a group the caller's process has dropped or not yet received).
Caller peer_of(int fd) {
  Caller c;
  ucred cred{};
  socklen_t len = sizeof cred;
  if (::getsockopt(fd, SOL_SOCKET, SO_PEERCRED, &cred, &len) != 0) {
    return c;
  }
  c.known = true;
  c.pid = cred.pid;
  c.uid = cred.uid;
  c.gid = cred.gid;
  std::vector<gid_t> groups(64);
  for (int attempt = 0; attempt < 2; ++attempt) {
    socklen_t glen = static_cast<socklen_t>(groups.size() * sizeof(gid_t));
    if (::getsockopt(fd, SOL_SOCKET, SO_PEERGROUPS, groups.data(), &glen) == 0) {
      groups.resize(glen / sizeof(gid_t));
      c.groups = std::move(groups);
      c.groups_known = true;
      break;
    }
    if (errno != ERANGE) break;
    groups.resize(glen / sizeof(gid_t) + 1);  // the kernel said how many it has
  }
  return c;
}

// A last word to a client being dropped; never waits (the client may not read).
void send_nowait(int fd, const std::string& s) {
  (void)::send(fd, s.data(), s.size(), MSG_NOSIGNAL | MSG_DONTWAIT);
}

std::string http_response(const std::string& status, const std::string& body) {
  return "HTTP/1.0 " + status + "\r\nContent-Type: text/plain; version=0.0.4\r\nContent-Length: " +
         std::to_string(body.size()) + "\r\nConnection: close\r\n\r\n" + body;
}

// Client side: blocking.
Clock::time_point deadline_after(double s) {
  return Clock::now() +
         std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(s));
}

std::string seconds_text(double s) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", s);
  return buf;
}

}  // namespace

struct StatusServer::Client {
  enum class Phase { kReading, kCommand, kWriting, kDone };
  int fd{-1};
  bool http{false};
  std::uint64_t id{0};
  Caller caller;
  Phase phase{Phase::kReading};
  Clock::time_point deadline;
  std::string in;
  std::string out;
  std::size_t sent{0};
};

StatusServer::StatusServer(StatusContext context) : context_(std::move(context)) {
  context_.server = &counters_;
}

StatusServer::~StatusServer() { stop(); }

void StatusServer::start(const StatusServerOptions& options) {
  options_ = options;
  options_.client_timeout_s = std::clamp(options_.client_timeout_s, 0.01, 3600.0);
  options_.max_clients = std::max(options_.max_clients, 1);
  const std::string& socket_path = options_.socket_path;
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  if (socket_path.size() >= sizeof(addr.sun_path)) {
    throw std::system_error(ENAMETOOLONG, std::generic_category(),
                            "status socket path '" + socket_path + "'");
  }
  std::memcpy(addr.sun_path, socket_path.c_str(), socket_path.size() + 1);
  ::unlink(socket_path.c_str());  // a stale socket of a crashed daemon
  unix_fd_ = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
  if (unix_fd_ < 0) {
    sys_fail("status socket");
  }
  if (::bind(unix_fd_, reinterpret_cast<const sockaddr*>(&addr), sizeof(addr)) != 0) {
    sys_fail("cannot bind status socket '" + socket_path + "'");
  }
  if (::chmod(socket_path.c_str(), 0660) != 0) {
    sys_fail("cannot chmod status socket '" + socket_path + "'");
  }
  if (::listen(unix_fd_, 64) != 0) {
    sys_fail("cannot listen on '" + socket_path + "'");
  }
  const int prometheus_port = options_.prometheus_port;
  const std::string& prometheus_address = options_.prometheus_address;
  if (prometheus_port > 0 || prometheus_port == -1) {
    const bool v6 = prometheus_address == "::1";
    tcp_fd_ = ::socket(v6 ? AF_INET6 : AF_INET, SOCK_STREAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
    if (tcp_fd_ < 0) {
      sys_fail("prometheus socket");
    }
    const int one = 1;
    ::setsockopt(tcp_fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    const auto port = static_cast<std::uint16_t>(prometheus_port < 0 ? 0 : prometheus_port);
    int rc = 0;
    if (v6) {
      sockaddr_in6 a{};
      a.sin6_family = AF_INET6;
      a.sin6_port = htons(port);
      a.sin6_addr = in6addr_loopback;
      rc = ::bind(tcp_fd_, reinterpret_cast<const sockaddr*>(&a), sizeof a);
    } else {
      sockaddr_in a{};
      a.sin_family = AF_INET;
      a.sin_port = htons(port);
      a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
      rc = ::bind(tcp_fd_, reinterpret_cast<const sockaddr*>(&a), sizeof a);
    }
    if (rc != 0 || ::listen(tcp_fd_, 64) != 0) {
      sys_fail("cannot listen on " + prometheus_address + ":" + std::to_string(port));
    }
    sockaddr_storage got{};
    socklen_t len = sizeof got;
    ::getsockname(tcp_fd_, reinterpret_cast<sockaddr*>(&got), &len);
    bound_port_ = ntohs(v6 ? reinterpret_cast<sockaddr_in6*>(&got)->sin6_port
                           : reinterpret_cast<sockaddr_in*>(&got)->sin_port);
  }
  wake_fd_ = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
  if (wake_fd_ < 0) {
    sys_fail("status eventfd");
  }
  stop_.store(false);
  thread_ = std::thread([this] { run(); });
  command_thread_ = std::thread([this] { run_commands(); });
}

void StatusServer::stop() {
  {
    std::lock_guard<std::mutex> lock(jobs_mu_);
    stop_.store(true);
  }
  jobs_cv_.notify_all();
  if (wake_fd_ >= 0) {
    const std::uint64_t one = 1;
    (void)!::write(wake_fd_, &one, sizeof one);
  }
  if (thread_.joinable()) {
    thread_.join();
  }
  if (command_thread_.joinable()) {
    command_thread_.join();
  }
  if (unix_fd_ >= 0) {
    ::close(unix_fd_);
    ::unlink(options_.socket_path.c_str());
    unix_fd_ = -1;
  }
  if (tcp_fd_ >= 0) {
    ::close(tcp_fd_);
    tcp_fd_ = -1;
  }
  if (wake_fd_ >= 0) {
    ::close(wake_fd_);
    wake_fd_ = -1;
  }
  jobs_.clear();
  finished_.clear();
}

void StatusServer::run_commands() {
  for (;;) {
    Job job;
    {
      std::unique_lock<std::mutex> lock(jobs_mu_);
      jobs_cv_.wait(lock, [this] { return stop_.load() || !jobs_.empty(); });
      if (stop_.load()) {
        return;
      }
      job = std::move(jobs_.front());
      jobs_.pop_front();
    }
    std::string answer;
    if (!dispatch_command(job.line, job.caller, options_.policy, answer)) {
      answer = "error: unknown request\n";  // only if the verb were unregistered meanwhile
    }
    {
      std::lock_guard<std::mutex> lock(jobs_mu_);
      finished_.emplace_back(job.client, std::move(answer));
    }
    const std::uint64_t one = 1;
    (void)!::write(wake_fd_, &one, sizeof one);
  }
}

void StatusServer::accept_clients(int listen_fd, bool http, std::vector<Client>& clients) {
  for (;;) {
    const int fd = ::accept4(listen_fd, nullptr, nullptr, SOCK_CLOEXEC | SOCK_NONBLOCK);
    if (fd < 0) {
      if (errno == EINTR || errno == ECONNABORTED) continue;
      return;  // EAGAIN: none left; anything else is tried again at the next poll
    }
    counters_.clients.fetch_add(1);
    if (clients.size() >= static_cast<std::size_t>(options_.max_clients)) {
      counters_.turned_away.fetch_add(1);
      const std::string why = "busy: " + std::to_string(clients.size()) +
                              " clients are being served ([status] max_clients); try again\n";
      send_nowait(fd, http ? http_response("503 Service Unavailable", why) : "error: " + why);
      ::close(fd);
      continue;
    }
    Client c;
    c.fd = fd;
    c.http = http;
    c.id = next_client_++;
    c.deadline = deadline_after(options_.client_timeout_s);
    if (!http) {
      c.caller = peer_of(fd);
    }
    clients.push_back(std::move(c));
  }
}

void StatusServer::read_request(Client& c) {
  const std::size_t limit = c.http ? kHttpRequestBytes : kUnixRequestBytes;
  const char* terminator = c.http ? "\r\n\r\n" : "\n";
  bool eof = false;
  char buf[512];
  while (c.in.size() < limit && c.in.find(terminator) == std::string::npos) {
    const ssize_t n = ::recv(c.fd, buf, std::min(sizeof buf, limit - c.in.size()), 0);
    if (n > 0) {
      c.in.append(buf, static_cast<std::size_t>(n));
    } else if (n == 0) {
      eof = true;
      break;
    } else if (errno == EINTR) {
      continue;
    } else if (errno == EAGAIN || errno == EWOULDBLOCK) {
      return;  // more at the next poll, until the deadline
    } else {
      ::close(c.fd);
      c.fd = -1;
      c.phase = Client::Phase::kDone;
      return;
    }
  }
  const bool complete = eof || c.in.find(terminator) != std::string::npos;
  const auto reply = [&](std::string text) { start_answer(c, std::move(text)); };
  if (c.http) {
    // A request line and headers longer than the limit are answered from the request line.
    if (c.in.rfind("GET /metrics", 0) == 0 || c.in.rfind("GET / ", 0) == 0) {
      reply(http_response("200 OK", render_prometheus(context_)));
    } else {
      counters_.bad_requests.fetch_add(1);
      reply(http_response("404 Not Found", "GET /metrics\n"));
    }
    return;
  }
  if (!complete) {
    counters_.bad_requests.fetch_add(1);
    reply("error: request longer than " + std::to_string(kUnixRequestBytes - 1) +
          " bytes (one line: text, json, metrics or an operator command)\n");
    return;
  }
  // One line: a status request, or an operator command ("calibrate facets lateral 1.99 1.98").
  std::string req = c.in.substr(0, c.in.find('\n'));
  while (!req.empty() && (req.back() == '\r' || req.back() == ' ')) {
    req.pop_back();
  }
  if (is_command(req)) {
    if (commands_in_flight_ >= kMaxCommandsWaiting) {
      counters_.turned_away.fetch_add(1);
      reply("error: busy: " + std::to_string(commands_in_flight_) +
            " operator commands are waiting for the loop; try again\n");
      return;
    }
    ++commands_in_flight_;
    c.phase = Client::Phase::kCommand;  // no deadline: the handler has its own
    {
      std::lock_guard<std::mutex> lock(jobs_mu_);
      jobs_.push_back(Job{c.id, req, c.caller});
    }
    jobs_cv_.notify_one();
    return;
  }
  if (req == client::kStatusJson) {
    reply(render_json(context_));
  } else if (req == client::kStatusMetrics) {
    reply(render_prometheus(context_));
  } else if (req == client::kStatusText || req.empty()) {
    reply(render_text(context_));
  } else {
    counters_.bad_requests.fetch_add(1);
    reply("error: unknown request '" + req.substr(0, 32) + "' (text, json, metrics)\n");
  }
}

void StatusServer::start_answer(Client& c, std::string text) {
  c.out = std::move(text);
  c.sent = 0;
  c.phase = Client::Phase::kWriting;
  c.deadline = deadline_after(options_.client_timeout_s);
  answer(c);
}

void StatusServer::answer(Client& c) {
  while (c.sent < c.out.size()) {
    const ssize_t n =
        ::send(c.fd, c.out.data() + c.sent, c.out.size() - c.sent, MSG_NOSIGNAL | MSG_DONTWAIT);
    if (n > 0) {
      c.sent += static_cast<std::size_t>(n);
    } else if (n < 0 && errno == EINTR) {
      continue;
    } else if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
      return;  // the client reads slowly: the rest at the next POLLOUT, until the deadline
    } else {
      break;  // the client has gone
    }
  }
  ::close(c.fd);
  c.fd = -1;
  c.phase = Client::Phase::kDone;
}

void StatusServer::take_finished(std::vector<Client>& clients) {
  std::vector<std::pair<std::uint64_t, std::string>> done;
  {
    std::lock_guard<std::mutex> lock(jobs_mu_);
    done.swap(finished_);
  }
  for (auto& [id, text] : done) {
    --commands_in_flight_;
    for (auto& c : clients) {
      if (c.id == id && c.phase == Client::Phase::kCommand) {
        start_answer(c, std::move(text));
        break;
      }
    }
  }
}

void StatusServer::run() {
  std::vector<Client> clients;
  std::vector<pollfd> fds;
  std::vector<std::size_t> owner;  // fds[3 + k] belongs to clients[owner[k]]
  while (!stop_.load()) {
    fds.clear();
    owner.clear();
    fds.push_back({wake_fd_, POLLIN, 0});
    fds.push_back({unix_fd_, POLLIN, 0});
    fds.push_back({tcp_fd_, POLLIN, 0});  // -1 (no Prometheus port) is ignored by poll
    const auto now = Clock::now();
    auto next = now + std::chrono::milliseconds(200);
    for (std::size_t i = 0; i < clients.size(); ++i) {
      const Client& c = clients[i];
      if (c.phase != Client::Phase::kReading && c.phase != Client::Phase::kWriting) {
        continue;  // a command running: its answer comes through wake_fd_
      }
      fds.push_back(
          {c.fd, static_cast<short>(c.phase == Client::Phase::kReading ? POLLIN : POLLOUT), 0});
      owner.push_back(i);
      next = std::min(next, c.deadline);
    }
    const auto wait =
        std::chrono::ceil<std::chrono::milliseconds>(std::max(next - now, Clock::duration{0}));
    if (::poll(fds.data(), fds.size(), static_cast<int>(wait.count())) < 0 && errno != EINTR) {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));  // e.g. ENOMEM: try again
      continue;
    }
    if ((fds[0].revents & POLLIN) != 0) {
      std::uint64_t n = 0;
      (void)!::read(wake_fd_, &n, sizeof n);
      take_finished(clients);
    }
    for (std::size_t k = 0; k < owner.size(); ++k) {
      if (fds[3 + k].revents == 0) continue;
      Client& c = clients[owner[k]];
      if (c.phase == Client::Phase::kReading) {
        read_request(c);
      } else if (c.phase == Client::Phase::kWriting) {
        answer(c);
      }
    }
    if ((fds[1].revents & POLLIN) != 0) {
      accept_clients(unix_fd_, false, clients);
    }
    if ((fds[2].revents & POLLIN) != 0) {
      accept_clients(tcp_fd_, true, clients);
    }
    const auto t = Clock::now();
    for (auto& c : clients) {
      const bool waiting = c.phase == Client::Phase::kReading || c.phase == Client::Phase::kWriting;
      if (!waiting || t < c.deadline) continue;
      counters_.timed_out.fetch_add(1);
      if (c.phase == Client::Phase::kReading) {
        const std::string why =
            "no complete request within " + seconds_text(options_.client_timeout_s) + " s\n";
        send_nowait(c.fd, c.http ? http_response("408 Request Timeout", why) : "error: " + why);
      }
      ::close(c.fd);
      c.fd = -1;
      c.phase = Client::Phase::kDone;
    }
    std::erase_if(clients, [](const Client& c) { return c.phase == Client::Phase::kDone; });
  }
  for (auto& c : clients) {
    if (c.fd >= 0) ::close(c.fd);
  }
}

}  // namespace nccomp::daemon
