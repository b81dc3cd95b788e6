#include "daemon/daemon.hpp"

#include <dlfcn.h>
#include <poll.h>
#include <signal.h>
#include <spdlog/spdlog.h>
#include <sys/mman.h>
#include <sys/signalfd.h>
#include <systemd/sd-daemon.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <functional>
#include <iostream>
#include <map>
#include <memory>
#include <mutex>
#include <optional>

#include "daemon/commands/command.hpp"
#include "daemon/config/builtin_sections.hpp"
#include "daemon/config/config.hpp"
#include "daemon/cpu_placement.hpp"
#include "daemon/events_while_down.hpp"
#include "daemon/lockstep.hpp"
#include "daemon/logging.hpp"
#include "daemon/loop.hpp"
#include "daemon/measurement_log.hpp"
#include "daemon/sections/model/model_section.hpp"
#include "daemon/state_store.hpp"
#include "daemon/status.hpp"
#include "daemon/timing.hpp"

namespace nccomp::daemon {

namespace {

namespace fs = std::filesystem;
namespace cfg = config;

/// The [model] section of the configuration file as it is now (a model verb checks against it);
/// nullptr with the reason in `error` when the file does not load or has no [model].
const sections::ModelSection* model_section_of(const cfg::LoadResult& current,
                                               const std::string& path, std::string& error) {
  if (!current.config) {
    error = "the configuration file does not load:\n" + current.diagnostics.to_string();
    return nullptr;
  }
  const auto* s = sections::model_section(*current.config);
  if (s == nullptr) {
    error = path +
            ": no [model] section: its [[model.apply]] entries say which term goes onto "
            "which register";
  }
  return s;
}

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__) || defined(NCCOMP_ASAN) || \
    defined(NCCOMP_TSAN)
constexpr bool kSanitizerBuild = true;
#else
constexpr bool kSanitizerBuild = false;
#endif

core::TimeNs monotonic_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<core::TimeNs>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

// A directory from the config, else systemd's environment variable, else the FHS default.
std::string pick_dir(const cfg::Config& c, const std::string& configured, const char* env,
                     const char* fallback) {
  if (!configured.empty()) {
    return c.resolve(configured);
  }
  if (const char* e = std::getenv(env); e != nullptr && *e != '\0') {
    // systemd may list several directories separated by ':'; the first is ours.
    std::string s(e);
    return s.substr(0, s.find(':'));
  }
  return fallback;
}

// The status socket: [status] socket_path, else in systemd's RuntimeDirectory, else in /run.
std::string status_socket_path(const cfg::Config& c) {
  const auto& s = cfg::status_section(c);
  return s.socket_path.empty()
             ? pick_dir(c, "", "RUNTIME_DIRECTORY", "/run/nccompd") + "/status.sock"
             : c.resolve(s.socket_path);
}

struct BusEntry {
  std::string name;
  std::unique_ptr<drivers::Bus> bus;
};

std::vector<BusEntry> make_buses(const cfg::Config& c) {
  std::vector<BusEntry> out;
  for (const auto* p : cfg::section_parsers()) {
    if (p->provides_bus() && c.has(p->name())) {
      out.push_back(BusEntry{std::string(p->name()), p->make_bus(c)});
    }
  }
  return out;
}

/// Builds a Runtime for the buses that run. Throws std::invalid_argument.
std::unique_ptr<Runtime> make_runtime(const cfg::Config& c, const std::vector<BusEntry>& buses,
                                      bool dry_run_cli, std::uint64_t generation) {
  auto rt = std::make_unique<Runtime>();
  formats::Diagnostics diag;
  rt->engine = cfg::build_engine(c, diag);
  if (!rt->engine) {
    // The engine's refusal, located: "file:line:column: key.path: message".
    std::string what = diag.to_string();
    while (!what.empty() && what.back() == '\n') {
      what.pop_back();
    }
    throw std::invalid_argument(what);
  }
  for (const auto& r : cfg::registers_section(c).registers) {
    int idx = -1;
    for (std::size_t b = 0; b < buses.size(); ++b) {
      if (buses[b].name == r.bus) {
        idx = static_cast<int>(b);
      }
    }
    if (idx < 0) {
      throw std::invalid_argument("register '" + r.spec.name + "' needs bus '" + r.bus +
                                  "', which is not running (bus changes need a restart)");
    }
    rt->register_bus.push_back(idx);
  }
  rt->dry_run = dry_run_cli || cfg::daemon_section(c).dry_run;
  rt->generation = generation;
  return rt;
}

std::vector<core::engine::RegisterSpec> register_specs(const cfg::Config& c) {
  std::vector<core::engine::RegisterSpec> specs;
  for (const auto& r : cfg::registers_section(c).registers) {
    specs.push_back(r.spec);
  }
  return specs;
}

std::vector<std::string> register_names(const cfg::Config& c) {
  std::vector<std::string> names;
  for (const auto& r : cfg::registers_section(c).registers) {
    names.push_back(r.spec.name);
  }
  return names;
}

void notify(const std::string& s) { (void)sd_notify(0, s.c_str()); }

std::vector<std::pair<std::string, StartupHook>>& hook_storage() {
  static std::vector<std::pair<std::string, StartupHook>> hooks;
  return hooks;
}

/// Loads the configuration; on errors prints them and "nccompd: N error(s) in FILE" to standard
/// error and returns null.
std::unique_ptr<cfg::Config> load_config(const std::string& path) {
  auto loaded = cfg::load_file(path);
  if (!loaded.config) {
    std::cerr << loaded.diagnostics.to_string() << "nccompd: " << loaded.diagnostics.items().size()
              << " error(s) in " << path << "\n";
  }
  return std::move(loaded.config);
}

/// A call from the status server's command thread run on the main thread, which alone reloads
/// (a model verb's reload must not race a SIGHUP's). One caller at a time (the command thread).
class MainThreadCalls {
 public:
  /// Runs f on the main thread (its next serve(), at most 100 ms away) and waits for it; false
  /// if the main thread did not take it within `timeout` (f is then never run).
  bool run(std::function<void()> f, std::chrono::milliseconds timeout) {
    std::unique_lock<std::mutex> lock(mu_);
    pending_ = std::move(f);
    done_ = false;
    if (!cv_.wait_for(lock, timeout, [this] { return done_ || running_; })) {
      pending_ = nullptr;
      return false;
    }
    cv_.wait(lock, [this] { return done_; });
    return true;
  }
  /// The main thread: runs the call waiting, if any.
  void serve() {
    std::unique_lock<std::mutex> lock(mu_);
    if (!pending_) return;
    std::function<void()> f = std::move(pending_);
    pending_ = nullptr;
    running_ = true;
    lock.unlock();
    f();
    lock.lock();
    running_ = false;
    done_ = true;
    cv_.notify_all();
  }

 private:
  std::mutex mu_;
  std::condition_variable cv_;
  std::function<void()> pending_;
  bool running_{false};
  bool done_{false};
};

/// What the registers' read-back at start-up found (anchor_registers, adopt_without_state).
struct ReadBackCounts {
  std::size_t anchored{0};
  std::size_t differ{0};
  std::size_t beyond{0};
  std::size_t adopted{0};
  std::size_t held{0};
};

/// The main thread's state while it runs the loop (Daemon::run_until_stopped).
struct RunState {
  HeartbeatWatch heartbeat{0};
  bool watchdog{false};
  std::uint64_t watchdog_usec{0};
  std::chrono::steady_clock::time_point last_feed;
  std::chrono::steady_clock::time_point last_status;
  bool stalled_logged{false};
  std::uint64_t sync_timeouts_logged{0};
  std::uint64_t flush_timeouts_logged{0};
  BusAlarmWatch bus_alarms;
  std::vector<std::string> bus_names;
  std::vector<drivers::BusStatus> bus_statuses;
};

/// nccompd's process from start to stop, as a sequence of steps (run()). Members are declared in
/// the order the steps create them: they are destroyed in the reverse order, the loop before the
/// buses, rings and persister it uses.
class Daemon {
 public:
  explicit Daemon(const DaemonOptions& options)
      : options_(options), lockstep_(!options.lockstep_socket.empty()) {}
  ~Daemon() {
    if (sfd_ >= 0) close(sfd_);
  }
  Daemon(const Daemon&) = delete;
  Daemon& operator=(const Daemon&) = delete;

  /// The process exit status (run_daemon's).
  int run() {
    if (!block_signals()) return 1;
    if (const int rc = configure(); rc != 0) return rc;
    place_cpus();
    restore_state();
    lock_memory();
    read_back_registers();
    if (!start_buses()) return 1;
    start_persister_and_log();
    if (!start_loop_and_status()) return 1;
    run_until_stopped();
    return shut_down();
  }

 private:
  const cfg::DaemonSection& dsec() const { return cfg::daemon_section(*config_); }
  bool block_signals();
  int configure();
  void place_cpus();
  void restore_state();
  void lock_memory();
  void read_back_registers();
  RegisterReader register_reader();
  ReadBackCounts anchor_registers(const RegisterReader& read, core::TimeNs now);
  void adopt_without_state(const RegisterReader& read, core::TimeNs now, ReadBackCounts& n);
  void run_startup_hooks(const RegisterReader& read, core::TimeNs now);
  bool start_buses();
  void start_persister_and_log();
  bool start_loop_and_status();
  LoopOptions loop_options();
  bool connect_lockstep();
  bool start_status();
  void log_loop_start(const LoopSetupReport& rep);
  void run_until_stopped();
  bool lockstep_ended(RunState& rs);
  bool handle_signal();
  /// A new configuration swapped in (SIGHUP, a model verb); "" if accepted, else why not (the
  /// configuration's errors, one per line).
  std::string reload(const std::string& why);
  /// The operator's model choice from the state directory, applied before the first parse.
  void restore_model_choice();
  /// model_state_ from a configuration that runs (start-up, every accepted reload).
  void note_model(const cfg::Config& config);
  ModelChange change_model(ModelAction action, const std::string& file, const std::string& who);
  /// A load or rollback (the caller checked nothing else runs).
  ModelChange load_or_roll_back(ModelAction action, const std::string& file);
  ModelChange take_candidate(const std::string& file, const std::string& who);
  /// The shadow's decisions: logged, carried out (promotion, demotion), recorded.
  void serve_shadow();
  void record_decision(sections::ShadowDecision d);
  void watch_buses(RunState& rs);
  void feed_watchdog(RunState& rs, std::chrono::steady_clock::time_point now);
  void update_status_line(RunState& rs, std::chrono::steady_clock::time_point now);
  int shut_down();

  const DaemonOptions& options_;
  const bool lockstep_;
  int sfd_{-1};
  std::shared_ptr<const cfg::Config> config_;
  std::vector<BusEntry> buses_;
  std::unique_ptr<Runtime> runtime_;  // until the loop's ConfigSwap takes it
  std::mutex names_mu_;
  std::shared_ptr<const std::vector<std::string>> names_;
  std::shared_ptr<const std::vector<core::engine::RegisterSpec>> specs_;  // under names_mu_
  std::vector<int> loop_cpus_;  // LoopOptions::cpu_affinity (cpu_placement.hpp)
  std::string state_path_;
  std::string state_problem_;  // not empty: offsets are held
  std::uint64_t sequence_{0};
  bool state_imported_{false};
  std::map<std::uint16_t, std::optional<double>> read_back_;  // each register read once
  EventsWhileDownLog::Buses event_buses_;
  EventsWhileDownLog events_while_down_;
  std::size_t blob_bytes_{0};
  std::unique_ptr<StatePersister> persister_;
  /// The candidate in shadow (before mlog_, whose thread feeds it) and its history file.
  sections::Shadow shadow_;
  std::string shadow_path_;
  std::unique_ptr<MeasurementLogWriter> mlog_;
  std::unique_ptr<core::rt::ConfigSwap<Runtime>> swap_;
  std::vector<drivers::Bus*> bus_ptrs_;
  CommandBus commands_;
  LockstepPeer peer_;
  std::unique_ptr<Loop> loop_;
  std::unique_ptr<EventLogger> logger_;
  StatusContext sc_;
  std::unique_ptr<StatusServer> status_;
  std::uint64_t generation_{1};
  /// The model verbs: their calls onto the main thread, the record of the operator's choice in
  /// the state directory, and the model in force (the command thread reads it).
  MainThreadCalls main_calls_;
  std::string model_choice_path_;
  std::mutex model_mu_;
  ModelState model_state_;  // under model_mu_: the last accepted configuration's
  /// The model the loop runs (under model_mu_): model_state_'s once the loop swapped in its
  /// generation.
  sections::ModelRecord running_model_;
  std::uint64_t running_generation_{0};
  /// model_state_ as the loop runs it: a model not swapped in yet is pending. Any thread.
  ModelState model_view();
};

// Signals are blocked before any thread exists, so every thread inherits the mask and the main
// thread alone receives them through the signalfd.
bool Daemon::block_signals() {
  sigset_t mask;
  sigemptyset(&mask);
  sigaddset(&mask, SIGTERM);
  sigaddset(&mask, SIGINT);
  sigaddset(&mask, SIGHUP);
  pthread_sigmask(SIG_BLOCK, &mask, nullptr);
  sfd_ = signalfd(-1, &mask, SFD_CLOEXEC);
  if (sfd_ < 0) {
    std::cerr << "nccompd: signalfd: " << std::strerror(errno) << "\n";
    return false;
  }
  return true;
}

// The configuration, the logging it asks for, the buses (not started) and the engine.
int Daemon::configure() {
  config_ = load_config(options_.config_path);
  if (!config_) {
    return 3;
  }
  const std::string log_target = setup_logging(cfg::log_section(*config_));
  spdlog::info("nccompd starting: config {}, logging to {}", options_.config_path, log_target);
  restore_model_choice();
  try {
    buses_ = make_buses(*config_);
    runtime_ = make_runtime(*config_, buses_, options_.dry_run, 1);
  } catch (const std::exception& e) {
    spdlog::error("configuration refused: {}", e.what());
    return 3;
  }
  if (runtime_->dry_run) {
    spdlog::warn(
        "DRY RUN: offsets are computed and logged, nothing is written to the NC, and the state "
        "file keeps what the NC has");
  }
  names_ = std::make_shared<const std::vector<std::string>>(register_names(*config_));
  specs_ =
      std::make_shared<const std::vector<core::engine::RegisterSpec>>(register_specs(*config_));
  note_model(*config_);
  return 0;
}

void Daemon::restore_model_choice() {
  const std::string state_dir = pick_dir(*config_, cfg::state_section(*config_).directory,
                                         "STATE_DIRECTORY", "/var/lib/nccompd");
  model_choice_path_ = state_dir + "/model-choice";
  shadow_path_ = state_dir + "/model-shadow";
  if (const StateFile h = read_state_file(shadow_path_); h.status != StateFileStatus::kAbsent) {
    try {
      if (h.status != StateFileStatus::kOk) throw std::invalid_argument(h.reason);
      shadow_.set_history(sections::history_from_text(
          std::string_view(reinterpret_cast<const char*>(h.payload.data()), h.payload.size())));
    } catch (const std::exception& e) {
      spdlog::error("model shadow history {} is unreadable ({}): starting a new one", shadow_path_,
                    e.what());
    }
  }
  const StateFile f = read_state_file(model_choice_path_);
  if (f.status == StateFileStatus::kAbsent) return;
  sections::ModelChoice choice;
  try {
    if (f.status != StateFileStatus::kOk) throw std::invalid_argument(f.reason);
    choice = sections::model_choice_from_text(
        std::string_view(reinterpret_cast<const char*>(f.payload.data()), f.payload.size()));
  } catch (const std::exception& e) {
    spdlog::error("model choice {} is unreadable ({}): the configuration's [model] runs",
                  model_choice_path_, e.what());
    return;
  }
  sections::set_model_choice(choice);
  auto again = cfg::load_file(options_.config_path);
  if (!again.config) {
    for (const auto& d : again.diagnostics.items()) {
      spdlog::error("model choice: {}", formats::format(d));
    }
    spdlog::error(
        "the model chosen by nccomp model load / rollback ({}) cannot run: the configuration's "
        "[model] runs",
        choice.live.file.empty() ? std::string("none") : choice.live.file);
    sections::set_model_choice(std::nullopt);
    return;
  }
  const auto* m = sections::model_section(*again.config);
  if (m != nullptr && m->chosen) {
    spdlog::info("model: {} (chosen by nccomp model load / rollback, {}); previous {}",
                 choice.live.file.empty() ? std::string("none") : choice.live.file,
                 model_choice_path_,
                 choice.previous.file.empty() ? std::string("none") : choice.previous.file);
  }
  config_ = std::move(again.config);
}

void Daemon::note_model(const cfg::Config& config) {
  ModelState m;
  m.generation = generation_;
  const auto* s = sections::model_section(config);
  auto choice = sections::model_choice();
  if (choice && (s == nullptr || !s->chosen)) {
    // The configuration names another file now (or has no [model]): the operator chose anew.
    spdlog::info(
        "model: the configuration's [model] replaces the model chosen by nccomp model "
        "load / rollback ({})",
        choice->live.file.empty() ? std::string("none") : choice->live.file);
    sections::set_model_choice(std::nullopt);
    choice.reset();
    std::error_code ec;
    fs::remove(model_choice_path_, ec);
  }
  std::lock_guard<std::mutex> lock(model_mu_);
  if (s != nullptr) {
    m.has_section = true;
    m.configured = s->configured_file;
    m.chosen = s->chosen && choice.has_value();
    if (m.chosen) {
      m.live = choice->live;
      m.previous = choice->previous;
    } else {
      m.live.file = s->file;
      m.live.since_utc = model_state_.live.file == s->file && !model_state_.live.since_utc.empty()
                             ? model_state_.live.since_utc
                             : sections::utc_now();
      try {
        m.live.hash = sections::model_file_hash(s->file);
      } catch (const std::exception&) {
        m.live.hash.clear();  // it loaded a moment ago; shown as unknown
      }
    }
  }
  std::vector<std::string> context_names;
  for (const auto& c : cfg::measurement_log_section(config).context_columns) {
    context_names.push_back(c.name);
  }
  shadow_.configure(s != nullptr ? s->shadow : sections::ShadowOptions{}, std::move(context_names));
  shadow_.set_live(m.live.file, m.live.hash,
                   s != nullptr && s->loaded && !s->disabled ? s->model : core::model::Model{});
  if (!loop_) {  // start-up: the loop starts with this configuration
    running_model_ = m.live;
    running_generation_ = m.generation;
  }
  model_state_ = std::move(m);
}

ModelState Daemon::model_view() {
  const LoopStats ls = loop_ ? loop_->stats() : LoopStats{};
  std::lock_guard<std::mutex> lock(model_mu_);
  const bool same = running_model_.file == model_state_.live.file &&
                    running_model_.hash == model_state_.live.hash;
  if (ls.cycles == 0 || ls.config_generation >= model_state_.generation) {
    if (running_generation_ < model_state_.generation) {
      // Seen within the main thread's 0.1 s poll of the swap: the model is live from here.
      if (!same) model_state_.live.since_utc = sections::utc_now();
      running_model_ = model_state_.live;
      running_generation_ = model_state_.generation;
    }
    return model_state_;
  }
  if (same) return model_state_;  // a reload that keeps the model
  ModelState m = model_state_;
  m.pending = true;
  m.pending_model = m.live;
  m.pending_model.since_utc.clear();
  m.pending_generation = m.generation;
  m.pending_cycles = ls.swap_waiting;
  m.live = running_model_;
  m.generation = ls.config_generation;
  return m;
}

ModelChange Daemon::change_model(ModelAction action, const std::string& file,
                                 const std::string& who) {
  if (action == ModelAction::kCandidate) return take_candidate(file, who);
  if (action != ModelAction::kPromote) return load_or_roll_back(action, file);
  ModelChange out;
  const sections::ShadowStatus sh = shadow_.status();
  if (sh.phase != sections::ShadowPhase::kAnnounced) {
    out.error = sh.phase == sections::ShadowPhase::kCandidate
                    ? fmt::format(
                          "the candidate {} has not been found better yet ({} of {} parts "
                          "scored)",
                          sh.other_file, sh.window.parts, sh.options.min_parts)
                    : "no candidate the rule found better (nccomp model status shows the shadow)";
    return out;
  }
  out = load_or_roll_back(ModelAction::kLoad, sh.other_file);
  if (out.ok) {
    shadow_.watch_previous();
    sections::ShadowDecision d;
    d.utc = sections::utc_now();
    d.action = "promoted";
    d.by = who.empty() ? "the operator" : who;
    d.live_file = sh.live_file;
    d.other_file = sh.other_file;
    d.test = sh.window;
    record_decision(std::move(d));
    std::lock_guard<std::mutex> lock(model_mu_);
    out.state.shadow = shadow_.status();
  }
  return out;
}

ModelChange Daemon::take_candidate(const std::string& file, const std::string& who) {
  ModelChange out;
  if (!mlog_) {
    out.error =
        "the measurement log is not running ([measurement_log]): the shadow scores the rows it "
        "writes";
    return out;
  }
  const auto current = cfg::load_file(options_.config_path);
  const auto* s = model_section_of(current, options_.config_path, out.error);
  if (s == nullptr) return out;
  // Parsed as a load would parse it: the candidate must be able to become live.
  const auto old = sections::model_choice();
  sections::ModelChoice trial;
  trial.configured = s->configured_file;
  trial.live.file = file;
  sections::set_model_choice(trial);
  auto check = cfg::load_file(options_.config_path);
  sections::set_model_choice(old);
  if (!check.config) {
    out.error = check.diagnostics.to_string();
    return out;
  }
  const auto* cs = sections::model_section(*check.config);
  if (cs == nullptr || !cs->loaded || cs->disabled) {
    out.error = "cannot load the model " + file;
    return out;
  }
  std::string hash;
  try {
    hash = sections::model_file_hash(file);
  } catch (const std::exception& e) {
    out.error = e.what();
    return out;
  }
  shadow_.set_candidate(file, hash, cs->model);
  sections::ShadowDecision d;
  d.utc = sections::utc_now();
  d.action = "candidate";
  d.by = who.empty() ? "the operator" : who;
  d.other_file = file;
  {
    std::lock_guard<std::mutex> lock(model_mu_);
    d.live_file = model_state_.live.file;
  }
  record_decision(std::move(d));
  out.ok = true;
  std::lock_guard<std::mutex> lock(model_mu_);
  out.state = model_state_;
  out.state.shadow = shadow_.status();
  return out;
}

void Daemon::record_decision(sections::ShadowDecision d) {
  if (d.action == "candidate") {
    spdlog::info("model shadow: {}", sections::describe(d));
  } else {
    spdlog::warn("model shadow: {}", sections::describe(d));
  }
  shadow_.record(std::move(d));
  try {
    const std::string text = sections::history_to_text(shadow_.history());
    write_state_file(
        shadow_path_,
        std::span<const std::byte>(reinterpret_cast<const std::byte*>(text.data()), text.size()),
        generation_);
  } catch (const std::exception& e) {
    spdlog::error("model shadow history not recorded: {}", e.what());
  }
}

void Daemon::serve_shadow() {
  auto d = shadow_.take_decision();
  if (!d) return;
  if (d->action == "promoted") {
    const ModelChange c = load_or_roll_back(ModelAction::kLoad, d->other_file);
    if (c.ok) {
      shadow_.watch_previous();
    } else {
      d->action = "refused";
      shadow_.clear();
      spdlog::error("model shadow: the promotion of {} was refused: {}", d->other_file, c.error);
    }
  } else if (d->action == "demoted") {
    const ModelChange c = load_or_roll_back(ModelAction::kRollback, "");
    if (!c.ok) {
      d->action = "refused";
      spdlog::error("model shadow: the demotion of {} was refused: {}", d->live_file, c.error);
    }
    shadow_.clear();
  }
  record_decision(std::move(*d));
}

ModelChange Daemon::load_or_roll_back(ModelAction action, const std::string& file) {
  ModelChange out;
  const auto current = cfg::load_file(options_.config_path);
  const auto* s = model_section_of(current, options_.config_path, out.error);
  if (s == nullptr) return out;
  const auto old = sections::model_choice();
  ModelState before;
  {
    std::lock_guard<std::mutex> lock(model_mu_);
    before = model_state_;
  }
  sections::ModelRecord in_force;
  if (s->chosen && old) {
    in_force = old->live;
  } else {
    in_force.file = s->file;
    in_force.since_utc = before.live.file == s->file ? before.live.since_utc : std::string();
    try {
      in_force.hash = sections::model_file_hash(s->file);
    } catch (const std::exception&) {
    }
  }
  sections::ModelChoice next;
  next.configured = s->configured_file;
  next.previous = in_force;
  if (action == ModelAction::kLoad) {
    next.live.file = file;
    try {
      next.live.hash = sections::model_file_hash(file);
    } catch (const std::exception& e) {
      out.error = e.what();
      return out;
    }
  } else {
    next.live = s->chosen && old ? old->previous : sections::ModelRecord{};
    if (next.live.file.empty() && in_force.file.empty()) {
      out.error = "no model is live and none is kept to roll back to";
      return out;
    }
  }
  next.live.since_utc = sections::utc_now();
  sections::set_model_choice(next);
  const std::string refused =
      reload(action == ModelAction::kLoad ? "nccomp model load" : "nccomp model rollback");
  if (!refused.empty()) {
    sections::set_model_choice(old);
    out.error = refused;
    return out;
  }
  const std::string text = sections::to_text(next);
  try {
    write_state_file(
        model_choice_path_,
        std::span<const std::byte>(reinterpret_cast<const std::byte*>(text.data()), text.size()),
        generation_);
  } catch (const std::exception& e) {
    out.record_error = e.what();
    spdlog::error("model choice not recorded: {}", e.what());
  }
  out.ok = true;
  std::lock_guard<std::mutex> lock(model_mu_);
  out.state = model_state_;
  return out;
}

// Before any thread starts: the loop's CPU(s) apart from the other threads' (cpu_placement.hpp).
void Daemon::place_cpus() { loop_cpus_ = place_threads(dsec().cpu_affinity); }

// State: absent → fresh; valid → resumed; corrupt or unusable → hold (offsets stay as the NC has
// them) and an alarm, never a guess.
void Daemon::restore_state() {
  const std::string state_dir = pick_dir(*config_, cfg::state_section(*config_).directory,
                                         "STATE_DIRECTORY", "/var/lib/nccompd");
  state_path_ = state_dir + "/state.bin";
  std::error_code ec;
  fs::create_directories(state_dir, ec);
  const StateFile sf = read_state_file(state_path_);
  if (sf.status == StateFileStatus::kAbsent) {
    spdlog::info("no state file at {}: starting fresh", state_path_);
  } else if (sf.status == StateFileStatus::kCorrupt) {
    state_problem_ = "state file " + state_path_ + " is corrupt: " + sf.reason;
  } else {
    std::size_t skipped = 0;
    // In lock-step the peer's clock starts near 0: restored limiters start there too.
    const core::TimeNs resume_ns = lockstep_ ? 0 : monotonic_ns();
    if (runtime_->engine->import_state(sf.payload, resume_ns, &skipped)) {
      sequence_ = sf.sequence;
      state_imported_ = true;
      spdlog::info("state resumed from {} (write #{}, {} bytes, {} unknown entries skipped)",
                   state_path_, sf.sequence, sf.payload.size(), skipped);
    } else {
      state_problem_ = "state file " + state_path_ + " has a valid checksum but does not parse";
    }
  }
  if (!state_problem_.empty()) {
    spdlog::error(
        "{}; offsets are HELD (nothing is written to the NC). Restore or remove the file "
        "and restart nccompd.",
        state_problem_);
  }
}

void Daemon::lock_memory() {
  if (dsec().lock_memory && kSanitizerBuild) {
    spdlog::warn(
        "lock_memory ignored: this is a sanitizer build (its shadow memory is terabytes of "
        "reserved address space that mlockall would try to make resident)");
  } else if (dsec().lock_memory) {
    if (mlockall(MCL_CURRENT | MCL_FUTURE) == 0) {
      spdlog::info("memory locked (mlockall)");
    } else {
      spdlog::warn(
          "mlockall failed: {} (loop may page-fault; grant CAP_IPC_LOCK or raise "
          "LimitMEMLOCK)",
          std::strerror(errno));
    }
  }
}

// Before the buses start: a bus that can read its offset registers back (Modbus) does it now on
// this thread; the others say they cannot, and the start-up hooks of the sections (S1: the NC's
// checkpoint registers against the learned table) fall back to rewriting what the NC must hold.
// Then the events the NC published while nccompd was down: the buses resume from the engine's
// event cursors (restored with the state), their first reads are logged while running.
void Daemon::read_back_registers() {
  const RegisterReader read = register_reader();
  const core::TimeNs now = lockstep_ ? 0 : monotonic_ns();
  ReadBackCounts n = anchor_registers(read, now);
  adopt_without_state(read, now, n);
  if (n.anchored == 0) {
    spdlog::info(
        "registers: none can be read back from the NC; the limiters start from the values in "
        "the state file (0 without one){}",
        n.held > 0 ? fmt::format("; {} held without state", n.held) : std::string{});
  } else {
    spdlog::info(
        "registers: {} of {} read back from the NC, {} differ from the state, {} beyond "
        "max_abs_um (held), {} adopted without state, {} held without state; their limiters "
        "start from the NC's values",
        n.anchored, runtime_->engine->register_count(), n.differ, n.beyond, n.adopted, n.held);
  }
  run_startup_hooks(read, now);

  for (auto& b : buses_) {
    event_buses_.emplace_back(b.name, b.bus.get());
  }
  for (const EventsLine& l :
       events_while_down_.resume(runtime_->engine->event_cursors(), event_buses_)) {
    spdlog::info("{}", l.text);
  }
}

// Each register is read once: the anchoring, the adoption and every hook see the same value.
RegisterReader Daemon::register_reader() {
  return [this](std::uint16_t index) -> std::optional<double> {
    if (const auto it = read_back_.find(index); it != read_back_.end()) {
      return it->second;
    }
    std::optional<double> v;
    const int b = index < runtime_->register_bus.size() ? runtime_->register_bus[index] : -1;
    if (b >= 0 && static_cast<std::size_t>(b) < buses_.size()) {
      v = buses_[static_cast<std::size_t>(b)].bus->read_offset(index);
    }
    read_back_.emplace(index, v);
    return v;
  };
}

// Every register the NC returns: its limiter starts from the NC's value, not from the state's
// (docs/daemon.md, "State and crashes"). Differences beyond 0.1 µm (the reference map's counts)
// are logged.
ReadBackCounts Daemon::anchor_registers(const RegisterReader& read, core::TimeNs now) {
  auto& engine = *runtime_->engine;
  ReadBackCounts n;
  for (std::size_t i = 0; i < engine.register_count() && i <= 0xFFFFU; ++i) {
    const auto v = read(static_cast<std::uint16_t>(i));
    const auto a = v ? engine.anchor_register(i, *v, now) : core::engine::AnchorResult{};
    if (!a.anchored) {
      continue;
    }
    ++n.anchored;
    const std::string& name = engine.register_spec(i).name;
    if (a.known && std::fabs(*v - a.before_um) > 0.1) {
      ++n.differ;
      spdlog::warn(
          "register {} ({}): the NC holds {:.3f} um, the state {:.3f} um ({:+.3f} um); the next "
          "writes start from the NC's value",
          i, name, *v, a.before_um, *v - a.before_um);
    }
    if (a.beyond_limit) {
      ++n.beyond;
      spdlog::error(
          "register {} ({}): the NC holds {:.3f} um, beyond max_abs_um {:.3f}: nothing is "
          "written "
          "to it (alarm register_beyond_limit, code 60) until the NC's register is corrected and "
          "nccompd restarted, or `nccomp register release {}` writes the daemon's value in one "
          "move",
          i, name, *v, engine.register_spec(i).limits.max_abs_um, name);
    }
  }
  return n;
}

// Modules without usable state take what the NC holds as their starting point, or the register
// is held (docs/daemon.md, "Start-up: registers beyond the limits and modules without state"). Not
// in hold mode (a corrupt state file): nothing is written then anyway, and the file may still be
// restored.
void Daemon::adopt_without_state(const RegisterReader& read, core::TimeNs now, ReadBackCounts& n) {
  namespace eng = core::engine;
  auto& engine = *runtime_->engine;
  for (std::size_t i = 0; state_problem_.empty() && i < engine.register_count() && i <= 0xFFFFU;
       ++i) {
    const int b = i < runtime_->register_bus.size() ? runtime_->register_bus[i] : -1;
    const bool known_bus = b >= 0 && static_cast<std::size_t>(b) < buses_.size();
    const bool readable = known_bus && buses_[static_cast<std::size_t>(b)].bus->reads_back();
    const auto v = read(static_cast<std::uint16_t>(i));
    const auto what = engine.adopt_without_state(i, v, readable, now);
    if (what == eng::StartupAdoption::kNotNeeded || what == eng::StartupAdoption::kFlag) {
      continue;
    }
    const auto k = static_cast<std::size_t>(engine.register_writer(i));
    const auto source = engine.module_state(k);
    const std::string_view why =
        source == eng::ModuleStateSource::kRestored
            ? "the register is held without state since an earlier start"
        : source == eng::ModuleStateSource::kUnreadable
            ? "its entry in the state file could not be read"
        : state_imported_ ? "it is not in the state file: added to the configuration since"
                          : "no state file";
    const std::string& name = engine.register_spec(i).name;
    const std::string_view module = engine.module(k).name();
    if (what == eng::StartupAdoption::kAdopted) {
      ++n.adopted;
      if (std::fabs(*v) > 0.1) {
        spdlog::warn(
            "register {} ({}): module {} has no usable state ({}); the NC's {:.3f} um is its "
            "starting point: nothing is written to the register until a new measurement "
            "(register_adopted, code 61)",
            i, name, module, why, *v);
      }
    } else if (what == eng::StartupAdoption::kHeld) {
      ++n.held;
      spdlog::warn(
          "register {} ({}): module {} has no usable state ({}) and {}: nothing is written to "
          "it (alarm register_held_without_state, code 62) until `nccomp register release {}`",
          i, name, module, why,
          v ? fmt::format("cannot adopt the NC's {:.3f} um", *v)
            : std::string("the NC did not answer the read-back"),
          name);
    } else {
      spdlog::warn(
          "register {} ({}): module {} has no usable state ({}) and bus {} cannot read it back: "
          "the module's values are written as it computes them from nothing; if the NC holds "
          "an offset there that must be kept, stop nccompd and see docs/daemon.md",
          i, name, module, why,
          known_bus ? buses_[static_cast<std::size_t>(b)].name : std::string("?"));
    }
  }
}

void Daemon::run_startup_hooks(const RegisterReader& read, core::TimeNs now) {
  for (const auto& [hook_name, hook] : startup_hooks()) {
    try {
      for (const auto& line : hook(*runtime_->engine, read, now)) {
        spdlog::info("{}", line);
      }
    } catch (const std::exception& e) {
      spdlog::error("start-up of {}: {}", hook_name, e.what());
    }
  }
}

bool Daemon::start_buses() {
  for (auto& b : buses_) {
    try {
      b.bus->set_lockstep(lockstep_);
      b.bus->start();
      spdlog::info("bus {} started", b.name);
    } catch (const std::exception& e) {
      spdlog::error("bus {} failed to start: {}", b.name, e.what());
      for (auto& o : buses_) {
        o.bus->stop();
      }
      return false;
    }
  }
  return true;
}

void Daemon::start_persister_and_log() {
  blob_bytes_ = std::max<std::size_t>(64 * 1024, 4 * runtime_->engine->state_capacity());
  persister_ = std::make_unique<StatePersister>(state_path_, blob_bytes_);
  persister_->start(sequence_);
  const auto& msec = cfg::measurement_log_section(*config_);
  if (!msec.enabled) {
    return;
  }
  MeasurementLogOptions mo;
  mo.directory = pick_dir(*config_, msec.directory, "LOGS_DIRECTORY", "/var/log/nccompd");
  mo.max_file_bytes = msec.max_file_bytes;
  mo.keep_files = msec.keep_files;
  const std::string machine =
      msec.machine_id.empty() ? formats::measurement_log::host_machine_id() : msec.machine_id;
  mo.machine_id = machine;
  mo.context_columns = msec.context_columns;
  mo.monotonic_record_clock = !lockstep_;  // the peer's TICKs are not CLOCK_MONOTONIC
  mo.fsync_interval_s = msec.fsync_interval_s;
  if (!msec.face_probe_points_mm.empty()) {
    FaceProbeConfig& fp = mo.face_probe;
    fp.count = msec.face_probe_points_mm.size();
    std::copy(msec.face_probe_points_mm.begin(), msec.face_probe_points_mm.end(),
              fp.point_mm.begin());
    fp.capture_radius_mm = msec.face_probe_capture_radius_mm;
    fp.ball_radius_mm = msec.face_probe_ball_radius_mm;
    // The names were checked against [[registers]] (cross_check): the engine's indices.
    const auto& regs = cfg::registers_section(*config_).registers;
    for (std::size_t i = 0; i < regs.size(); ++i) {
      if (regs[i].spec.name == msec.face_probe_length_register) fp.length_register = i;
      if (regs[i].spec.name == msec.face_probe_radius_register) fp.radius_register = i;
    }
  }
  mlog_ = std::make_unique<MeasurementLogWriter>(std::move(mo));
  mlog_->set_observer([this](const core::MeasurementRecord& r) { shadow_.observe(r); });
  try {
    mlog_->start();
    spdlog::info("measurement log: {} (machine {}, {} context column(s))", mlog_->current_path(),
                 machine, msec.context_columns.size());
  } catch (const std::exception& e) {
    spdlog::warn("measurement log disabled: {}", e.what());
    mlog_.reset();
  }
}

// The loop thread (with the operator commands' ring and, in lock-step, the peer), the event
// logger and the status server; then the loop starts.
bool Daemon::start_loop_and_status() {
  swap_ = std::make_unique<core::rt::ConfigSwap<Runtime>>(std::move(runtime_));
  const LoopOptions lo = loop_options();
  for (auto& b : buses_) {
    bus_ptrs_.push_back(b.bus.get());
  }
  // Operator commands (`nccomp calibrate --daemon`): the command thread queues them as events,
  // the loop drains them like a bus's (last in the list: register indices map to the buses above).
  bus_ptrs_.push_back(&commands_);
  if (lockstep_ && !connect_lockstep()) {
    return false;
  }
  loop_ = std::make_unique<Loop>(lo, *swap_, bus_ptrs_, persister_.get(), mlog_.get());
  loop_->set_hold(!state_problem_.empty());
  logger_ = std::make_unique<EventLogger>(*loop_);
  logger_->start();
  if (!state_problem_.empty()) {
    logger_->raise(core::AlarmEvent{monotonic_ns(), core::Severity::kAlarm,
                                    core::AlarmCode::kStateCorrupt, -1, 0.0});
  }
  if (!start_status()) {
    return false;
  }
  log_loop_start(loop_->start());
  notify("READY=1\nSTATUS=running: loop " + std::to_string(static_cast<int>(dsec().rate_hz)) +
         " Hz" + (state_problem_.empty() ? "" : ", OFFSETS HELD (state corrupt)"));
  return true;
}

LoopOptions Daemon::loop_options() {
  LoopOptions lo;
  lo.rate_hz = dsec().rate_hz;
  lo.overrun_policy = dsec().overrun_policy;
  lo.max_events_per_cycle = dsec().max_events_per_cycle;
  lo.sched_fifo_priority = dsec().sched_fifo_priority;
  lo.cpu_affinity = loop_cpus_;
  lo.prefault_stack_kib = dsec().prefault_stack_kib;
  lo.state_min_interval_s = cfg::state_section(*config_).min_interval_s;
  lo.state_buffer_bytes = blob_bytes_;
  // Benchmarks preload a counting malloc (bench/daemon/alloc_preload): if it is there, the loop
  // counts its thread's allocations and frees after warm-up (status: allocations_after_warmup).
  using CountFn = std::uint64_t (*)() noexcept;
  if (void* a = dlsym(RTLD_DEFAULT, "nccomp_preload_thread_allocations"); a != nullptr) {
    lo.thread_allocations = reinterpret_cast<CountFn>(a);
    if (void* f = dlsym(RTLD_DEFAULT, "nccomp_preload_thread_frees"); f != nullptr) {
      lo.thread_deallocations = reinterpret_cast<CountFn>(f);
    }
    spdlog::info("allocation counter preloaded: allocations on the loop thread are counted");
  }
  if (const char* stall = std::getenv("NCCOMPD_TEST_STALL_AFTER_CYCLES");
      stall != nullptr && *stall != '\0') {
    // Test hook of the watchdog test (tests/hil/daemon): never set it on a machine.
    char* end = nullptr;
    const unsigned long long n = std::strtoull(stall, &end, 10);
    if (end != nullptr && *end == '\0' && n > 0) {
      lo.test_stall_after_cycles = n;
      spdlog::warn("TEST HOOK NCCOMPD_TEST_STALL_AFTER_CYCLES: the loop stalls after {} cycles", n);
    }
  }
  if (lockstep_) {
    lo.lockstep = &peer_;
  }
  return lo;
}

bool Daemon::connect_lockstep() {
  try {
    spdlog::info("lock-step: connecting to {}", options_.lockstep_socket);
    peer_.connect(options_.lockstep_socket, options_.lockstep_connect_timeout_s);
    spdlog::info(
        "lock-step: connected; the peer's TICKs drive the loop (rate_hz {} is the "
        "peer's lockstep_rate_hz)",
        dsec().rate_hz);
  } catch (const std::exception& e) {
    spdlog::error("{}", e.what());
    persister_->stop();
    if (mlog_) {
      mlog_->stop();
    }
    for (auto& b : buses_) {
      b.bus->stop();
    }
    return false;
  }
  return true;
}

bool Daemon::start_status() {
  sc_.loop = loop_.get();
  for (auto& b : buses_) {
    sc_.buses.emplace_back(b.name, b.bus.get());
  }
  sc_.logger = logger_.get();
  sc_.persister = persister_.get();
  sc_.measurement_log = mlog_.get();
  sc_.register_names = [this] {
    std::lock_guard<std::mutex> lock(names_mu_);
    return *names_;
  };
  sc_.register_specs = [this] {
    std::lock_guard<std::mutex> lock(names_mu_);
    return *specs_;
  };
  sc_.state_problem = [problem = state_problem_] { return problem; };
  sc_.shadow = [this] { return shadow_.status(); };
  sc_.model = [this] { return model_view(); };
  sc_.config_path = options_.config_path;
  sc_.state_path = state_path_;
  status_ = std::make_unique<StatusServer>(sc_);
  CommandContext cc{&commands_, loop_.get(), sc_.register_names, {}, {}, {}};
  cc.model_state = [this] {
    ModelState m = model_view();
    m.shadow = shadow_.status();
    return m;
  };
  cc.change_model = [this](ModelAction action, const std::string& file, const std::string& who) {
    ModelChange change;
    if (!main_calls_.run([&] { change = change_model(action, file, who); },
                         std::chrono::milliseconds(1000))) {
      change.error = "the daemon's main thread did not take the request within 1 s";
    }
    return change;
  };
  set_command_context(cc);
  const auto& stsec = cfg::status_section(*config_);
  const std::string sock = status_socket_path(*config_);
  std::error_code ec;
  fs::create_directories(fs::path(sock).parent_path(), ec);
  try {
    StatusServerOptions so;
    so.socket_path = sock;
    so.prometheus_address = stsec.prometheus_address;
    so.prometheus_port = stsec.prometheus_port;
    so.policy = CommandPolicy{stsec.admin_group, ::geteuid()};
    so.client_timeout_s = stsec.client_timeout_s;
    so.max_clients = stsec.max_clients;
    status_->start(so);
    spdlog::info("status socket {}{}; commands that change the machine: root and group {}", sock,
                 status_->prometheus_port() > 0
                     ? fmt::format(", Prometheus on {}:{}", stsec.prometheus_address,
                                   status_->prometheus_port())
                     : std::string{},
                 stsec.admin_group);
    if (!group_exists(stsec.admin_group)) {
      spdlog::warn(
          "status: group '{}' ([status] admin_group) does not exist: only root and the "
          "daemon's user can run commands that change the machine",
          stsec.admin_group);
    }
  } catch (const std::exception& e) {
    spdlog::error("status: {}", e.what());
    logger_->stop();
    persister_->stop();
    for (auto& b : buses_) {
      b.bus->stop();
    }
    return false;
  }
  return true;
}

void Daemon::log_loop_start(const LoopSetupReport& rep) {
  if (lockstep_) {
    spdlog::info("loop running in lock-step: one cycle per TICK of the peer");
  } else {
    spdlog::info("loop running at {} Hz, overrun policy {}", dsec().rate_hz,
                 dsec().overrun_policy == cfg::OverrunPolicy::kRestart ? "restart" : "skip_missed");
  }
  if (rep.sched_requested) {
    if (rep.sched_errno == 0) {
      spdlog::info("loop thread: SCHED_FIFO priority {}", dsec().sched_fifo_priority);
    } else {
      spdlog::warn("loop thread: SCHED_FIFO priority {} refused: {} (running SCHED_OTHER)",
                   dsec().sched_fifo_priority, std::strerror(rep.sched_errno));
    }
  }
  if (rep.affinity_requested) {
    if (rep.affinity_errno == 0) {
      spdlog::info("loop thread: pinned to CPU(s) {}", fmt::join(loop_cpus_, ","));
    } else {
      spdlog::warn("loop thread: CPU affinity refused: {}", std::strerror(rep.affinity_errno));
    }
  }
  if (rep.prefaulted_kib > 0) {
    spdlog::info("loop thread: {} KiB of stack pre-faulted", rep.prefaulted_kib);
  }
}

// Until a signal stops it (or, in lock-step, the peer ends the run): every pass (at most 100 ms
// apart) takes a signal, reclaims a replaced configuration, watches the buses' alarms and first
// reads, feeds the systemd watchdog and updates the status line. Never from the loop thread.
void Daemon::run_until_stopped() {
  RunState rs;
  rs.watchdog = sd_watchdog_enabled(0, &rs.watchdog_usec) > 0 && rs.watchdog_usec > 0;
  if (rs.watchdog) {
    spdlog::info("systemd watchdog: {} ms; fed while the loop heartbeat advances",
                 rs.watchdog_usec / 1000);
  }
  rs.heartbeat = HeartbeatWatch(loop_->heartbeat());
  rs.last_feed = std::chrono::steady_clock::now();
  rs.last_status = rs.last_feed;
  for (const auto& b : buses_) {
    rs.bus_names.push_back(b.name);
  }
  rs.bus_statuses.resize(buses_.size());
  for (;;) {
    if (lockstep_ && lockstep_ended(rs)) {
      break;
    }
    if (handle_signal()) {
      break;
    }
    main_calls_.serve();
    serve_shadow();
    (void)model_view();  // stamps a model live when the loop has swapped it in
    swap_->reclaim();
    watch_buses(rs);
    const auto now = std::chrono::steady_clock::now();
    feed_watchdog(rs, now);
    update_status_line(rs, now);
  }
}

bool Daemon::lockstep_ended(RunState& rs) {
  const LoopStats ls = loop_->stats();
  if (ls.sync_timeouts != rs.sync_timeouts_logged ||
      ls.flush_timeouts != rs.flush_timeouts_logged) {
    const auto bi = static_cast<std::size_t>(std::max(ls.last_timeout_bus, 0));
    spdlog::warn(
        "lock-step: bus {} did not answer in time at cycle {} ({} sync, {} flush timeouts "
        "so far); the cycles completed anyway",
        bi < buses_.size() ? buses_[bi].name : std::string("?"), ls.last_timeout_cycle,
        ls.sync_timeouts, ls.flush_timeouts);
    rs.sync_timeouts_logged = ls.sync_timeouts;
    rs.flush_timeouts_logged = ls.flush_timeouts;
  }
  if (loop_->finished()) {
    spdlog::info("lock-step: run ended after {} cycles: {}", ls.cycles,
                 to_string(loop_->lockstep_end()));
    return true;
  }
  return false;
}

// Waits up to 100 ms for a signal; true for SIGTERM / SIGINT (stop). SIGHUP reloads.
bool Daemon::handle_signal() {
  pollfd pfd{sfd_, POLLIN, 0};
  const int pr = poll(&pfd, 1, 100);
  if (pr <= 0 || (pfd.revents & POLLIN) == 0) {
    return false;
  }
  signalfd_siginfo si{};
  if (read(sfd_, &si, sizeof si) != static_cast<ssize_t>(sizeof si)) {
    return false;
  }
  if (si.ssi_signo == SIGTERM || si.ssi_signo == SIGINT) {
    spdlog::info("signal {}: stopping", si.ssi_signo == SIGTERM ? "SIGTERM" : "SIGINT");
    return true;
  }
  if (si.ssi_signo == SIGHUP) {
    (void)reload("SIGHUP");
  }
  return false;
}

// A new configured engine built here and swapped in at a cycle boundary; a bad configuration is
// refused and the running one keeps running.
std::string Daemon::reload(const std::string& why) {
  notify("RELOADING=1\nSTATUS=reloading " + options_.config_path);
  spdlog::info("{}: reloading {}", why, options_.config_path);
  auto next = cfg::load_file(options_.config_path);
  std::string refused;
  std::string errors;
  if (!next.config) {
    for (const auto& d : next.diagnostics.items()) {
      spdlog::error("reload: {}", formats::format(d));
      errors += formats::format(d) + "\n";
    }
    refused = std::to_string(next.diagnostics.items().size()) + " error(s)";
  } else {
    try {
      auto rt = make_runtime(*next.config, buses_, options_.dry_run, generation_ + 1);
      if (rt->engine->state_capacity() > blob_bytes_) {
        throw std::invalid_argument("the new engine's state needs " +
                                    std::to_string(rt->engine->state_capacity()) +
                                    " bytes, more than this process reserved; restart");
      }
      ++generation_;
      {
        std::lock_guard<std::mutex> lock(names_mu_);
        names_ = std::make_shared<const std::vector<std::string>>(register_names(*next.config));
        specs_ = std::make_shared<const std::vector<core::engine::RegisterSpec>>(
            register_specs(*next.config));
      }
      swap_->publish(std::move(rt));
      note_model(*next.config);
      spdlog::info(
          "reload: configuration {} accepted (loop settings, buses, state, log "
          "and status settings take effect at the next restart)",
          generation_);
    } catch (const std::exception& e) {
      refused = e.what();
      errors = refused + "\n";
    }
  }
  if (!refused.empty()) {
    spdlog::error("reload refused ({}); configuration {} keeps running", refused, generation_);
  }
  notify("READY=1\nSTATUS=running: configuration " + std::to_string(generation_) +
         (refused.empty() ? "" : " (last reload refused)"));
  return errors;
}

// The buses' alarm flags (drivers::BusStatus::alarm) become the daemon's alarm bus_alarm (code
// 54) on each rise and fall: logged and in the status's alarm list. Then the first reads of
// events published while nccompd was down.
void Daemon::watch_buses(RunState& rs) {
  for (std::size_t i = 0; i < buses_.size(); ++i) {
    rs.bus_statuses[i] = buses_[i].bus->status();
  }
  for (const BusAlarmChange& c :
       rs.bus_alarms.update(rs.bus_names, rs.bus_statuses, monotonic_ns())) {
    if (c.event.severity == core::Severity::kAlarm) {
      spdlog::error("{}", c.message);
    } else {
      spdlog::info("{}", c.message);
    }
    logger_->raise(c.event);
  }
  for (const EventsLine& l : events_while_down_.poll(event_buses_)) {
    if (l.warning) {
      spdlog::warn("{}", l.text);
    } else {
      spdlog::info("{}", l.text);
    }
  }
}

// Fed at half its interval while the loop's heartbeat advances: a stalled loop is restarted by
// systemd when WatchdogSec runs out.
void Daemon::feed_watchdog(RunState& rs, std::chrono::steady_clock::time_point now) {
  if (!rs.watchdog || now - rs.last_feed < std::chrono::microseconds(rs.watchdog_usec / 2)) {
    return;
  }
  const std::uint64_t beat = loop_->heartbeat();
  if (rs.heartbeat.advanced(beat)) {
    notify("WATCHDOG=1");
    rs.stalled_logged = false;
  } else if (!rs.stalled_logged) {
    spdlog::error("loop heartbeat stalled at {}: not feeding the systemd watchdog", beat);
    rs.stalled_logged = true;
  }
  rs.last_feed = now;
}

// systemd's status line, every 10 s.
void Daemon::update_status_line(RunState& rs, std::chrono::steady_clock::time_point now) {
  if (now - rs.last_status < std::chrono::seconds(10)) {
    return;
  }
  const LoopStats s = loop_->stats();
  char buf[200];
  std::snprintf(buf, sizeof buf,
                "STATUS=running: %llu cycles, %llu overruns, latency p99 %.0f us%s%s",
                static_cast<unsigned long long>(s.cycles),
                static_cast<unsigned long long>(s.overruns), loop_->latency().quantile_us(0.99),
                s.dry_run ? ", dry run" : "", s.hold ? ", OFFSETS HELD" : "");
  notify(buf);
  rs.last_status = now;
}

int Daemon::shut_down() {
  notify("STOPPING=1\nSTATUS=stopping");
  loop_->stop();
  // The persister first: it writes what the loop queued before it stopped, which is older than
  // the final state below (written after it, the queued one would overwrite the final one).
  persister_->stop();
  // The loop is stopped: its engine can be read from this thread. Persist the final state (not in
  // hold mode: the corrupt file stays for inspection; in dry run only the state as the NC has it,
  // never the dry run's values). The NC keeps its offsets as they are.
  if (state_problem_.empty()) {
    std::vector<std::byte> buf(std::max(swap_->current().engine->state_capacity(), blob_bytes_));
    const std::size_t n = loop_->final_state(buf);
    if (n > 0) {
      persister_->write_now(std::span<const std::byte>(buf.data(), n));
    }
  }
  const auto ps = persister_->stats();
  status_->stop();
  set_command_context(CommandContext{});
  logger_->stop();
  if (mlog_) {
    mlog_->stop();
  }
  for (auto& b : buses_) {
    b.bus->stop();
  }
  const LoopStats s = loop_->stats();
  spdlog::info("stopped after {} cycles ({} overruns); state written {} times, last #{}{}",
               s.cycles, s.overruns, ps.writes, ps.sequence,
               ps.failures > 0 ? fmt::format(", {} failures: {}", ps.failures, ps.last_error)
                               : std::string{});
  close(sfd_);
  sfd_ = -1;
  if (lockstep_) {
    const LockstepEnd end = loop_->lockstep_end();
    if (end == LockstepEnd::kBadMessage || end == LockstepEnd::kBadSequence ||
        end == LockstepEnd::kSocketError) {
      spdlog::error("lock-step ended abnormally: {} (detail {})", to_string(end),
                    end == LockstepEnd::kBadMessage
                        ? std::string(to_string(static_cast<LockstepDecode>(peer_.end_detail())))
                        : std::to_string(peer_.end_detail()));
      return 1;
    }
  }
  return 0;
}

}  // namespace

int register_startup_hook(std::string name, StartupHook hook) {
  hook_storage().emplace_back(std::move(name), std::move(hook));
  return 0;
}

const std::vector<std::pair<std::string, StartupHook>>& startup_hooks() { return hook_storage(); }

int run_daemon(const DaemonOptions& options) {
  Daemon daemon(options);
  return daemon.run();
}

int check_config(const DaemonOptions& options) {
  const std::string& file = options.config_path;
  auto result = cfg::load_file(file);
  if (result.config) {
    // Engine-level refusals (e.g. two modules writing one register) are reported like every
    // other error: file:line:column: key.path: message.
    auto engine = cfg::build_engine(*result.config, result.diagnostics);
    if (engine) {
      std::cout << file << ": OK\n  files:";
      for (const auto& f : result.config->files()) {
        std::cout << " " << f;
      }
      std::cout << "\n  sections:";
      for (const auto& s : result.config->section_names()) {
        std::cout << " " << s;
      }
      const auto& d = cfg::daemon_section(*result.config);
      std::cout << "\n  loop: " << d.rate_hz << " Hz" << (d.dry_run ? " (dry run)" : "")
                << "\n  registers: " << engine->register_count()
                << "\n  modules: " << engine->module_count();
      for (std::size_t i = 0; i < engine->module_count(); ++i) {
        std::cout << (i == 0 ? " (" : ", ") << engine->module(i).name();
      }
      std::cout << (engine->module_count() > 0 ? ")" : "") << "\n";
      return 0;
    }
  }
  std::cerr << result.diagnostics.to_string() << "nccompd: " << result.diagnostics.items().size()
            << " error(s) in " << file << "\n";
  return 3;
}

int print_status_socket(const DaemonOptions& options) {
  const auto config = load_config(options.config_path);
  if (!config) {
    return 3;
  }
  std::cout << status_socket_path(*config) << "\n";
  return 0;
}

}  // namespace nccomp::daemon
