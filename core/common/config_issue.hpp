// A configuration value the core refuses, named by its key path in the operator's file
// ("creep.edge.edge_points", "checkpoints.contour[2].alpha_deg") and the reason, never as text
// with the key inside: the loader points at that key's file, line and column. Not real-time.
#pragma once

#include <stdexcept>
#include <string>
#include <vector>

namespace nccomp::core {

struct ConfigIssue {
  /// The TOML key path, "section.table.key" or "section.array[i].key".
  std::string key;
  /// Why, without the key: "must be > 0, got -2".
  std::string reason;
};

/// Thrown by validate(), configure() and attach() with every issue found (at least one).
/// what() is "key: reason", several joined by "; " (for logs).
class ConfigInvalid : public std::invalid_argument {
 public:
  explicit ConfigInvalid(std::vector<ConfigIssue> issues);
  ConfigInvalid(std::string key, std::string reason);
  [[nodiscard]] const std::vector<ConfigIssue>& issues() const noexcept { return issues_; }

 private:
  std::vector<ConfigIssue> issues_;
};

/// Collects issues so that a validator reports all of them; throw_if_any() throws them.
class ConfigIssues {
 public:
  void add(std::string key, std::string reason);
  [[nodiscard]] bool empty() const noexcept { return issues_.empty(); }
  /// Throws ConfigInvalid with every issue added, if there is one.
  void throw_if_any();

 private:
  std::vector<ConfigIssue> issues_;
};

}  // namespace nccomp::core
