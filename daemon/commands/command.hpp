// Operator commands on the status socket (docs/daemon.md, "Operator commands"): the verb registry.
// A request line whose first word is a registered verb ("calibrate begin", ...) goes to that
// verb's handler instead of the status renderer. The verbs live beside this file, one per file
// (acknowledge, warm-start, register, calibrate, model), and register themselves at static
// initialisation; their request syntax is client/protocol.hpp's. Handlers run on the status
// server's command thread (one request at a time) and reach the loop only through the CommandBus:
// an SPSC ring of core events that the loop drains like a bus's receive ring, so the loop thread
// takes commands without allocation or locks.
//
// Privilege separation: every verb is registered with an access rule, "changes the machine" by
// default. dispatch_command() runs a changing command only for root, the daemon's own user or a
// member of the admin group ([status] admin_group), judged from the caller's kernel credentials
// (SO_PEERCRED, SO_PEERGROUPS), and logs it with the caller's uid, user name and pid, refused
// attempts too. Read-only verbs opt out explicitly.
// Not real-time (except CommandBus::rx(), which the loop uses).
#pragma once

#include <sys/types.h>

#include <atomic>
#include <cstdint>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include "core/rt/spsc_ring.hpp"
#include "daemon/sections/model/model_choice.hpp"
#include "daemon/sections/model/shadow.hpp"
#include "drivers/bus.hpp"

namespace nccomp::daemon {

class Loop;

/// The command channel into the loop: an extra "bus" in the loop's list whose receive ring the
/// command thread fills. It takes no offset writes (no register is mapped to it).
class CommandBus final : public drivers::Bus {
 public:
  explicit CommandBus(std::size_t capacity = 64);
  void start() override {}
  void stop() override {}
  core::rt::SpscRing<core::Event>& rx() override { return rx_; }
  core::rt::SpscRing<core::OffsetWrite>& tx() override { return tx_; }
  [[nodiscard]] drivers::BusStatus status() const override;

  /// The single producer (the command thread): queues an event for the loop's next cycle.
  /// False if the ring is full (the loop is not running).
  bool push(const core::Event& e);
  /// Commands queued, and refused (malformed, not permitted or the ring full).
  [[nodiscard]] std::uint64_t pushed() const noexcept { return pushed_.load(); }
  [[nodiscard]] std::uint64_t refused() const noexcept { return refused_.load(); }
  void count_refused() noexcept { refused_.fetch_add(1); }

 private:
  core::rt::SpscRing<core::Event> rx_;
  core::rt::SpscRing<core::OffsetWrite> tx_;
  std::atomic<std::uint64_t> pushed_{0};
  std::atomic<std::uint64_t> refused_{0};
};

/// The model the daemon runs (`nccomp model status`; daemon.cpp keeps it).
struct ModelState {
  /// The running configuration has a [model] section (else there is no model to change).
  bool has_section{false};
  /// Its `file`, and whether the operator's choice (`nccomp model load` / `rollback`) replaces
  /// it.
  std::string configured;
  bool chosen{false};
  sections::ModelRecord live;      // file "" = no model
  sections::ModelRecord previous;  // kept for rollback; file "" = none
  std::uint64_t generation{0};     // the configuration it runs in
  /// A model accepted (load, promote, rollback) that the loop has not swapped in yet: it waits
  /// for a cycle in which the bus has confirmed every write. live is the model still in force.
  bool pending{false};
  sections::ModelRecord pending_model;  // file "" = taking the model out
  std::uint64_t pending_generation{0};
  std::uint64_t pending_cycles{0};  // cycles it has waited so far
  /// The candidate in shadow, the scores and the history of decisions.
  sections::ShadowStatus shadow;
};

/// kCandidate: a model into the shadow (nothing on the machine changes); kPromote: the
/// candidate the rule announced made live.
enum class ModelAction { kLoad, kRollback, kCandidate, kPromote };

/// What a model change did: refused (error, nothing changed), or accepted as state.generation.
struct ModelChange {
  bool ok{false};
  std::string error;
  ModelState state;
  /// Accepted, but the record in the state directory could not be written ("" = written).
  std::string record_error;
};

struct CommandContext {
  CommandBus* bus{nullptr};
  const Loop* loop{nullptr};
  /// The running configuration's register names, by index (a reload may change them).
  std::function<std::vector<std::string>()> register_names;
  /// The model verbs (daemon.cpp): the model in force, and a change of it, which the daemon
  /// runs as a reload on its main thread (never two reloads at once) and answers.
  std::function<ModelState()> model_state;
  /// who: the caller as dispatch_command() logs it (for the shadow's history).
  std::function<ModelChange(ModelAction action, const std::string& file, const std::string& who)>
      change_model;
  /// Set by dispatch_command() for a command that changes the machine: uid, user and pid.
  std::string who;
};

/// Who sent a request: the connecting process's credentials as the kernel recorded them at
/// connect() (SO_PEERCRED, SO_PEERGROUPS), not what it claims.
struct Caller {
  bool known{false};  // false: SO_PEERCRED failed; nothing that changes the machine is run
  pid_t pid{0};
  uid_t uid{0};
  gid_t gid{0};               // effective group
  std::vector<gid_t> groups;  // supplementary groups
  bool groups_known{false};   // false: SO_PEERGROUPS failed; only gid counts
};

/// Who may run commands that change the machine besides root.
struct CommandPolicy {
  /// Members of this group (effective or supplementary) may; resolved at each command, so a
  /// group created after the start counts.
  std::string admin_group{"nccomp-admin"};
  /// The daemon's own user: it can already stop the daemon and rewrite its state file.
  uid_t daemon_uid{0};
};

/// True if the group is known to the system (getgrnam).
[[nodiscard]] bool group_exists(const std::string& name);

enum class CommandAccess { kChangesMachine, kReadOnly };

/// What a request (the arguments after the verb) does; must not throw.
using AccessRule = CommandAccess (*)(std::string_view args);
[[nodiscard]] CommandAccess changes_machine(std::string_view args) noexcept;
[[nodiscard]] CommandAccess read_only(std::string_view args) noexcept;

/// args: the request line after the verb, trimmed. Returns the answer (lines ending in '\n'):
/// the first line is "ok ..." or "error: <what>".
using CommandHandler = std::function<std::string(std::string_view args, CommandContext& ctx)>;

/// Registers a verb (static initialisation of the verb's object file). Throws on a duplicate.
/// A verb changes the machine unless its registration says otherwise (read_only, or a rule
/// that looks at the arguments).
int register_command_handler(std::string verb, CommandHandler handler,
                             AccessRule access = &changes_machine);

/// A handler's refusal: counted (CommandBus::refused) unless count is false, logged as a warning,
/// answered "error: <why>\n".
std::string refuse(CommandContext& ctx, const std::string& why, bool count = true);

/// The registered verbs, sorted.
[[nodiscard]] std::vector<std::string> registered_verbs();

/// Set by run_daemon before the status server starts, cleared after it stopped.
void set_command_context(const CommandContext& context);

/// True if the first word of line is a registered verb.
[[nodiscard]] bool is_command(std::string_view line);

/// If the first word of line is a registered verb, checks that caller may run it (policy),
/// runs its handler into answer and returns true. A refusal answers "error: permission denied:
/// ..." without running the handler; refusals and every command that changes the machine are
/// logged with the caller's uid, user name and pid. Exceptions of a handler become "error: ..."
/// answers. Refusals of either kind are counted (CommandBus::refused).
bool dispatch_command(std::string_view line, const Caller& caller, const CommandPolicy& policy,
                      std::string& answer);

}  // namespace nccomp::daemon
