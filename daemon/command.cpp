#include "daemon/command.hpp"

#include <map>
#include <mutex>
#include <stdexcept>

namespace nccomp::daemon {

namespace {

struct Registry {
  std::mutex mu;
  std::map<std::string, CommandHandler, std::less<>> handlers;
  CommandContext context;
};

Registry& registry() {
  static Registry r;
  return r;
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

int register_command_handler(std::string verb, CommandHandler handler) {
  auto& r = registry();
  std::lock_guard<std::mutex> lock(r.mu);
  if (!r.handlers.emplace(std::move(verb), std::move(handler)).second) {
    throw std::logic_error("operator command verb registered twice");
  }
  return 0;
}

void set_command_context(const CommandContext& context) {
  auto& r = registry();
  std::lock_guard<std::mutex> lock(r.mu);
  r.context = context;
}

bool dispatch_command(std::string_view line, std::string& answer) {
  const auto ws = [](char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n'; };
  while (!line.empty() && ws(line.front())) line.remove_prefix(1);
  while (!line.empty() && ws(line.back())) line.remove_suffix(1);
  std::size_t end = 0;
  while (end < line.size() && !ws(line[end])) ++end;
  const std::string_view verb = line.substr(0, end);
  std::string_view args = line.substr(end);
  while (!args.empty() && ws(args.front())) args.remove_prefix(1);
  auto& r = registry();
  CommandHandler handler;
  CommandContext ctx;
  {
    std::lock_guard<std::mutex> lock(r.mu);
    const auto it = r.handlers.find(verb);
    if (it == r.handlers.end()) {
      return false;
    }
    handler = it->second;
    ctx = r.context;
  }
  try {
    answer = handler(args, ctx);
  } catch (const std::exception& e) {
    if (ctx.bus != nullptr) ctx.bus->count_refused();
    answer = std::string("error: ") + e.what() + "\n";
  }
  return true;
}

}  // namespace nccomp::daemon
