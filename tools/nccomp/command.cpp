#include "tools/nccomp/command.hpp"

#include <algorithm>
#include <cstring>

namespace nccomp::tools {

namespace {
std::vector<CommandEntry>& registry() {
  static std::vector<CommandEntry> entries;
  return entries;
}
}  // namespace

int register_command(const char* name, SetupFn setup) {
  registry().push_back({name, setup});
  return 0;
}

std::vector<CommandEntry> registered_commands() {
  auto entries = registry();
  std::sort(entries.begin(), entries.end(), [](const CommandEntry& a, const CommandEntry& b) {
    return std::strcmp(a.name, b.name) < 0;
  });
  return entries;
}

}  // namespace nccomp::tools
