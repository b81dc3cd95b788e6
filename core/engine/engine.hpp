// The engine: the one object the loop thread steps (architecture.md, "Data flow").
//
// It owns the register table (logical register index → name, kind, limiter), the compensation
// modules (S0 creep, S1 checkpoints, ... behind the small Module interface), and turns the
// modules' absolute offset targets into limited offset writes:
//
//   events ──validate──▶ modules ──targets──▶ per-register OffsetLimiter ──▶ writes (changed only)
//
// - Invalid events (non-finite positions, wear, deviations) are counted, raise kEventInvalid and
//   never reach a module.
// - Faulted measurements (InputFault: the NC reported a measurement the driver could not use)
//   reach the modules with every value field 0, so that each method raises its own alarm.
// - A target the limiter rejects (NaN, beyond the absolute limit) raises an alarm and is not
//   forwarded: the register holds its value. A slewed target keeps converging on later cycles
//   without the module writing it again (targets are absolute and remembered per register).
// - Trims: besides one target per register (one writing module), any module may publish an
//   additive trim for a register (StepOutput::trims, e.g. the [model] section's fitted effect on
//   top of S1's learned checkpoint value). The register is sent base target + Σ trims through the
//   same limiter; a sum the limiter refuses raises the same alarm and changes nothing. Trims are
//   not part of the saved state: the base target is saved, and the trimming module publishes its
//   trim again after a restart, so nothing is applied twice.
// - In hold mode (state file corrupt, operator request) modules still run and alarms still flow,
//   but no offset write leaves the engine: the NC keeps the offsets it has.
// - Read-back at start-up: a register whose value the NC returns is anchored to it
//   (anchor_register()): its limiter slews from what the NC holds, not from the value restored
//   from the state, so no write steps further than max_step_um from the NC's real value.
// - Start-up holds (RegisterHold): a register whose NC value lies beyond max_abs_um is never
//   written (not even inward) until the operator releases it (OperatorCommand
//   kRegisterRelease); the release writes the register's target in one move, within the limits.
//   A module without usable state (none restored: no state file, its entry unreadable, or added
//   since) is asked to adopt what the NC holds (Module::adopt_output()); an offset register it
//   cannot adopt, or whose value the NC did not return, is held until released. Held registers
//   raise one alarm each (codes 60..62) and are saved with the state (an entry "@holds").
// - Measurement context (core/engine/context.hpp): the engine follows every cycle's validated
//   events in one MachineContext before the modules step, and every measurement record leaves
//   the engine through it: path_mm and temp_c a module left unknown are filled in, and time_ns
//   becomes the time since the machine's warm start (the log's time_s). The context is saved
//   with the state (an entry named "@context" among the modules' states, which an older engine
//   skips as an unknown module).
// - Event cursors (core/engine/cursors.hpp): per bus and numbered event kind, the NC's counter of
//   the last event step() was handed, saved with the state as the entry "@cursors"; at start-up
//   the daemon gives them to the buses, which resume the NC's events from there.
// - Write receipts (set_write_receipts(), the daemon's loop): max_step_um and max_rate_um_per_s
//   bound what reaches the NC. A bus may write less often than the loop steps (a slow poll, a
//   back-off, a reconnect) and keeps only the latest value per register, so two writes the
//   limiter spaced would reach the NC as one larger step. Each write of an offset register is
//   therefore in flight until the bus reports it finished (write_receipt()); meanwhile the
//   register gets no other write, and the next one is limited from what the NC holds. A refused
//   write puts the limiter back on the NC's value; a write of unknown fate is sent again as it
//   is (within max_step_um of either value the NC may hold). Registers in flight are saved with
//   the state (entry "@inflight") and sent again as they are after an import (reload, restart).
// - Trim handover: each register's sum of trims is saved with the state (entry "@trims") with the
//   identity of what computed it (Module::trim_identity(), e.g. the model file). In the first
//   step after import_state() (a reload, a restart), a register whose trims now come from
//   something else (a model loaded, replaced or taken out) keeps its total: the difference
//   new − old is taken off the writing module's state (Module::rebase_output()) and off the
//   register's target, so the new trims predict and the writer learns what is left. The same
//   trims as saved (a restart of the same configuration) are not rebased. A writer that learned
//   from readings cut at other inputs (earlier along the tool's cut path, at another temperature
//   or time) gets the new trims evaluated at each reading's inputs as well (TrimChange,
//   Module::rebase_output_along()).
//
// Lifecycle: configure() allocates and validates (throws std::invalid_argument naming what is
// wrong); step(), export_state(), import_state() are real-time safe: no allocation, no locks, no
// I/O. core/ is pure: time comes in as an argument.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "core/common/limiter.hpp"
#include "core/common/output.hpp"
#include "core/common/types.hpp"
#include "core/engine/context.hpp"
#include "core/engine/cursors.hpp"
#include "core/engine/input_lag.hpp"
#include "core/engine/input_snapshot.hpp"
#include "core/engine/input_sum.hpp"
#include "core/engine/tool_wear_trims.hpp"

namespace nccomp::core::engine {

/// What an NC register holds; the config names it, drivers map it to bus addresses.
enum class RegisterKind : std::uint8_t {
  kToolLengthWear = 0,
  kToolRadiusWear = 1,
  kCheckpoint = 2,
  kAxisOffset = 3,
  /// A value that is not an offset: a 0 / 1 flag for the NC or PLC (warning, alarm, measurement
  /// due, tool change request) or a program position (a sister tool's restart path [µm]). It is
  /// written exactly as the module asks: only non-finite values and values beyond max_abs_um are
  /// refused; max_step_um and max_rate_um_per_s do not apply (a flag must not be slewed, a path
  /// position is not a correction).
  kFlag = 4,
};

/// "tool_length_wear", "tool_radius_wear", "checkpoint", "axis_offset", "flag".
[[nodiscard]] std::string_view to_string(RegisterKind kind) noexcept;
/// Inverse of to_string(); false if the name is unknown.
[[nodiscard]] bool parse_register_kind(std::string_view name, RegisterKind& out) noexcept;

/// Why the engine writes nothing to a register (RegisterState::hold, `nccomp status`).
enum class RegisterHold : std::uint8_t {
  kNone = 0,
  /// The NC holds a value beyond max_abs_um (read back at start-up, or the output restored or
  /// carried over a reload lies beyond the limit): alarm register_beyond_limit (60).
  kBeyondLimit = 1,
  /// The module that writes it has no usable state and did not adopt the NC's value (or the NC
  /// did not answer the read-back): alarm register_held_without_state (62).
  kWithoutState = 2,
};

/// "none", "beyond_limit", "without_state".
[[nodiscard]] std::string_view to_string(RegisterHold hold) noexcept;

struct RegisterSpec {
  /// Unique name (config key `name`), used to match state across restarts and reloads.
  std::string name;
  RegisterKind kind{RegisterKind::kToolLengthWear};
  LimiterConfig limits{};
};

/// Read-only view of the configured registers, given to modules when they attach.
class RegisterTable {
 public:
  explicit RegisterTable(const std::vector<RegisterSpec>& specs) : specs_(&specs) {}
  [[nodiscard]] std::size_t size() const noexcept { return specs_->size(); }
  [[nodiscard]] const RegisterSpec& operator[](std::size_t i) const { return (*specs_)[i]; }
  /// Index of the register called name, or -1.
  [[nodiscard]] int find(std::string_view name) const noexcept;

 private:
  const std::vector<RegisterSpec>* specs_;
};

/// One value of a module's status (`nccomp status`): key and text are string literals (static
/// storage), so a status is filled without allocating. A value with text != nullptr is a word
/// (e.g. a mode), else a number in the unit its key names.
struct StatusValue {
  const char* key{nullptr};
  double value{0.0};
  const char* text{nullptr};
};
/// Most values one module reports (the creep module: 15 of its own and up to 8 remembered
/// tools, three of its counters making room).
inline constexpr std::size_t kMaxStatusValues = 20;

/// Trim handover: one register's trims, new and old, for a writer whose state holds values
/// measured at earlier inputs (S1's last readings, each cut at its own temperature, time and
/// cut path): it takes each reading's change of trim at the inputs it was cut with. The old
/// trims' module is gone (a rollback, a restart): the writer keeps what they were at each cut
/// (ToolWearTrimSource::trim_in_force_um()), else takes them as they were at the switch.
/// Real-time safe.
class TrimChange {
 public:
  /// The new trims at `inputs` [µm] (an input it does not hold: as now); NaN: unknown (a
  /// trimming module that cannot evaluate at given inputs).
  [[nodiscard]] virtual double new_at(const InputSnapshot& inputs) const noexcept = 0;
  /// The old trims as they were at the switch (saved with the state) [µm].
  [[nodiscard]] virtual double old_at_switch_um() const noexcept = 0;

 protected:
  ~TrimChange() = default;
};

/// A compensation module (S0 creep, S1 checkpoints, S2, S3, a model). Modules write absolute
/// targets (OffsetWrite) for registers they were given at attach(); the engine limits them.
class Module {
 public:
  virtual ~Module() = default;

  /// Stable name: matches a module's state across restarts and reloads.
  [[nodiscard]] virtual std::string_view name() const noexcept = 0;

  /// Not real-time. Validates the register indices the module uses against the table and
  /// allocates everything step() needs. Throws std::invalid_argument with a clear message.
  virtual void attach(const RegisterTable& registers) = 0;

  /// Real-time safe: no allocation, no locks, no I/O. Consumes the cycle's validated events,
  /// appends targets / alarms / measurement records to out.
  virtual void step(TimeNs now_ns, std::span<const Event> events, StepOutput& out) noexcept = 0;

  /// Real-time safe. Every measurement record of the cycle (any module's, stamped with the
  /// machine context), after every module has stepped: a module that learns from measurements
  /// it does not make (the model's session offset). Default: ignored.
  virtual void observe_record(const MeasurementRecord& record) noexcept { (void)record; }

  /// Upper bound [bytes] of save_state()'s output; fixed after attach().
  [[nodiscard]] virtual std::size_t state_capacity() const noexcept { return 0; }
  /// Real-time safe. Serialises the state that must survive a restart; returns bytes written
  /// (≤ state_capacity(), ≤ buf.size()).
  virtual std::size_t save_state(std::span<std::byte> buf) const noexcept {
    (void)buf;
    return 0;
  }
  /// Real-time safe (storage sized in attach()). Restores save_state()'s output; false if the
  /// bytes are not a valid state of this module (the module then keeps its fresh state).
  virtual bool load_state(std::span<const std::byte> bytes) noexcept { return bytes.empty(); }
  /// Real-time safe. Advances whenever the state changed in a way worth persisting.
  [[nodiscard]] virtual std::uint64_t state_generation() const noexcept { return 0; }
  /// Not real-time (after attach()). The register indices this module writes: two modules must
  /// not drive the same register (the engine keeps one target per register, so they would
  /// overwrite each other every cycle); configure() refuses such a table.
  [[nodiscard]] virtual std::vector<std::uint16_t> written_registers() const { return {}; }
  /// Real-time safe (the loop thread publishes it for the status socket). Writes at most
  /// out.size() values; returns how many.
  virtual std::size_t status(std::span<StatusValue> out) const noexcept {
    (void)out;
    return 0;
  }
  /// Not real-time (configure(), after attach()). The engine's machine context (time since the
  /// warm start, cut path per tool, temperatures, position; core/engine/context.hpp), updated
  /// with each cycle's validated events before any module steps. A module may keep the
  /// reference: it lives as long as the engine.
  virtual void bind_context(const MachineContext& context) { (void)context; }
  /// Not real-time. Context options this module sets for the engine (the daemon's
  /// [measurement_context] section); nullptr = none. At most one module of an engine may.
  [[nodiscard]] virtual const ContextOptions* context_options() const noexcept { return nullptr; }
  /// Start-up only (not real-time; after import_state(), before the loop steps the engine): the
  /// module has no usable state and the NC holds nc_value_um in register_index, one of
  /// written_registers(). True: the module took the value as the starting point of its
  /// compensation and keeps the register there until a new measurement (or a command) moves it,
  /// never back toward its fresh value. False (the default): it cannot; the engine then holds
  /// an offset register until the operator releases it (a flag is written as computed).
  virtual bool adopt_output(std::uint16_t register_index, double nc_value_um, TimeNs now_ns) {
    (void)register_index;
    (void)nc_value_um;
    (void)now_ns;
    return false;
  }
  /// Real-time safe. What this module's trims are computed from (e.g. a hash of a fitted model
  /// and its register mapping); 0 = the module publishes no trims. A trim whose identity differs
  /// from the one saved with the state is a handover ("Trim handover" in the file comment).
  [[nodiscard]] virtual std::uint64_t trim_identity() const noexcept { return 0; }
  /// Real-time safe. Trim handover: shift everything this module has learned for register
  /// register_index (one of written_registers()) by delta_um, so its target moves by exactly
  /// delta_um and its later learning continues from there. False (the default): it cannot.
  virtual bool rebase_output(std::uint16_t register_index, double delta_um,
                             TimeNs now_ns) noexcept {
    (void)register_index;
    (void)delta_um;
    (void)now_ns;
    return false;
  }
  /// Real-time safe. rebase_output() with the change evaluated along the path as well (see
  /// TrimChange); the default ignores it.
  virtual bool rebase_output_along(std::uint16_t register_index, double delta_um,
                                   const TrimChange& change, TimeNs now_ns) noexcept {
    (void)change;
    return rebase_output(register_index, delta_um, now_ns);
  }
  /// Real-time safe. The motion of the tool as the module follows it between cycles (last axis
  /// sample, feed direction, …): not state (a restart re-anchors on the first sample), but a
  /// reload's new engine continues it (Engine::export_motion()), so no cycle of cut path or feed
  /// direction is lost at the swap. Writes at most buf.size() bytes, 0 = nothing to carry.
  virtual std::size_t save_motion(std::span<std::byte> buf) const noexcept {
    (void)buf;
    return 0;
  }
  /// Real-time safe. Continues save_motion()'s bytes of the same module in the engine before;
  /// false (nothing changed) if they do not fit.
  virtual bool load_motion(std::span<const std::byte> bytes) noexcept {
    (void)bytes;
    return false;
  }
  /// Real-time safe. The trim this module would publish on register_index had the context been
  /// `inputs` (an input they do not hold: as now) [µm]; NaN: it cannot say (the default).
  [[nodiscard]] virtual double trim_at_inputs(std::uint16_t register_index,
                                              const InputSnapshot& inputs) const noexcept {
    (void)register_index;
    (void)inputs;
    return std::numeric_limits<double>::quiet_NaN();
  }
};

/// Bytes a buffer for Engine::export_motion() needs at most.
inline constexpr std::size_t kMotionBytes = 8192;

struct EngineOptions {
  /// Largest number of events one step accepts; extra events are counted and dropped.
  std::size_t max_events_per_step{256};
  /// The machine context's options, unless a module sets them (Module::context_options()).
  ContextOptions context{};
  /// Derived lag inputs (input_lag.hpp): each cycle, after the validated events, one
  /// TemperatureSample per lag on its output sensor; saved with the state (entry "@lags").
  std::vector<InputLagSpec> lags{};
  /// Derived sum inputs (input_sum.hpp): each cycle, after the lags (whose samples of the cycle
  /// they see), one TemperatureSample per complete sum on its output sensor; not saved.
  std::vector<InputSumSpec> sums{};
};

struct EngineCounters {
  std::uint64_t steps{0};
  std::uint64_t events_accepted{0};
  std::uint64_t events_invalid{0};
  std::uint64_t events_overflow{0};  // beyond max_events_per_step
  std::uint64_t writes_forwarded{0};
  std::uint64_t writes_rejected{0};  // limiter rejected (NaN / absolute limit)
  std::uint64_t writes_unknown_register{0};
  std::uint64_t writes_held{0};       // suppressed by hold mode
  std::uint64_t output_overflows{0};  // StepOutput full: writes/alarms/records lost
  /// More registers to write than one StepOutput holds (128): written on the next cycle(s), in
  /// turn, nothing lost. Large S1 tables at part start or while slewing.
  std::uint64_t writes_deferred{0};
  /// Operator warm-start commands (OperatorCommand kWarmStart) the machine context took, the
  /// sequence number of the last one (0 = none yet), and the context's warm starts (by the idle
  /// rule or declared): the command's sender waits for its sequence here.
  std::uint64_t warm_start_commands{0};
  std::uint32_t last_warm_start_sequence{0};
  std::uint64_t warm_starts{0};
  /// Operator acknowledgements (OperatorCommand kAcknowledge) handed to the modules, and the
  /// sequence number of the last one (0 = none yet): every module stepped with it in the cycle
  /// that counted it (the creep module clears its halt and flags; docs/daemon.md).
  std::uint64_t acknowledge_commands{0};
  std::uint32_t last_acknowledge_sequence{0};
  /// Writes a held register (RegisterHold) would have received: one per register and cycle.
  std::uint64_t writes_blocked{0};
  /// Write receipts: a register's next write waited for the NC to take its previous one (one per
  /// register and cycle). Grows while a bus writes less often than the loop steps: the register
  /// then slews at max_step_um per bus write, not at max_rate_um_per_s.
  std::uint64_t writes_awaiting_nc{0};
  /// Operator releases (OperatorCommand kRegisterRelease) taken, the sequence of the last one
  /// (the sender waits for it) and how many registers it released (0: none was held).
  std::uint64_t release_commands{0};
  std::uint32_t last_release_sequence{0};
  std::uint32_t last_release_count{0};
  /// Trim handovers ("Trim handover" in the file comment): registers whose writing module took
  /// the change of trim into its own state, and registers where none could (no writer, or it
  /// refused): their total moves by the change, through the limiter.
  std::uint64_t handover_rebases{0};
  std::uint64_t handover_unabsorbed{0};
  /// Handovers (first steps after an import in which some register's trims changed identity),
  /// and of the last one: the largest change of a register's trims [µm] and the largest change
  /// that no writer absorbed, i.e. moved the register's total through the limiter [µm] (0: all
  /// absorbed).
  std::uint64_t handovers{0};
  double last_handover_trim_change_um{0.0};
  double last_handover_unabsorbed_um{0.0};
};

/// What Engine::anchor_register() / adopt_register() found and did.
struct AnchorResult {
  /// False: refused (unknown register, or a non-finite value read back); nothing changed.
  bool anchored{false};
  /// What the engine took the NC to hold until then [µm]: the value restored from the state or
  /// last sent in this run. known = false on a fresh register (nothing restored or sent).
  double before_um{0.0};
  bool known{false};
  /// The value read back lies beyond max_abs_um: the register is held (RegisterHold::
  /// kBeyondLimit), nothing is written to it until the operator releases it.
  bool beyond_limit{false};
  /// adopt_register(): the register's target became the value read back.
  bool adopted{false};
};

/// One register's state as status shows it.
struct RegisterState {
  double output_um{0.0};  // last value forwarded (or restored)
  double target_um{0.0};  // last accepted target
  bool has_target{false};
  bool slewing{false};
  /// Σ of the modules' trims; the register converges on target_um + trim_um.
  double trim_um{0.0};
  bool has_trim{false};
  RegisterHold hold{RegisterHold::kNone};
  /// Write receipts: output_um is in flight, the bus has not reported it on the NC yet.
  bool awaiting_nc{false};
};

/// What Engine::adopt_without_state() did with one register.
enum class StartupAdoption : std::uint8_t {
  /// Nothing: no module writes it, its module's state was restored, or it is held beyond the
  /// limit.
  kNotNeeded = 0,
  /// The module took the NC's value as its starting point (the register's target is that value).
  kAdopted = 1,
  /// Held: nothing is written until the operator releases it (RegisterHold::kWithoutState).
  kHeld = 2,
  /// A flag register: written as the module computes it (after the module saw the NC's value).
  kFlag = 3,
  /// The bus cannot read the register back: the module's values are written (the daemon has
  /// nothing to adopt; docs/daemon.md says what the operator does).
  kNotReadable = 4,
};

/// Whether a module's state came from the state file (Engine::module_state()).
enum class ModuleStateSource : std::uint8_t {
  /// No state was imported for it: no state file, or the module is not in it.
  kFresh = 0,
  /// Its entry was in the state but the module refused the bytes (it kept its fresh state).
  kUnreadable = 1,
  kRestored = 2,
};

class Engine {
 public:
  Engine() = default;
  Engine(const Engine&) = delete;
  Engine& operator=(const Engine&) = delete;

  /// Not real-time. Validates registers (unique non-empty names, limits), attaches the modules
  /// (unique names) and sizes every buffer. Throws std::invalid_argument naming the problem.
  void configure(std::vector<RegisterSpec> registers, std::vector<std::unique_ptr<Module>> modules,
                 EngineOptions options = {});

  /// Real-time safe: no allocation, no locks, no I/O. `out` is cleared first; it receives the
  /// limited writes, the alarms and the measurement records of this cycle.
  void step(TimeNs now_ns, std::span<const Event> events, StepOutput& out) noexcept;

  /// Hold mode: nothing is forwarded to the NC (modules and alarms keep running). Real-time safe.
  void set_hold(bool hold) noexcept { hold_ = hold; }
  [[nodiscard]] bool hold() const noexcept { return hold_; }

  /// Marks every register with a known value to be written again on the next step (after a
  /// bus reconnect, at start-up). Real-time safe.
  void resend_all() noexcept;

  /// Write receipts (see the file comment; off by default: a write counts as on the NC when
  /// step() emits it). On: each write of a register that is not a flag stays in flight until
  /// write_receipt() reports it finished. Only from the thread that steps the engine.
  /// Real-time safe.
  void set_write_receipts(bool on) noexcept { receipts_ = on; }
  /// The sequence (OffsetWrite::sequence) of register i's write in flight, 0 if none. Real-time
  /// safe.
  [[nodiscard]] std::uint64_t write_in_flight(std::size_t i) const noexcept {
    return i < regs_.size() ? regs_[i].in_flight : 0;
  }
  /// What the bus did with register i's writes: a receipt for the write in flight (or a later
  /// one) finishes it. kReached: the NC holds it; kRefused: the NC keeps what it held, the
  /// limiter starts from there again at now_ns; kUnknown: it is sent again as it is. Anything
  /// else (kPending, an older sequence, an unknown register) changes nothing. Real-time safe.
  void write_receipt(std::size_t i, WriteReceipt receipt, TimeNs now_ns) noexcept;
  /// The sequence of the last write step() emitted (0: none yet).
  [[nodiscard]] std::uint64_t write_sequence() const noexcept { return write_sequence_; }
  /// A new engine taking over from another (reload): its writes are numbered after `last`, so a
  /// bus's receipt of an earlier engine's write is never taken for one of its own. Before its
  /// first step. Real-time safe.
  void continue_write_sequence(std::uint64_t last) noexcept {
    write_sequence_ = std::max(write_sequence_, last);
  }

  /// Start-up only (after import_state(), before the loop steps the engine; never while another
  /// thread steps it): the NC was read back and holds nc_value_um in register i. The register's
  /// limiter and its last-sent value start from that value, so the next writes move from what
  /// the NC really holds through max_step_um and max_rate_um_per_s (not from the value restored
  /// from the state, which an operator edit or an NC that lost its registers made wrong). The
  /// target stays what the modules compute: a register whose target differs converges on it
  /// from the NC's value. A non-finite value or an unknown register is refused (nothing
  /// changes). No allocation.
  AnchorResult anchor_register(std::size_t i, double nc_value_um, TimeNs now_ns) noexcept;
  /// anchor_register(), and the register's target becomes the NC's value (minus the register's
  /// trims), so the register stays where it is until a module sends another target: for a
  /// value a module adopted from the NC (S1 reconcile_prefer = "nc") but publishes only on a
  /// later cycle. A value beyond max_abs_um is anchored, never adopted.
  AnchorResult adopt_register(std::size_t i, double nc_value_um, TimeNs now_ns) noexcept;

  /// Start-up only, after import_state() and anchor_register() (same rules): if the module that
  /// writes register i has no restored state (or the register is still held without state from
  /// an earlier start), it is offered what the NC holds
  /// (Module::adopt_output()); an offset register it does not adopt is held. nc_value_um:
  /// the read-back, nullopt if there is none; readable: the bus can read registers back (false:
  /// CAN, loopback; nothing is adopted or held then). Raises the register's alarm on the next
  /// step (61 adopted, 62 held) when the NC's value is not 0 (beyond 0.1 µm) or unknown.
  StartupAdoption adopt_without_state(std::size_t i, std::optional<double> nc_value_um,
                                      bool readable, TimeNs now_ns);
  /// Whether module k's state was restored by import_state() (kFresh before any import).
  [[nodiscard]] ModuleStateSource module_state(std::size_t k) const noexcept {
    return module_state_[k];
  }
  /// The module that writes register i (Module::written_registers()), or -1.
  [[nodiscard]] int register_writer(std::size_t i) const noexcept { return writer_[i]; }
  /// Ends register i's hold (what OperatorCommand kRegisterRelease does in step()): beyond the
  /// limit, the register's target (with trims) is written in one move if it is within the
  /// limits, else the limiter starts from the bound; without state, the register converges on
  /// its target from the NC's value through the limiter. False if it was not held. Real-time
  /// safe; only from the thread that steps the engine.
  bool release_register(std::size_t i, TimeNs now_ns) noexcept;

  /// Upper bound [bytes] of export_state(); fixed after configure().
  [[nodiscard]] std::size_t state_capacity() const noexcept { return state_capacity_; }
  /// Real-time safe. Serialises registers and module states into buf; returns bytes written, or
  /// 0 if buf is smaller than needed.
  [[nodiscard]] std::size_t export_state(std::span<std::byte> buf) const noexcept;
  /// Real-time safe. Restores a state exported by this or an earlier configuration: registers and
  /// modules are matched by name (unknown ones in the bytes are skipped and counted in
  /// `skipped`). Limiters restart from the restored outputs at now_ns. Returns false if the bytes
  /// are malformed or a register's output lies beyond its max_abs_um (the limiter would slew
  /// from there, every write beyond the limit); the engine is then unchanged.
  bool import_state(std::span<const std::byte> bytes, TimeNs now_ns,
                    std::size_t* skipped = nullptr) noexcept;
  /// Real-time safe. Advances when registers or module states changed.
  [[nodiscard]] std::uint64_t state_generation() const noexcept;
  /// Real-time safe. A reload (the daemon's loop): the motion the context and the modules follow
  /// (Module::save_motion()) into buf, for the next engine's import_motion() after its
  /// import_state(). Returns bytes written, 0 if buf is too small (kMotionBytes suffices).
  [[nodiscard]] std::size_t export_motion(std::span<std::byte> buf) const noexcept;
  /// Real-time safe. Continues the motion of export_motion()'s bytes: the context's, and each
  /// module's with a module of the same name here. Returns the number of parts continued.
  std::size_t import_motion(std::span<const std::byte> bytes) noexcept;

  [[nodiscard]] std::size_t register_count() const noexcept { return specs_.size(); }
  [[nodiscard]] const RegisterSpec& register_spec(std::size_t i) const { return specs_[i]; }
  [[nodiscard]] RegisterState register_state(std::size_t i) const noexcept;
  [[nodiscard]] const LimiterCounters& limiter_counters(std::size_t i) const noexcept {
    return regs_[i].limiter.counters();
  }
  [[nodiscard]] std::size_t module_count() const noexcept { return modules_.size(); }
  [[nodiscard]] const Module& module(std::size_t i) const { return *modules_[i]; }
  /// For start-up work on a module (e.g. S1 reconcile with registers read back) before the loop
  /// thread steps the engine. Not real-time; never while another thread steps the engine.
  [[nodiscard]] Module& module(std::size_t i) { return *modules_[i]; }
  [[nodiscard]] const EngineCounters& counters() const noexcept { return counters_; }
  /// The machine context (see the file comment). Real-time safe.
  [[nodiscard]] const MachineContext& context() const noexcept { return context_; }
  /// The derived lag inputs (EngineOptions::lags). Real-time safe.
  [[nodiscard]] const InputLags& input_lags() const noexcept { return lags_; }
  /// The derived sum inputs (EngineOptions::sums). Real-time safe.
  [[nodiscard]] const InputSums& input_sums() const noexcept { return sums_; }
  /// The event cursors (see the file comment). Real-time safe.
  [[nodiscard]] const EventCursors& event_cursors() const noexcept { return cursors_; }

 private:
  struct Reg {
    OffsetLimiter limiter;
    double target_um{0.0};
    double sent_um{0.0};
    bool has_target{false};
    bool sent{false};
    bool slewing{false};
    double trim_um{0.0};  // Σ trims_ of this register
    bool has_trim{false};
    RegisterHold hold{RegisterHold::kNone};
    /// An alarm for this register raised on the next step (kNone: none), with its value.
    AlarmCode notice{AlarmCode::kNone};
    double notice_value{0.0};
    /// Write receipts: the sequence of the write in flight (0: none); what the NC holds as far
    /// as the engine knows (nc_sent: anything at all), the limiter's origin after a refusal;
    /// sent_um is to be written again as it is (its fate unknown, or imported in flight), and
    /// the write in flight is such a re-send.
    std::uint64_t in_flight{0};
    double nc_um{0.0};
    bool nc_sent{false};
    bool resend_as_is{false};
    bool as_is_in_flight{false};
  };

  bool validate(const Event& e) const noexcept;
  void hold_register(std::size_t i, RegisterHold hold, AlarmCode notice, double value) noexcept;
  void accept_target(const OffsetWrite& w, TimeNs now_ns, StepOutput& out) noexcept;
  void accept_trim(std::size_t module, const OffsetWrite& w, TimeNs now_ns,
                   StepOutput& out) noexcept;
  /// The NC holds `value_um` (read back, restored): nothing in flight.
  static void nc_holds(Reg& r, double value_um) noexcept;

  std::vector<RegisterSpec> specs_;
  std::vector<Reg> regs_;
  std::vector<std::unique_ptr<Module>> modules_;
  std::vector<Event> valid_;
  /// modules × registers: each module's trim of each register [µm]; NaN = none published.
  std::vector<double> trims_;
  /// Per module: itself as a ToolWearTrimSource (told which of its trims are in force), or null.
  std::vector<ToolWearTrimSource*> wear_source_of_;
  StepOutput scratch_{};
  MachineContext context_{};
  EventCursors cursors_{};
  InputLags lags_{};
  InputSums sums_{};
  EngineOptions options_{};
  EngineCounters counters_{};
  std::size_t state_capacity_{0};
  std::uint64_t register_generation_{0};
  /// First register the convergence scan looks at (round robin when a cycle's writes are full).
  std::size_t write_cursor_{0};
  /// Per module: where its state came from; per register: the module that writes it (-1: none).
  std::vector<ModuleStateSource> module_state_;
  std::vector<int> writer_;
  /// Registers whose notice is still to be raised (step() skips the scan while 0).
  std::size_t notices_pending_{0};
  std::uint64_t write_sequence_{0};
  /// Trim handover: per register, the sum of trims and its identity in the imported state
  /// (known = the register was in its "@trims" entry); pending until the first step after it.
  [[nodiscard]] std::uint64_t trim_identity(std::size_t i) const noexcept;
  void hand_over_trims(TimeNs now_ns) noexcept;
  std::vector<double> handover_trim_um_;
  std::vector<std::uint64_t> handover_identity_;
  std::vector<std::uint8_t> handover_known_;
  bool handover_pending_{false};
  bool hold_{false};
  bool receipts_{false};
};

}  // namespace nccomp::core::engine
