#include "core/common/config_issue.hpp"

#include <utility>

namespace nccomp::core {

namespace {

std::string join(const std::vector<ConfigIssue>& issues) {
  std::string s;
  for (const auto& i : issues) {
    if (!s.empty()) s += "; ";
    s += i.key;
    s += ": ";
    s += i.reason;
  }
  return s;
}

}  // namespace

ConfigInvalid::ConfigInvalid(std::vector<ConfigIssue> issues)
    : std::invalid_argument(join(issues)), issues_(std::move(issues)) {}

ConfigInvalid::ConfigInvalid(std::string key, std::string reason)
    : ConfigInvalid(std::vector<ConfigIssue>{{std::move(key), std::move(reason)}}) {}

void ConfigIssues::add(std::string key, std::string reason) {
  issues_.push_back(ConfigIssue{std::move(key), std::move(reason)});
}

void ConfigIssues::throw_if_any() {
  if (!issues_.empty()) {
    std::vector<ConfigIssue> all;
    all.swap(issues_);
    throw ConfigInvalid(std::move(all));
  }
}

}  // namespace nccomp::core
