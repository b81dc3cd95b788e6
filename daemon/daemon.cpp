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
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <map>
#include <memory>
#include <mutex>
#include <optional>

#include "daemon/command.hpp"
#include "daemon/config/builtin_sections.hpp"
#include "daemon/config/config.hpp"
#include "daemon/cpu_placement.hpp"
#include "daemon/events_while_down.hpp"
#include "daemon/lockstep.hpp"
#include "daemon/logging.hpp"
#include "daemon/loop.hpp"
#include "daemon/measurement_log.hpp"
#include "daemon/state_store.hpp"
#include "daemon/status.hpp"

namespace nccomp::daemon {

namespace {

namespace fs = std::filesystem;
namespace cfg = config;

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

std::vector<std::string> register_names(const cfg::Config& c) {
  std::vector<std::string> names;
  for (const auto& r : cfg::registers_section(c).registers) {
    names.push_back(r.spec.name);
  }
  return names;
}

void notify(const std::string& s) { (void)sd_notify(0, s.c_str()); }

}  // namespace

namespace {
std::vector<std::pair<std::string, StartupHook>>& hook_storage() {
  static std::vector<std::pair<std::string, StartupHook>> hooks;
  return hooks;
}
}  // namespace

int register_startup_hook(std::string name, StartupHook hook) {
  hook_storage().emplace_back(std::move(name), std::move(hook));
  return 0;
}

const std::vector<std::pair<std::string, StartupHook>>& startup_hooks() { return hook_storage(); }

int run_daemon(const DaemonOptions& options) {
  // Signals are blocked before any thread exists, so every thread inherits the mask and the main
  // thread alone receives them through the signalfd.
  sigset_t mask;
  sigemptyset(&mask);
  sigaddset(&mask, SIGTERM);
  sigaddset(&mask, SIGINT);
  sigaddset(&mask, SIGHUP);
  pthread_sigmask(SIG_BLOCK, &mask, nullptr);
  const int sfd = signalfd(-1, &mask, SFD_CLOEXEC);
  if (sfd < 0) {
    std::cerr << "nccompd: signalfd: " << std::strerror(errno) << "\n";
    return 1;
  }

  auto loaded = cfg::load_file(options.config_path);
  if (!loaded.config) {
    std::cerr << loaded.diagnostics.to_string() << "nccompd: " << loaded.diagnostics.items().size()
              << " error(s) in " << options.config_path << "\n";
    return 3;
  }
  std::shared_ptr<const cfg::Config> config = std::move(loaded.config);
  const std::string log_target = setup_logging(cfg::log_section(*config));
  spdlog::info("nccompd starting: config {}, logging to {}", options.config_path, log_target);

  std::vector<BusEntry> buses;
  std::unique_ptr<Runtime> runtime;
  try {
    buses = make_buses(*config);
    runtime = make_runtime(*config, buses, options.dry_run, 1);
  } catch (const std::exception& e) {
    spdlog::error("configuration refused: {}", e.what());
    return 3;
  }
  if (runtime->dry_run) {
    spdlog::warn(
        "DRY RUN: offsets are computed and logged, nothing is written to the NC, and the state "
        "file keeps what the NC has");
  }
  std::mutex names_mu;
  auto names = std::make_shared<const std::vector<std::string>>(register_names(*config));

  const auto& dsec = cfg::daemon_section(*config);
  const auto& ssec = cfg::state_section(*config);
  // Before any thread starts: the loop's CPU(s) apart from the other threads' (cpu_placement.hpp).
  const std::vector<int> loop_cpus = place_threads(dsec.cpu_affinity);

  // State: absent → fresh; valid → resumed; corrupt or unusable → hold (offsets stay as the NC
  // has them) and an alarm, never a guess.
  const std::string state_dir =
      pick_dir(*config, ssec.directory, "STATE_DIRECTORY", "/var/lib/nccompd");
  const std::string state_path = state_dir + "/state.bin";
  std::error_code ec;
  fs::create_directories(state_dir, ec);
  std::string state_problem;
  std::uint64_t sequence = 0;
  bool state_imported = false;
  {
    const StateFile sf = read_state_file(state_path);
    if (sf.status == StateFileStatus::kAbsent) {
      spdlog::info("no state file at {}: starting fresh", state_path);
    } else if (sf.status == StateFileStatus::kCorrupt) {
      state_problem = "state file " + state_path + " is corrupt: " + sf.reason;
    } else {
      std::size_t skipped = 0;
      // In lock-step the peer's clock starts near 0: restored limiters start there too.
      const core::TimeNs resume_ns = options.lockstep_socket.empty() ? monotonic_ns() : 0;
      if (runtime->engine->import_state(sf.payload, resume_ns, &skipped)) {
        sequence = sf.sequence;
        state_imported = true;
        spdlog::info("state resumed from {} (write #{}, {} bytes, {} unknown entries skipped)",
                     state_path, sf.sequence, sf.payload.size(), skipped);
      } else {
        state_problem = "state file " + state_path + " has a valid checksum but does not parse";
      }
    }
  }
  if (!state_problem.empty()) {
    spdlog::error(
        "{}; offsets are HELD (nothing is written to the NC). Restore or remove the file "
        "and restart nccompd.",
        state_problem);
  }

  if (dsec.lock_memory && kSanitizerBuild) {
    spdlog::warn(
        "lock_memory ignored: this is a sanitizer build (its shadow memory is terabytes of "
        "reserved address space that mlockall would try to make resident)");
  } else if (dsec.lock_memory) {
    if (mlockall(MCL_CURRENT | MCL_FUTURE) == 0) {
      spdlog::info("memory locked (mlockall)");
    } else {
      spdlog::warn(
          "mlockall failed: {} (loop may page-fault; grant CAP_IPC_LOCK or raise "
          "LimitMEMLOCK)",
          std::strerror(errno));
    }
  }

  // Start-up hooks of the sections (S1: the NC's checkpoint registers against the learned
  // table), before the buses start: a bus that can read its offset registers back (Modbus)
  // does it now on this thread; the others say they cannot, and the hooks fall back to
  // rewriting what the NC must hold.
  {
    // Each register is read once: the anchoring below and every hook see the same value.
    std::map<std::uint16_t, std::optional<double>> read_back;
    const RegisterReader read = [&](std::uint16_t index) -> std::optional<double> {
      if (const auto it = read_back.find(index); it != read_back.end()) {
        return it->second;
      }
      std::optional<double> v;
      const int b = index < runtime->register_bus.size() ? runtime->register_bus[index] : -1;
      if (b >= 0 && static_cast<std::size_t>(b) < buses.size()) {
        v = buses[static_cast<std::size_t>(b)].bus->read_offset(index);
      }
      read_back.emplace(index, v);
      return v;
    };
    const core::TimeNs hook_now = options.lockstep_socket.empty() ? monotonic_ns() : 0;
    // Every register the NC returns: its limiter starts from the NC's value, not from the state's
    // (docs/daemon.md, "State and crashes"). Differences beyond 0.1 µm (the reference map's
    // counts) are logged.
    auto& engine = *runtime->engine;
    std::size_t anchored = 0;
    std::size_t differ = 0;
    std::size_t beyond = 0;
    for (std::size_t i = 0; i < engine.register_count() && i <= 0xFFFFU; ++i) {
      const auto v = read(static_cast<std::uint16_t>(i));
      const auto a = v ? engine.anchor_register(i, *v, hook_now) : core::engine::AnchorResult{};
      if (!a.anchored) {
        continue;
      }
      ++anchored;
      if (a.known && std::fabs(*v - a.before_um) > 0.1) {
        ++differ;
        spdlog::warn(
            "register {} ({}): the NC holds {:.3f} um, the state {:.3f} um ({:+.3f} um); the next "
            "writes start from the NC's value",
            i, engine.register_spec(i).name, *v, a.before_um, *v - a.before_um);
      }
      if (a.beyond_limit) {
        ++beyond;
        spdlog::error(
            "register {} ({}): the NC holds {:.3f} um, beyond max_abs_um {:.3f}: nothing is "
            "written "
            "to it (alarm register_beyond_limit, code 60) until the NC's register is corrected and "
            "nccompd restarted, or `nccomp register release {}` writes the daemon's value in one "
            "move",
            i, engine.register_spec(i).name, *v, engine.register_spec(i).limits.max_abs_um,
            engine.register_spec(i).name);
      }
    }
    // Modules without usable state take what the NC holds as their starting point, or the
    // register is held (docs/daemon.md, "Start without usable state"). Not in hold mode (a
    // corrupt state file): nothing is written then anyway, and the file may still be restored.
    std::size_t adopted = 0;
    std::size_t held = 0;
    for (std::size_t i = 0; state_problem.empty() && i < engine.register_count() && i <= 0xFFFFU;
         ++i) {
      const int b = i < runtime->register_bus.size() ? runtime->register_bus[i] : -1;
      const bool readable = b >= 0 && static_cast<std::size_t>(b) < buses.size() &&
                            buses[static_cast<std::size_t>(b)].bus->reads_back();
      const auto v = read(static_cast<std::uint16_t>(i));
      const auto what = engine.adopt_without_state(i, v, readable, hook_now);
      if (what == core::engine::StartupAdoption::kNotNeeded ||
          what == core::engine::StartupAdoption::kFlag) {
        continue;
      }
      const auto k = static_cast<std::size_t>(engine.register_writer(i));
      const auto source = engine.module_state(k);
      const std::string_view why =
          source == core::engine::ModuleStateSource::kRestored
              ? "the register is held without state since an earlier start"
          : source == core::engine::ModuleStateSource::kUnreadable
              ? "its entry in the state file could not be read"
          : state_imported ? "it is not in the state file: added to the configuration since"
                           : "no state file";
      const std::string& name = engine.register_spec(i).name;
      const std::string_view module = engine.module(k).name();
      if (what == core::engine::StartupAdoption::kAdopted) {
        ++adopted;
        if (std::fabs(*v) > 0.1) {
          spdlog::warn(
              "register {} ({}): module {} has no usable state ({}); the NC's {:.3f} um is its "
              "starting point: nothing is written to the register until a new measurement "
              "(register_adopted, code 61)",
              i, name, module, why, *v);
        }
      } else if (what == core::engine::StartupAdoption::kHeld) {
        ++held;
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
            b >= 0 && static_cast<std::size_t>(b) < buses.size()
                ? buses[static_cast<std::size_t>(b)].name
                : std::string("?"));
      }
    }
    if (anchored == 0) {
      spdlog::info(
          "registers: none can be read back from the NC; the limiters start from the values in "
          "the state file (0 without one){}",
          held > 0 ? fmt::format("; {} held without state", held) : std::string{});
    } else {
      spdlog::info(
          "registers: {} of {} read back from the NC, {} differ from the state, {} beyond "
          "max_abs_um (held), {} adopted without state, {} held without state; their limiters "
          "start from the NC's values",
          anchored, engine.register_count(), differ, beyond, adopted, held);
    }
    for (const auto& [hook_name, hook] : startup_hooks()) {
      try {
        for (const auto& line : hook(*runtime->engine, read, hook_now)) {
          spdlog::info("{}", line);
        }
      } catch (const std::exception& e) {
        spdlog::error("start-up of {}: {}", hook_name, e.what());
      }
    }
  }

  // Events the NC published while nccompd was down: the buses resume from the engine's event
  // cursors (restored with the state), and their first reads are logged in the loop below.
  EventsWhileDownLog::Buses event_buses;
  for (auto& b : buses) {
    event_buses.emplace_back(b.name, b.bus.get());
  }
  EventsWhileDownLog events_while_down;
  for (const EventsLine& l :
       events_while_down.resume(runtime->engine->event_cursors(), event_buses)) {
    spdlog::info("{}", l.text);
  }

  const bool lockstep = !options.lockstep_socket.empty();
  for (auto& b : buses) {
    try {
      b.bus->set_lockstep(lockstep);
      b.bus->start();
      spdlog::info("bus {} started", b.name);
    } catch (const std::exception& e) {
      spdlog::error("bus {} failed to start: {}", b.name, e.what());
      for (auto& o : buses) {
        o.bus->stop();
      }
      return 1;
    }
  }

  const std::size_t blob_bytes =
      std::max<std::size_t>(64 * 1024, 4 * runtime->engine->state_capacity());
  StatePersister persister(state_path, blob_bytes);
  persister.start(sequence);

  std::unique_ptr<MeasurementLogWriter> mlog;
  const auto& msec = cfg::measurement_log_section(*config);
  if (msec.enabled) {
    const std::string dir = pick_dir(*config, msec.directory, "LOGS_DIRECTORY", "/var/log/nccompd");
    MeasurementLogOptions mo;
    mo.directory = dir;
    mo.max_file_bytes = msec.max_file_bytes;
    mo.keep_files = msec.keep_files;
    const std::string machine = msec.machine_id.empty() ? host_machine_id() : msec.machine_id;
    mo.machine_id = machine;
    mo.context_columns = msec.context_columns;
    mo.monotonic_record_clock = !lockstep;  // the peer's TICKs are not CLOCK_MONOTONIC
    mo.fsync_interval_s = msec.fsync_interval_s;
    mlog = std::make_unique<MeasurementLogWriter>(std::move(mo));
    try {
      mlog->start();
      spdlog::info("measurement log: {} (machine {}, {} context column(s))", mlog->current_path(),
                   machine, msec.context_columns.size());
    } catch (const std::exception& e) {
      spdlog::warn("measurement log disabled: {}", e.what());
      mlog.reset();
    }
  }

  core::rt::ConfigSwap<Runtime> swap(std::move(runtime));
  LoopOptions lo;
  lo.rate_hz = dsec.rate_hz;
  lo.overrun_policy = dsec.overrun_policy;
  lo.max_events_per_cycle = dsec.max_events_per_cycle;
  lo.sched_fifo_priority = dsec.sched_fifo_priority;
  lo.cpu_affinity = loop_cpus;
  lo.prefault_stack_kib = dsec.prefault_stack_kib;
  lo.state_min_interval_s = ssec.min_interval_s;
  lo.state_buffer_bytes = blob_bytes;
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
  std::vector<drivers::Bus*> bus_ptrs;
  for (auto& b : buses) {
    bus_ptrs.push_back(b.bus.get());
  }
  // Operator commands (`nccomp calibrate --daemon`): the command thread queues them as events, the
  // loop drains them like a bus's (last in the list: register indices map to the buses above).
  CommandBus commands;
  bus_ptrs.push_back(&commands);
  LockstepPeer peer;
  if (lockstep) {
    try {
      spdlog::info("lock-step: connecting to {}", options.lockstep_socket);
      peer.connect(options.lockstep_socket, options.lockstep_connect_timeout_s);
      spdlog::info(
          "lock-step: connected; the peer's TICKs drive the loop (rate_hz {} is the "
          "peer's lockstep_rate_hz)",
          dsec.rate_hz);
    } catch (const std::exception& e) {
      spdlog::error("{}", e.what());
      persister.stop();
      if (mlog) {
        mlog->stop();
      }
      for (auto& b : buses) {
        b.bus->stop();
      }
      return 1;
    }
    lo.lockstep = &peer;
  }
  Loop loop(lo, swap, bus_ptrs, &persister, mlog.get());
  loop.set_hold(!state_problem.empty());
  EventLogger logger(loop);
  logger.start();
  if (!state_problem.empty()) {
    logger.raise(core::AlarmEvent{monotonic_ns(), core::Severity::kAlarm,
                                  core::AlarmCode::kStateCorrupt, -1, 0.0});
  }

  StatusContext sc;
  sc.loop = &loop;
  for (auto& b : buses) {
    sc.buses.emplace_back(b.name, b.bus.get());
  }
  sc.logger = &logger;
  sc.persister = &persister;
  sc.measurement_log = mlog.get();
  sc.register_names = [&names_mu, &names] {
    std::lock_guard<std::mutex> lock(names_mu);
    return *names;
  };
  sc.state_problem = [state_problem] { return state_problem; };
  sc.config_path = options.config_path;
  sc.state_path = state_path;
  StatusServer status(sc);
  set_command_context(CommandContext{&commands, &loop, sc.register_names});
  const auto& stsec = cfg::status_section(*config);
  const std::string sock =
      stsec.socket_path.empty()
          ? pick_dir(*config, "", "RUNTIME_DIRECTORY", "/run/nccompd") + "/status.sock"
          : config->resolve(stsec.socket_path);
  fs::create_directories(fs::path(sock).parent_path(), ec);
  try {
    StatusServerOptions so;
    so.socket_path = sock;
    so.prometheus_address = stsec.prometheus_address;
    so.prometheus_port = stsec.prometheus_port;
    so.policy = CommandPolicy{stsec.admin_group, ::geteuid()};
    so.client_timeout_s = stsec.client_timeout_s;
    so.max_clients = stsec.max_clients;
    status.start(so);
    spdlog::info("status socket {}{}; commands that change the machine: root and group {}", sock,
                 status.prometheus_port() > 0
                     ? fmt::format(", Prometheus on {}:{}", stsec.prometheus_address,
                                   status.prometheus_port())
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
    logger.stop();
    persister.stop();
    for (auto& b : buses) {
      b.bus->stop();
    }
    return 1;
  }

  const LoopSetupReport rep = loop.start();
  if (lockstep) {
    spdlog::info("loop running in lock-step: one cycle per TICK of the peer");
  } else {
    spdlog::info("loop running at {} Hz, overrun policy {}", dsec.rate_hz,
                 dsec.overrun_policy == cfg::OverrunPolicy::kRestart ? "restart" : "skip_missed");
  }
  if (rep.sched_requested) {
    if (rep.sched_errno == 0) {
      spdlog::info("loop thread: SCHED_FIFO priority {}", dsec.sched_fifo_priority);
    } else {
      spdlog::warn("loop thread: SCHED_FIFO priority {} refused: {} (running SCHED_OTHER)",
                   dsec.sched_fifo_priority, std::strerror(rep.sched_errno));
    }
  }
  if (rep.affinity_requested) {
    if (rep.affinity_errno == 0) {
      spdlog::info("loop thread: pinned to CPU(s) {}", fmt::join(loop_cpus, ","));
    } else {
      spdlog::warn("loop thread: CPU affinity refused: {}", std::strerror(rep.affinity_errno));
    }
  }
  if (rep.prefaulted_kib > 0) {
    spdlog::info("loop thread: {} KiB of stack pre-faulted", rep.prefaulted_kib);
  }

  notify("READY=1\nSTATUS=running: loop " + std::to_string(static_cast<int>(dsec.rate_hz)) + " Hz" +
         (state_problem.empty() ? "" : ", OFFSETS HELD (state corrupt)"));
  std::uint64_t watchdog_usec = 0;
  const bool watchdog = sd_watchdog_enabled(0, &watchdog_usec) > 0 && watchdog_usec > 0;
  if (watchdog) {
    spdlog::info("systemd watchdog: {} ms; fed while the loop heartbeat advances",
                 watchdog_usec / 1000);
  }

  std::uint64_t generation = 1;
  HeartbeatWatch heartbeat(loop.heartbeat());
  auto last_feed = std::chrono::steady_clock::now();
  auto last_status = last_feed;
  bool stalled_logged = false;
  std::uint64_t sync_timeouts_logged = 0;
  std::uint64_t flush_timeouts_logged = 0;
  // The buses' alarm flags (drivers::BusStatus::alarm) become the daemon's alarm bus_alarm
  // (code 54) on each rise and fall: logged and in the status's alarm list. Looked at every pass
  // of this loop (at most 100 ms apart: the poll below), never from the loop thread.
  BusAlarmWatch bus_alarms;
  std::vector<std::string> bus_names;
  for (const auto& b : buses) {
    bus_names.push_back(b.name);
  }
  std::vector<drivers::BusStatus> bus_statuses(buses.size());
  for (;;) {
    if (lockstep) {
      const LoopStats ls = loop.stats();
      if (ls.sync_timeouts != sync_timeouts_logged || ls.flush_timeouts != flush_timeouts_logged) {
        const auto bi = static_cast<std::size_t>(std::max(ls.last_timeout_bus, 0));
        spdlog::warn(
            "lock-step: bus {} did not answer in time at cycle {} ({} sync, {} flush timeouts "
            "so far); the cycles completed anyway",
            bi < buses.size() ? buses[bi].name : std::string("?"), ls.last_timeout_cycle,
            ls.sync_timeouts, ls.flush_timeouts);
        sync_timeouts_logged = ls.sync_timeouts;
        flush_timeouts_logged = ls.flush_timeouts;
      }
      if (loop.finished()) {
        spdlog::info("lock-step: run ended after {} cycles: {}", ls.cycles,
                     to_string(loop.lockstep_end()));
        break;
      }
    }
    pollfd pfd{sfd, POLLIN, 0};
    const int pr = poll(&pfd, 1, 100);
    if (pr > 0 && (pfd.revents & POLLIN) != 0) {
      signalfd_siginfo si{};
      if (read(sfd, &si, sizeof si) == static_cast<ssize_t>(sizeof si)) {
        if (si.ssi_signo == SIGTERM || si.ssi_signo == SIGINT) {
          spdlog::info("signal {}: stopping", si.ssi_signo == SIGTERM ? "SIGTERM" : "SIGINT");
          break;
        }
        if (si.ssi_signo == SIGHUP) {
          notify("RELOADING=1\nSTATUS=reloading " + options.config_path);
          spdlog::info("SIGHUP: reloading {}", options.config_path);
          auto next = cfg::load_file(options.config_path);
          std::string refused;
          if (!next.config) {
            for (const auto& d : next.diagnostics.items()) {
              spdlog::error("reload: {}", formats::format(d));
            }
            refused = std::to_string(next.diagnostics.items().size()) + " error(s)";
          } else {
            try {
              auto rt = make_runtime(*next.config, buses, options.dry_run, generation + 1);
              if (rt->engine->state_capacity() > blob_bytes) {
                throw std::invalid_argument("the new engine's state needs " +
                                            std::to_string(rt->engine->state_capacity()) +
                                            " bytes, more than this process reserved; restart");
              }
              ++generation;
              {
                std::lock_guard<std::mutex> lock(names_mu);
                names =
                    std::make_shared<const std::vector<std::string>>(register_names(*next.config));
              }
              swap.publish(std::move(rt));
              spdlog::info(
                  "reload: configuration {} accepted (loop settings, buses, state, log "
                  "and status settings take effect at the next restart)",
                  generation);
            } catch (const std::exception& e) {
              refused = e.what();
            }
          }
          if (!refused.empty()) {
            spdlog::error("reload refused ({}); configuration {} keeps running", refused,
                          generation);
          }
          notify("READY=1\nSTATUS=running: configuration " + std::to_string(generation) +
                 (refused.empty() ? "" : " (last reload refused)"));
        }
      }
    }
    swap.reclaim();
    for (std::size_t i = 0; i < buses.size(); ++i) {
      bus_statuses[i] = buses[i].bus->status();
    }
    for (const BusAlarmChange& c : bus_alarms.update(bus_names, bus_statuses, monotonic_ns())) {
      if (c.event.severity == core::Severity::kAlarm) {
        spdlog::error("{}", c.message);
      } else {
        spdlog::info("{}", c.message);
      }
      logger.raise(c.event);
    }
    for (const EventsLine& l : events_while_down.poll(event_buses)) {
      if (l.warning) {
        spdlog::warn("{}", l.text);
      } else {
        spdlog::info("{}", l.text);
      }
    }
    const auto now = std::chrono::steady_clock::now();
    if (watchdog && now - last_feed >= std::chrono::microseconds(watchdog_usec / 2)) {
      const std::uint64_t beat = loop.heartbeat();
      if (heartbeat.advanced(beat)) {
        notify("WATCHDOG=1");
        stalled_logged = false;
      } else if (!stalled_logged) {
        // No feed: systemd restarts the daemon when WatchdogSec runs out.
        spdlog::error("loop heartbeat stalled at {}: not feeding the systemd watchdog", beat);
        stalled_logged = true;
      }
      last_feed = now;
    }
    if (now - last_status >= std::chrono::seconds(10)) {
      const LoopStats s = loop.stats();
      char buf[200];
      std::snprintf(buf, sizeof buf,
                    "STATUS=running: %llu cycles, %llu overruns, latency p99 %.0f us%s%s",
                    static_cast<unsigned long long>(s.cycles),
                    static_cast<unsigned long long>(s.overruns), loop.latency().quantile_us(0.99),
                    s.dry_run ? ", dry run" : "", s.hold ? ", OFFSETS HELD" : "");
      notify(buf);
      last_status = now;
    }
  }

  notify("STOPPING=1\nSTATUS=stopping");
  loop.stop();
  // The persister first: it writes what the loop queued before it stopped, which is older than
  // the final state below (written after it, the queued one would overwrite the final one).
  persister.stop();
  // The loop is stopped: its engine can be read from this thread. Persist the final state (not in
  // hold mode: the corrupt file stays for inspection; in dry run only the state as the NC has it,
  // never the dry run's values). The NC keeps its offsets as they are.
  if (state_problem.empty()) {
    std::vector<std::byte> buf(std::max(swap.current().engine->state_capacity(), blob_bytes));
    const std::size_t n = loop.final_state(buf);
    if (n > 0) {
      persister.write_now(std::span<const std::byte>(buf.data(), n));
    }
  }
  const auto ps = persister.stats();
  status.stop();
  set_command_context(CommandContext{});
  logger.stop();
  if (mlog) {
    mlog->stop();
  }
  for (auto& b : buses) {
    b.bus->stop();
  }
  const LoopStats s = loop.stats();
  spdlog::info("stopped after {} cycles ({} overruns); state written {} times, last #{}{}",
               s.cycles, s.overruns, ps.writes, ps.sequence,
               ps.failures > 0 ? fmt::format(", {} failures: {}", ps.failures, ps.last_error)
                               : std::string{});
  close(sfd);
  if (lockstep) {
    const LockstepEnd end = loop.lockstep_end();
    if (end == LockstepEnd::kBadMessage || end == LockstepEnd::kBadSequence ||
        end == LockstepEnd::kSocketError) {
      spdlog::error("lock-step ended abnormally: {} (detail {})", to_string(end),
                    end == LockstepEnd::kBadMessage
                        ? std::string(to_string(static_cast<LockstepDecode>(peer.end_detail())))
                        : std::to_string(peer.end_detail()));
      return 1;
    }
  }
  return 0;
}

}  // namespace nccomp::daemon
