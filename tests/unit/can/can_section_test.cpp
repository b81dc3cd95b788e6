// GIVEN a daemon config whose [can] map has several mistakes and another section one more, WHEN
// nccompd's loader reads it, THEN every mistake of the map is reported beside the other
// section's, each at its key's file:line:column with its key path.
#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <tuple>
#include <vector>

#include "daemon/config/config.hpp"

namespace nccomp::daemon::config {
namespace {

TEST(CanSection, EveryErrorOfTheMapIsReportedBesideTheOtherSections) {
  const std::string text =
      "[can]\ninterface = \"vcan0\"\nack_retries = 200\nack_timout_s = 0.1\n"
      "[[registers]]\nname = \"can0\"\nkind = \"tool_length_wear\"\nbus = \"can\"\n"
      "max_abs_um = 100\nmax_step_um = -5\nmax_rate_um_per_s = 50\n";
  const LoadResult r = load_string(text, "n.toml", ".");
  ASSERT_FALSE(r.config);
  std::vector<std::tuple<std::string, int, int, std::string>> got;
  for (const formats::Diagnostic& d : r.diagnostics.items()) {
    got.emplace_back(d.where.key_path, d.where.line, d.where.column, d.where.file);
  }
  std::sort(got.begin(), got.end());
  const std::vector<std::tuple<std::string, int, int, std::string>> want = {
      {"can.ack_retries", 3, 15, "n.toml"},
      {"can.ack_timout_s", 4, 16, "n.toml"},
      {"registers[0].max_step_um", 10, 15, "n.toml"},
  };
  EXPECT_EQ(got, want) << r.diagnostics.to_string();
}

}  // namespace
}  // namespace nccomp::daemon::config
