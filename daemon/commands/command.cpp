#include "daemon/commands/command.hpp"

#include <grp.h>
#include <pwd.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <map>
#include <mutex>
#include <optional>
#include <stdexcept>

namespace nccomp::daemon {

namespace {

struct Verb {
  CommandHandler handler;
  AccessRule access{&changes_machine};
};

struct Registry {
  std::mutex mu;
  std::map<std::string, Verb, std::less<>> verbs;
  CommandContext context;
};

Registry& registry() {
  static Registry r;
  return r;
}

bool ws(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n'; }

std::string_view trim(std::string_view s) {
  while (!s.empty() && ws(s.front())) s.remove_prefix(1);
  while (!s.empty() && ws(s.back())) s.remove_suffix(1);
  return s;
}

std::pair<std::string_view, std::string_view> split_verb(std::string_view line) {
  line = trim(line);
  std::size_t end = 0;
  while (end < line.size() && !ws(line[end])) ++end;
  return {line.substr(0, end), trim(line.substr(end))};
}

// The NSS buffer size the C library suggests, else a size that fits ordinary entries.
std::size_t nss_buffer(int name) {
  const long n = ::sysconf(name);
  return n > 0 ? static_cast<std::size_t>(n) : 16384;
}

std::optional<gid_t> group_id(const std::string& name) {
  std::vector<char> buf(nss_buffer(_SC_GETGR_R_SIZE_MAX));
  for (;;) {
    group g{};
    group* found = nullptr;
    const int rc = ::getgrnam_r(name.c_str(), &g, buf.data(), buf.size(), &found);
    if (rc == ERANGE && buf.size() < (std::size_t{1} << 24)) {
      buf.resize(buf.size() * 2);
      continue;
    }
    if (rc != 0 || found == nullptr) return std::nullopt;
    return g.gr_gid;
  }
}

std::string user_name(uid_t uid) {
  std::vector<char> buf(nss_buffer(_SC_GETPW_R_SIZE_MAX));
  for (;;) {
    passwd p{};
    passwd* found = nullptr;
    const int rc = ::getpwuid_r(uid, &p, buf.data(), buf.size(), &found);
    if (rc == ERANGE && buf.size() < (std::size_t{1} << 24)) {
      buf.resize(buf.size() * 2);
      continue;
    }
    if (rc != 0 || found == nullptr || p.pw_name == nullptr) return "?";
    return p.pw_name;
  }
}

// A request as the log shows it: one line, printable, at most 80 characters.
std::string shown(std::string_view line) {
  std::string s;
  for (const char c : line.substr(0, 80)) {
    s += (c >= 0x20 && c < 0x7f) ? c : '?';
  }
  if (line.size() > 80) s += "...";
  return s;
}

struct Decision {
  bool allowed{false};
  std::string why;  // the refusal's reason
};

Decision authorize(const Caller& caller, const CommandPolicy& policy, const std::string& user) {
  if (!caller.known) {
    return {false, "the caller's credentials cannot be read"};
  }
  if (caller.uid == 0 || caller.uid == policy.daemon_uid) {
    return {true, {}};
  }
  const std::optional<gid_t> admin = group_id(policy.admin_group);
  if (!admin) {
    return {false, "group '" + policy.admin_group +
                       "' ([status] admin_group) does not exist on this host: only root and the "
                       "daemon's own user may"};
  }
  if (caller.gid == *admin ||
      std::find(caller.groups.begin(), caller.groups.end(), *admin) != caller.groups.end()) {
    return {true, {}};
  }
  std::string why = "uid " + std::to_string(caller.uid) + " (" + user +
                    ") is not root and not in group '" + policy.admin_group +
                    "' ([status] admin_group)";
  if (!caller.groups_known) {
    why += " (its supplementary groups cannot be read)";
  }
  why += "\n  an administrator grants it with: usermod -aG " + policy.admin_group + " " +
         (user == "?" ? std::string("<user>") : user) + " (effective at the user's next login)";
  return {false, why};
}

}  // namespace

CommandBus::CommandBus(std::size_t capacity) : rx_(capacity), tx_(2) {}

drivers::BusStatus CommandBus::status() const {
  drivers::BusStatus s;
  s.state = drivers::LinkState::kUp;
  s.counters.events_decoded = pushed_.load();
  s.counters.malformed = refused_.load();
  return s;
}

bool CommandBus::push(const core::Event& e) {
  if (!rx_.try_push(e)) {
    return false;
  }
  pushed_.fetch_add(1);
  return true;
}

bool group_exists(const std::string& name) { return group_id(name).has_value(); }

CommandAccess changes_machine(std::string_view /*args*/) noexcept {
  return CommandAccess::kChangesMachine;
}

CommandAccess read_only(std::string_view /*args*/) noexcept { return CommandAccess::kReadOnly; }

int register_command_handler(std::string verb, CommandHandler handler, AccessRule access) {
  if (access == nullptr) {
    throw std::logic_error("operator command verb registered without an access rule");
  }
  auto& r = registry();
  std::lock_guard<std::mutex> lock(r.mu);
  if (!r.verbs.emplace(std::move(verb), Verb{std::move(handler), access}).second) {
    throw std::logic_error("operator command verb registered twice");
  }
  return 0;
}

std::string refuse(CommandContext& ctx, const std::string& why, bool count) {
  if (count && ctx.bus != nullptr) ctx.bus->count_refused();
  spdlog::warn("operator command refused: {}", why);
  return "error: " + why + "\n";
}

std::vector<std::string> registered_verbs() {
  auto& r = registry();
  std::lock_guard<std::mutex> lock(r.mu);
  std::vector<std::string> v;
  for (const auto& [verb, entry] : r.verbs) v.push_back(verb);
  return v;
}

void set_command_context(const CommandContext& context) {
  auto& r = registry();
  std::lock_guard<std::mutex> lock(r.mu);
  r.context = context;
}

bool is_command(std::string_view line) {
  const auto verb = split_verb(line).first;
  auto& r = registry();
  std::lock_guard<std::mutex> lock(r.mu);
  return r.verbs.find(verb) != r.verbs.end();
}

bool dispatch_command(std::string_view line, const Caller& caller, const CommandPolicy& policy,
                      std::string& answer) {
  const auto [verb, args] = split_verb(line);
  auto& r = registry();
  Verb entry;
  CommandContext ctx;
  {
    std::lock_guard<std::mutex> lock(r.mu);
    const auto it = r.verbs.find(verb);
    if (it == r.verbs.end()) {
      return false;
    }
    entry = it->second;
    ctx = r.context;
  }
  if (entry.access(args) == CommandAccess::kChangesMachine) {
    const std::string user = caller.known ? user_name(caller.uid) : "?";
    const std::string who = caller.known ? "uid " + std::to_string(caller.uid) + " (" + user +
                                               ") pid " + std::to_string(caller.pid)
                                         : "an unknown caller";
    const Decision d = authorize(caller, policy, user);
    if (!d.allowed) {
      if (ctx.bus != nullptr) ctx.bus->count_refused();
      spdlog::warn("operator command refused: '{}' from {}: permission denied: {}",
                   shown(trim(line)), who, d.why.substr(0, d.why.find('\n')));
      answer = "error: permission denied: '" + std::string(verb) + "' changes the machine; " +
               d.why + "\n";
      return true;
    }
    spdlog::info("operator command from {}: {}", who, shown(trim(line)));
    ctx.who = who;
  }
  try {
    answer = entry.handler(args, ctx);
  } catch (const std::exception& e) {
    if (ctx.bus != nullptr) ctx.bus->count_refused();
    answer = std::string("error: ") + e.what() + "\n";
  }
  return true;
}

}  // namespace nccomp::daemon
