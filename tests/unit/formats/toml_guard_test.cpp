// GIVEN TOML texts that reach a defect of toml++ 3.3.0 (an assertion in parse_key(), an
// unreachable branch in its whitespace table), WHEN they go through formats::parse_toml(),
// THEN each is refused with a toml::parse_error at its line and column, before toml++ sees it.
// toml++ is compiled from its headers here with its assertions on, under ASan/UBSan (dev): an
// input that slipped through aborts the test. Valid TOML (non-ASCII text in strings and
// comments, nested arrays at the start of a line, the shipped configs) parses as before.
#include "formats/toml/guard.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <string_view>

namespace nccomp::formats {
namespace {

struct Refusal {
  std::uint32_t line;
  std::uint32_t column;
  std::string description;
};

Refusal refusal(std::string_view text) {
  try {
    (void)parse_toml(text, "t.toml");
  } catch (const toml::parse_error& e) {
    EXPECT_EQ(*e.source().path, "t.toml");
    return {e.source().begin.line, e.source().begin.column, std::string(e.description())};
  }
  ADD_FAILURE() << "accepted: " << text;
  return {0, 0, ""};
}

TEST(TomlGuard, TableHeaderWithoutAKeyIsRefused) {
  // The input, then the same defect behind "[[" and after spaces.
  const auto r = refusal("[}a]\n");
  EXPECT_EQ(r.line, 1U);
  EXPECT_EQ(r.column, 2U);
  EXPECT_EQ(r.description, "expected a key after '[' of a table header, saw '}'");
  const auto a = refusal("x = 1\n[[ =]]\n");
  EXPECT_EQ(a.line, 2U);
  EXPECT_EQ(a.column, 4U);
  EXPECT_EQ(a.description, "expected a key after '[' of a table header, saw '='");
  const auto n = refusal("[\na]\n");
  EXPECT_EQ(n.line, 1U);
  EXPECT_EQ(n.column, 2U);
  EXPECT_EQ(n.description, "expected a key after '[' of a table header, saw a line break");
  EXPECT_EQ(refusal("  [#]").column, 4U);
  EXPECT_EQ(refusal("[[[a]]]").column, 3U);  // upstream pull request 301
  EXPECT_EQ(refusal("[\t.a]").column, 3U);
  // Found by the coverage-guided run of fuzz_daemon_config (tests/fuzz/config/corpus).
  EXPECT_EQ(refusal("[~easurement_context]\nw = 2\n").column, 2U);
}

TEST(TomlGuard, ClosingBraceWhereAnArrayExpectsAValueIsRefused) {
  // Found by the coverage-guided runs of fuzz_daemon_config and fuzz_checkpoint_config.
  const auto r = refusal("a = [}");
  EXPECT_EQ(r.line, 1U);
  EXPECT_EQ(r.column, 6U);
  EXPECT_EQ(r.description, "expected a value or ']' in an array, saw '}'");
  EXPECT_EQ(refusal("include = [\"x.toml\", }\n").column, 22U);
  EXPECT_EQ(refusal("a = [\n  # c\n  }]").line, 3U);
  EXPECT_EQ(refusal("a = [[}]]").column, 7U);
  EXPECT_EQ(refusal("a = [{x = 1}, }").column, 15U);
}

TEST(TomlGuard, CharactersWithoutAWhitespaceAnswerAreRefusedOutsideStrings) {
  // U+FE00 in a key, at the start of a line, in an inline table; U+032A (upstream issue 295),
  // é and ° lie in the same undefined ranges of toml++'s table (U+00A1..U+0499 ...).
  const auto k = refusal("a\xEF\xB8\x80 = 1\n");
  EXPECT_EQ(k.line, 1U);
  EXPECT_EQ(k.column, 2U);
  EXPECT_EQ(k.description, "unexpected character U+FE00 outside a string or comment");
  EXPECT_EQ(refusal("\xEF\xB8\x80 = 1").column, 1U);
  EXPECT_EQ(refusal("a = {\xEF\xB8\x80 = 1}").column, 6U);
  EXPECT_EQ(refusal("a = 1\xC2\xB0").column, 6U);
  EXPECT_EQ(refusal("\xCC\xAA").description,
            "unexpected character U+032A outside a string or comment");
  EXPECT_EQ(refusal("x = 1\na\xC3\xA9 = 1").line, 2U);
  EXPECT_EQ(refusal("[a\xC3\xA9]").column, 3U);
  EXPECT_EQ(refusal("[\xC3\xA9]").description,
            "unexpected character U+00E9 outside a string or comment");
  EXPECT_EQ(refusal("a = [1,\n  2\xE3\x80\x81]").line, 2U);  // U+3001
}

TEST(TomlGuard, AQuoteRightAfterABareTokenOpensNoString) {
  // Found by fuzz_model_map (minimized): after the bad number `5"` toml++ reads on to the end of
  // the token and asks "whitespace?" of the degree sign. Refused (toml++'s own error comes
  // first, at the quote); with the guard treating the quote as a string, UBSan stops here.
  const auto v = refusal("i=5\"\xC2\xB0");
  EXPECT_EQ(v.line, 1U);
  EXPECT_LE(v.column, 5U);
  EXPECT_EQ(refusal("ab\"\xC2\xB0\" = 1").line, 1U);
  // Found by the coverage-guided run of fuzz_daemon_config (minimized): a value that begins
  // with a digit or a sign is scanned by toml++ up to a value terminator, brackets and quotes
  // included, so the quotes there open no string either.
  const auto b = refusal("a = 1[[\"\xC2\xB0\"]]\n");
  EXPECT_EQ(b.line, 1U);
  EXPECT_LE(b.column, 9U);
  EXPECT_EQ(refusal("a = [-2{\"\xD2\x8E\"}]").line, 1U);
  EXPECT_EQ(refusal("rahz = 1[-\x18" "a[[-se_0[[\"x\xD2\x8Eoml\"a").line, 1U);
  // After a terminator a string is a string: in arrays, inline tables, after a comment.
  EXPECT_NO_THROW((void)parse_toml("a = [1, \"\xC2\xB0\", -2,\"\xC2\xB5\"]\n"
                                   "b = {x = 1, y = \"\xC2\xB0\"}\nc = 3 # \xC2\xB0" "C\n"
                                   "d = 1979-05-27T07:32:00Z\ne = [+1.5e3]",
                                   "t.toml"));
  // A quoted key after a dot and a string value after '=' are strings as before.
  EXPECT_NO_THROW((void)parse_toml("a.\"t2(\xC2\xB0" "C)\" = \"\xC2\xB0\"", "t.toml"));
}

TEST(TomlGuard, MultiLineStringEscapesThatReachTheTableAreRefused) {
  // A backslash followed by such a character (an unknown escape anyway) ...
  const auto e = refusal("s = \"\"\"a\\\xC2\xB5\"\"\"");
  EXPECT_EQ(e.column, 10U);
  EXPECT_EQ(e.description, "unknown escape sequence '\\U+00B5'");
  // ... after spaces behind a backslash ...
  EXPECT_EQ(refusal("s = \"\"\"a\\  \xC2\xB5\"\"\"").column, 12U);
  // ... and as the first character after a line-ending backslash (upstream issue 190): valid
  // TOML, the one text the guard refuses; the escape is the way to write it.
  const auto c = refusal("s = \"\"\"\\\n  \n   \xC2\xB5m\"\"\"\n");
  EXPECT_EQ(c.line, 3U);
  EXPECT_EQ(c.column, 4U);
  EXPECT_NE(c.description.find("write it as an escape"), std::string::npos);
  const auto t = parse_toml("s = \"\"\"\\\n   \\u00B5m\"\"\"\n", "t.toml");
  EXPECT_EQ(t["s"].value_or(std::string()), "\xC2\xB5m");
}

TEST(TomlGuard, TomlsOwnErrorIsReportedWhenItComesFirst) {
  // The text is invalid before the defect: toml++ (which never reaches it) names the first one.
  const auto r = refusal("a = = 1\n[}b]\n");
  EXPECT_EQ(r.line, 1U);
  EXPECT_EQ(r.column, 5U);
  EXPECT_EQ(r.description.find("expected a key"), std::string::npos) << r.description;
}

TEST(TomlGuard, ValidTomlWithNonAsciiTextAndNestedArraysParsesAsBefore) {
  const char* text =
      "# Wear in \xC2\xB5m, 20 \xC2\xB0"
      "C, caf\xC3\xA9 \xEF\xB8\x80\n"
      "name = \"Fr\xC3\xA4ser \xC2\xB5 \xEF\xB8\x80\"\n"
      "lit = 'd\xC3\xA9j\xC3\xA0'\n"
      "ml = \"\"\"\n[}a]\n\xC2\xB5\"\"\"\"\n"
      "mll = '''\xC2\xB5'''''\n"
      "\"k\xC3\xA9y\" = 1  # \xC3\xA9\n"
      "grid = [\n  [ ],\n  [+1, -2],\n  [{x = 1}],  # \xC2\xB0\n]\n"
      "inl = {b = [1, 2], c = {d = []}}\n"
      "[\"t\xC3\xA9\".sub]\n"
      "[[arr]]\n";
  ASSERT_FALSE(find_toml_defect(text));
  const auto t = parse_toml(text, "t.toml");
  EXPECT_EQ(t["name"].value_or(std::string()), "Fr\xC3\xA4ser \xC2\xB5 \xEF\xB8\x80");
  EXPECT_EQ(t["lit"].value_or(std::string()), "d\xC3\xA9j\xC3\xA0");
  EXPECT_EQ(t["ml"].value_or(std::string()), "[}a]\n\xC2\xB5\"");
  EXPECT_EQ(t["mll"].value_or(std::string()), "\xC2\xB5''");
  EXPECT_EQ(t["k\xC3\xA9y"].value_or(0), 1);
  EXPECT_EQ(t["grid"].as_array()->size(), 3U);
  EXPECT_EQ(t["grid"][1][0].value_or(0), 1);
  EXPECT_EQ(t["inl"]["b"][1].value_or(0), 2);
  EXPECT_TRUE(t["t\xC3\xA9"]["sub"].is_table());
  EXPECT_TRUE(t["arr"].is_array_of_tables());
}

TEST(TomlGuard, ShippedConfigsPass) {
  int files = 0;
  for (const auto& e : std::filesystem::recursive_directory_iterator(NCCOMP_SOURCE_DIR "/config")) {
    if (e.path().extension() != ".toml") continue;
    std::ifstream in(e.path(), std::ios::binary);
    const std::string text{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
    EXPECT_FALSE(find_toml_defect(text)) << e.path();
    EXPECT_NO_THROW((void)parse_toml(text, e.path().string())) << e.path();
    ++files;
  }
  EXPECT_GE(files, 10);
}

TEST(TomlGuard, FileReaderAppliesTheGuard) {
  const auto dir = std::filesystem::temp_directory_path();
  const auto path = (dir / ("nccomp_toml_guard_" + std::to_string(::getpid()) + ".toml")).string();
  std::ofstream(path) << "a = 1\n[}a]\n";
  try {
    (void)parse_toml_file(path);
    ADD_FAILURE() << "accepted";
  } catch (const toml::parse_error& e) {
    EXPECT_EQ(*e.source().path, path);
    EXPECT_EQ(e.source().begin.line, 2U);
    EXPECT_EQ(e.source().begin.column, 2U);
  }
  std::filesystem::remove(path);
  EXPECT_THROW((void)parse_toml_file(path), toml::parse_error);  // gone: cannot be opened
}

}  // namespace
}  // namespace nccomp::formats
