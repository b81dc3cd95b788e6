// GIVEN the shipped example configurations (the ones an operator copies to /etc/nccompd), WHEN
// each is parsed, THEN every key that starts a line has a comment line directly above it (the
// chrony examples are the model: the file is its own documentation). Keys inside inline tables
// (`x_mm = { table = ..., address = ... }`) share their line and are covered by its comment.
#include <gtest/gtest.h>
#include <toml++/toml.h>

#include <fstream>
#include <sstream>
#include <string>
#include <string_view>
#include <vector>

namespace {

std::vector<std::string> read_lines(const std::string& path) {
  std::ifstream in(path);
  std::vector<std::string> lines;
  for (std::string l; std::getline(in, l);) {
    lines.push_back(l);
  }
  return lines;
}

std::string trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r");
  if (b == std::string::npos) {
    return {};
  }
  const auto e = s.find_last_not_of(" \t\r");
  return s.substr(b, e - b + 1);
}

struct Checker {
  const std::vector<std::string>& lines;
  std::string file;
  std::vector<std::string> missing;
  std::size_t keys{0};

  void table(const toml::table& t, const std::string& path) {
    for (auto&& [k, v] : t) {
      const std::string key(k.str());
      const std::string sub = path.empty() ? key : path + "." + key;
      const auto line = static_cast<std::size_t>(k.source().begin.line);
      if (line >= 1 && line <= lines.size()) {
        const std::string text = trim(lines[line - 1]);
        // A key that starts its line (not a table header, not inside an inline table).
        if (text.rfind(key, 0) == 0 || text.rfind("\"" + key + "\"", 0) == 0) {
          ++keys;
          const std::string above = line >= 2 ? trim(lines[line - 2]) : std::string();
          if (above.empty() || above[0] != '#') {
            missing.push_back(file + ":" + std::to_string(line) + ": " + sub);
          }
        }
      }
      if (const auto* sub_table = v.as_table(); sub_table != nullptr && !sub_table->is_inline()) {
        table(*sub_table, sub);
      } else if (const auto* arr = v.as_array(); arr != nullptr && arr->is_array_of_tables()) {
        for (std::size_t i = 0; i < arr->size(); ++i) {
          const auto* e = arr->get(i)->as_table();
          if (e != nullptr && !e->is_inline()) {
            table(*e, sub + "[" + std::to_string(i) + "]");
          }
        }
      }
    }
  }
};

class ShippedConfig : public testing::TestWithParam<const char*> {};

TEST_P(ShippedConfig, EveryKeyHasACommentAbove) {
  const std::string path = std::string(NCCOMP_SOURCE_DIR) + "/config/" + GetParam();
  const auto lines = read_lines(path);
  ASSERT_FALSE(lines.empty()) << path;
  toml::table t;
  try {
    t = toml::parse_file(path);
  } catch (const toml::parse_error& e) {
    FAIL() << path << ": " << e.description();
  }
  Checker c{lines, GetParam(), {}, 0};
  c.table(t, "");
  EXPECT_GT(c.keys, 5U) << "no keys found: the checker is broken";
  std::ostringstream s;
  for (const auto& m : c.missing) {
    s << "  " << m << "\n";
  }
  EXPECT_TRUE(c.missing.empty()) << c.missing.size() << " of " << c.keys
                                 << " keys have no comment line directly above:\n"
                                 << s.str();
}

INSTANTIATE_TEST_SUITE_P(Config, ShippedConfig,
                         testing::Values("nccompd.toml", "nccompd-loopback.toml",
                                         "reference-nc-modbus.toml", "reference-nc-can.toml",
                                         "nccomp-publish.toml"),
                         [](const testing::TestParamInfo<const char*>& i) {
                           std::string n = i.param;
                           for (char& ch : n) {
                             if (ch == '.' || ch == '-') {
                               ch = '_';
                             }
                           }
                           return n;
                         });

// The checker itself: a key without a comment above is found, one with a comment is not.
TEST(ShippedConfigChecker, FindsAKeyWithoutComment) {
  const std::vector<std::string> lines{"# a comment", "a = 1", "b = 2",        "[t]",
                                       "# c",         "c = 3", "d = { e = 1 }"};
  std::string text;
  for (const auto& l : lines) {
    text += l + "\n";
  }
  const toml::table t = toml::parse(std::string_view(text), std::string_view("x.toml"));
  Checker c{lines, "x.toml", {}, 0};
  c.table(t, "");
  EXPECT_EQ(c.keys, 4U);  // a, b, c, d (e is inside d's inline table)
  ASSERT_EQ(c.missing.size(), 2U);
  EXPECT_EQ(c.missing[0], "x.toml:3: b");
  EXPECT_EQ(c.missing[1], "x.toml:7: t.d");
}

}  // namespace
