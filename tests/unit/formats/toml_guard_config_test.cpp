// GIVEN config texts that reach a defect of toml++ 3.3.0, WHEN nccompd's config loader reads
// them (as text, as a file, as an included file), THEN it refuses them with one located error
// from the guard (formats/toml/guard.hpp), never with whatever Debian's toml++ makes of them.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "daemon/config/builtin_sections.hpp"
#include "daemon/config/config.hpp"

namespace nccomp::daemon::config {

using formats::format;
namespace {

std::string only_error(const LoadResult& r) {
  EXPECT_FALSE(r.config);
  EXPECT_EQ(r.diagnostics.items().size(), 1U) << r.diagnostics.to_string();
  return r.diagnostics.items().empty() ? "" : format(r.diagnostics.items()[0]);
}

TEST(ConfigTomlGuard, KnownDefectsOfToml3AreLocatedErrors) {
  // The table header and U+FE00 in a key, and what the coverage-guided runs found
  // (tests/fuzz/config/corpus/toml_defect_*).
  EXPECT_EQ(only_error(load_string("[}a]\n", "fuzz.toml", "/nonexistent")),
            "fuzz.toml:1:2: TOML syntax error: expected a key after '[' of a table header, saw "
            "'}'");
  EXPECT_EQ(
      only_error(load_string("[daemon]\nrate\xEF\xB8\x80_hz = 500\n", "fuzz.toml", "/nonexistent")),
      "fuzz.toml:2:5: TOML syntax error: unexpected character U+FE00 outside a string or "
      "comment");
  EXPECT_EQ(only_error(load_string("[\n[daemon]\n", "fuzz.toml", "/nonexistent")),
            "fuzz.toml:1:2: TOML syntax error: expected a key after '[' of a table header, saw a "
            "line break");
  EXPECT_EQ(
      only_error(load_string("[log]\nlevel = \"info\"\xC2\xB5\n", "fuzz.toml", "/nonexistent")),
      "fuzz.toml:2:15: TOML syntax error: unexpected character U+00B5 outside a string or "
      "comment");
  EXPECT_EQ(only_error(load_string("include = [\"x.toml\", }\n", "fuzz.toml", "/nonexistent")),
            "fuzz.toml:1:22: TOML syntax error: expected a value or ']' in an array, saw '}'");
}

TEST(ConfigTomlGuard, IncludedFileIsGuardedToo) {
  const auto dir = std::filesystem::temp_directory_path() /
                   ("nccomp_toml_guard_cfg_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  std::ofstream(dir / "main.toml") << "include = [\"map.toml\"]\n";
  std::ofstream(dir / "map.toml") << "# map\n\n  [[}modbus]]\n";
  const auto r = load_file((dir / "main.toml").string());
  EXPECT_EQ(only_error(r), (dir / "map.toml").string() +
                               ":3:5: TOML syntax error: expected a key after '[' of a table "
                               "header, saw '}'");
  std::filesystem::remove_all(dir);
}

TEST(ConfigTomlGuard, NonAsciiTextInCommentsAndStringsStillLoads) {
  const auto r = load_string(
      "# Gr\xC3\xB6\xC3\x9F"
      "e in \xC2\xB5m, 20 \xC2\xB0"
      "C \xEF\xB8\x80\n"
      "[log]\n# \xC3\xA9\nlevel = \"info\"  # \xC2\xB5\n",
      "fuzz.toml", "/nonexistent");
  EXPECT_TRUE(r.config) << r.diagnostics.to_string();
}

}  // namespace
}  // namespace nccomp::daemon::config
