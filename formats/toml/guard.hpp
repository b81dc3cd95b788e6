// The one way nccomp hands TOML text to toml++: Debian 12's toml++ 3.3.0 has three defects on
// malformed input, found by coverage-guided fuzzing (the first and the last fixed upstream
// after 3.3.0):
//   - a table header whose first character is not a key (`[}a]`, `[` + newline, `[[[a]]]`,
//     upstream pull request 301): an assertion in parse_key(), compiled out of Debian's
//     library, undefined behaviour where it is compiled as an assumption (clang);
//   - a '}' where an array expects a value (`a = [}`, `a = [1, }`): an assertion in
//     parse_value(), the same kind;
//   - a character U+00A1..U+0499, U+2C5E..U+2FFF, U+3001..U+3057 or U+FB26..U+FEFE (é, µ, °,
//     U+FE00 ...) where toml++ asks whether it is whitespace: outside strings and comments, and
//     in a multi-line "..." string right after a backslash or after a line-ending backslash;
//     also after a quote that directly follows a bare key or value (`i = 5"°`), and anywhere in
//     a value that begins with a digit or a sign up to the next whitespace, ']', '}', ',' or '#'
//     (`a = 1[["°"]]`), where toml++ reads on to the end of the bad token.
//     Its lookup table reaches __builtin_unreachable() there: undefined behaviour (upstream
//     issues 190 and 295, pull request 305).
// Debian's library is built without assertions and by GCC (no assumption), so there the first
// two end in toml++'s own error; the third is undefined behaviour in any build.
// parse_toml() and parse_toml_file() refuse such text before toml++ sees it, with a
// toml::parse_error at the offending line and column like toml++'s own errors (or toml++'s own
// error when the text is already invalid before that place). Only one valid TOML text is
// refused: a multi-line basic string whose line-ending backslash is followed by one of those
// characters (write it as \uXXXX). Everywhere else they are invalid TOML anyway, and in comments
// and other string positions they are accepted.
#pragma once

#include <toml++/toml.h>
#include <array>
#include <cstddef>
#include <cstdint>
#include <fstream>
#include <iterator>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

namespace nccomp::formats {

/// A place in a TOML text that toml++ 3.3.0 must not see. line and column are 1-based and count
/// code points, as toml++ counts them; offset is in bytes.
struct TomlDefect {
  std::uint32_t line{1};
  std::uint32_t column{1};
  std::size_t offset{0};
  std::string message;
};

namespace toml_guard_detail {

/// Where toml++ 3.3.0's is_non_ascii_horizontal_whitespace() has no defined answer.
constexpr bool undefined_whitespace(char32_t c) noexcept {
  return (c >= 0xA1 && c <= 0x499) || (c >= 0x2C5E && c <= 0x2FFF) ||
         (c >= 0x3001 && c <= 0x3057) || (c >= 0xFB26 && c <= 0xFEFE);
}

/// Non-ASCII characters toml++ takes for horizontal whitespace (and then refuses cleanly).
constexpr bool non_ascii_whitespace(char32_t c) noexcept {
  return c == 0xA0 || c == 0x1680 || c == 0x180E || (c >= 0x2000 && c <= 0x200B) || c == 0x202F ||
         c == 0x205F || c == 0x2060 || c == 0x3000 || c == 0xFEFF;
}

/// toml++'s is_value_terminator() for the characters it answers: whitespace, ']', '}', ',', '#'.
constexpr bool value_terminator(char32_t c) noexcept {
  return c == ' ' || c == '\t' || (c >= '\n' && c <= '\r') || c == ']' || c == '}' || c == ',' ||
         c == '#' || c == 0x85 || c == 0x2028 || c == 0x2029 || non_ascii_whitespace(c);
}

constexpr bool key_start(char32_t c) noexcept {
  return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' ||
         c == '-' || c == '"' || c == '\'';
}

inline std::string code_point_name(char32_t c) {
  if (c >= 0x21 && c < 0x7F) return std::string("'") + static_cast<char>(c) + "'";
  static const char* const kHex = "0123456789ABCDEF";
  std::string s = "U+";
  for (int shift = c > 0xFFFF ? 20 : 12; shift >= 0; shift -= 4) {
    s += kHex[(c >> shift) & 0xF];
  }
  return s;
}

/// Decodes leniently (no overlong or surrogate checks: toml++ is stricter and stops earlier).
class Reader {
 public:
  explicit Reader(std::string_view text) : text_(text) {
    // toml++ skips a byte order mark before it counts lines and columns.
    if (text_.substr(0, 3) == "\xEF\xBB\xBF") pos_ = 3;
  }
  [[nodiscard]] bool eof() const noexcept { return pos_ >= text_.size(); }
  /// The code point at the current position; false at the end or on malformed UTF-8 (where
  /// toml++ stops with its own error).
  bool peek(char32_t& c, std::size_t& len) const noexcept {
    if (eof()) return false;
    const auto b = static_cast<unsigned char>(text_[pos_]);
    std::size_t n = 1;
    if (b < 0x80) {
      c = b;
    } else if ((b & 0xE0) == 0xC0) {
      n = 2;
      c = b & 0x1F;
    } else if ((b & 0xF0) == 0xE0) {
      n = 3;
      c = b & 0x0F;
    } else if ((b & 0xF8) == 0xF0) {
      n = 4;
      c = b & 0x07;
    } else {
      return false;
    }
    if (pos_ + n > text_.size()) return false;
    for (std::size_t i = 1; i < n; ++i) {
      const auto cb = static_cast<unsigned char>(text_[pos_ + i]);
      if ((cb & 0xC0) != 0x80) return false;
      c = (c << 6) | (cb & 0x3F);
    }
    len = n;
    return true;
  }
  /// Peeks and advances; false as peek().
  bool next(char32_t& c) noexcept {
    std::size_t n = 0;
    if (!peek(c, n)) return false;
    here_ = Position{line_, column_, pos_};
    pos_ += n;
    if (c == '\n') {
      ++line_;
      column_ = 1;
    } else {
      ++column_;
    }
    return true;
  }
  [[nodiscard]] bool next_is(char32_t want) const noexcept {
    char32_t c = 0;
    std::size_t n = 0;
    return peek(c, n) && c == want;
  }
  struct Position {
    std::uint32_t line{1};
    std::uint32_t column{1};
    std::size_t offset{0};
  };
  /// Where the code point last returned by next() is.
  [[nodiscard]] Position here() const noexcept { return here_; }

 private:
  std::string_view text_;
  std::size_t pos_{0};
  std::uint32_t line_{1};
  std::uint32_t column_{1};
  Position here_{};
};

inline TomlDefect defect_at(const Reader& r, std::string message) {
  const auto p = r.here();
  return TomlDefect{p.line, p.column, p.offset, std::move(message)};
}

}  // namespace toml_guard_detail

/// The first place in text that would make toml++ 3.3.0 assert or run into undefined behaviour,
/// or nullopt. Follows TOML's lexical structure (keys, values, arrays, strings, comments) as
/// toml++ reads it, and stops where toml++ certainly stops with an error of its own; after
/// other errors it may report places toml++ would never reach (parse_toml() then reports
/// toml++'s error instead).
inline std::optional<TomlDefect> find_toml_defect(std::string_view text) {
  using namespace toml_guard_detail;
  Reader r(text);
  const auto outside = [&](char32_t ch) -> std::optional<TomlDefect> {
    if (!undefined_whitespace(ch)) return std::nullopt;
    return defect_at(
        r, "unexpected character " + code_point_name(ch) + " outside a string or comment");
  };
  char32_t c = 0;
  // Reads the rest of a string whose opening quote was just read. A defect, or nullopt with
  // `stop` set where toml++ stops (end of text, malformed UTF-8, an unterminated string).
  const auto skip_string = [&](char32_t quote, bool& stop) -> std::optional<TomlDefect> {
    stop = true;
    bool multi = false;
    if (r.next_is(quote)) {
      r.next(c);
      if (!r.next_is(quote)) {  // "" or ''
        stop = false;
        return std::nullopt;
      }
      r.next(c);
      multi = true;
    }
    bool skipping = false;  // after a line-ending backslash, where toml++ asks "whitespace?"
    while (r.next(c)) {
      if (c == quote) {
        int run = 1;
        while (multi && run < 5 && r.next_is(quote)) {
          r.next(c);
          ++run;
        }
        if (!multi || run >= 3) {
          stop = false;
          return std::nullopt;
        }
        skipping = false;
        continue;
      }
      if (c == '\n' && !multi) return std::nullopt;
      if (quote == '\'') continue;
      if (c == '\\') {
        skipping = false;
        if (!r.next(c)) return std::nullopt;
        if (!multi) continue;  // toml++ does not classify single-line escapes
        if (undefined_whitespace(c)) {
          return defect_at(r, "unknown escape sequence '\\" + code_point_name(c) + "'");
        }
        if (c == ' ' || c == '\t' || (c >= '\n' && c <= '\r')) {
          // A line-ending backslash: toml++ skips spaces and tabs, expects the line break, then
          // skips whitespace and line breaks up to the next character.
          while (c == ' ' || c == '\t') {
            if (!r.next(c)) return std::nullopt;
          }
          if (undefined_whitespace(c)) {
            return defect_at(
                r, "unexpected character " + code_point_name(c) + " after a line-ending backslash");
          }
          skipping = true;
        }
        continue;
      }
      if (skipping) {
        if (c == ' ' || c == '\t' || c == '\n' || c == '\r' || non_ascii_whitespace(c)) continue;
        if (undefined_whitespace(c)) {
          return defect_at(r, code_point_name(c) +
                                  " as the first character after a line-ending backslash is "
                                  "not supported by the TOML reader (toml++ 3.3.0); write it "
                                  "as an escape (\\u...)");
        }
        skipping = false;
      }
    }
    return std::nullopt;
  };

  enum class Mode { kLineStart, kKey, kValue, kHeader };
  Mode mode = Mode::kLineStart;
  std::string open;         // the [ and { open in a value, innermost last
  bool array_slot = false;  // in an array after '[' or ',': toml++ parses a value next
  bool bare = false;         // the last character belongs to a bare key or value token
  while (r.next(c)) {
    if (mode == Mode::kLineStart) {
      if (c == ' ' || c == '\t' || c == '\n' || c == '\r') continue;
      if (c == '[') {
        // toml++'s parse_table_header(): '[', spaces, a second '[' right after the first,
        // spaces; then parse_key() asserts a key character unless it sees ']'.
        if (!r.next(c)) return std::nullopt;
        bool spaced = false;
        while (c == ' ' || c == '\t') {
          spaced = true;
          if (!r.next(c)) return std::nullopt;
        }
        if (c == '[') {
          if (spaced || !r.next(c)) return std::nullopt;  // "[ [": toml++'s own error
          while (c == ' ' || c == '\t') {
            if (!r.next(c)) return std::nullopt;
          }
        }
        if (auto d = outside(c)) return d;
        if (!key_start(c) && c != ']' && !non_ascii_whitespace(c)) {
          return defect_at(r, "expected a key after '[' of a table header, saw " +
                                  (c == '\n' ? std::string("a line break") : code_point_name(c)));
        }
        mode = Mode::kHeader;
      } else if (c != '#') {
        mode = Mode::kKey;
      }
    }
    // A quote right after a bare key or value character (`i = 5"x`) opens no string: toml++
    // reads on to the end of the bad token and asks "whitespace?" of every character there.
    const bool in_token = bare;
    if (mode == Mode::kValue && !in_token && ((c >= '0' && c <= '9') || c == '+' || c == '-')) {
      // A value that begins with a digit or a sign (a number, date or time): toml++'s
      // parse_value() scans it up to a value terminator, whatever lies between (brackets and
      // quotes too: `a = 1[["x"]]`), and asks "whitespace?" of every character.
      array_slot = false;
      bare = false;
      char32_t n = 0;
      std::size_t len = 0;
      while (r.peek(n, len) && !value_terminator(n)) {
        r.next(c);
        if (undefined_whitespace(c)) {
          return defect_at(r, "unexpected character " + code_point_name(c) +
                                  " in a number, date or time value");
        }
      }
      if (!r.peek(n, len)) return std::nullopt;  // the end, or malformed UTF-8: toml++ stops
      continue;
    }
    bare = (mode == Mode::kKey || mode == Mode::kValue) &&
           ((c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') ||
            c == '_' || c == '-' || c == '+' || c == ':' || c >= 0x80 ||
            (c == '.' && mode == Mode::kValue) || (in_token && (c == '"' || c == '\'')));
    if ((c == '"' || c == '\'') && !in_token) {
      array_slot = false;
      bool stop = false;
      if (auto d = skip_string(c, stop)) return d;
      if (stop) return std::nullopt;
      continue;
    }
    if (c == '#') {
      while (r.next(c) && c != '\n') {
      }
      if (c != '\n') return std::nullopt;
    }
    if (c == '\n') {
      if (mode != Mode::kValue || open.empty()) mode = Mode::kLineStart;
      continue;
    }
    if (auto d = outside(c)) return d;
    if (c == ' ' || c == '\t' || c == '\r') continue;
    if (mode == Mode::kKey && c == '=') {
      mode = Mode::kValue;
      open.clear();
      array_slot = false;
    } else if (mode == Mode::kValue) {
      // toml++'s parse_array() hands a '}' there to parse_value(), which asserts a value.
      if (array_slot && c == '}') {
        return defect_at(r, "expected a value or ']' in an array, saw '}'");
      }
      array_slot = false;
      if (c == '[' || c == '{') {
        open += static_cast<char>(c);
        array_slot = c == '[';
      } else if ((c == ']' || c == '}') && !open.empty()) {
        open.pop_back();
      } else if (c == ',' && !open.empty() && open.back() == '[') {
        array_slot = true;
      }
    }
  }
  return std::nullopt;
}

/// toml::parse(text, source) for text that find_toml_defect() passes; otherwise throws
/// toml::parse_error: toml++'s own error where the text is invalid before the defect (found
/// by parsing only the text before it), else the defect's.
inline toml::table parse_toml(std::string_view text, std::string_view source) {
  const auto defect = find_toml_defect(text);
  if (!defect) return toml::parse(text, source);
  try {
    (void)toml::parse(text.substr(0, defect->offset), source);
  } catch (const toml::parse_error& e) {
    const auto& b = e.source().begin;
    if (b.line < defect->line || (b.line == defect->line && b.column < defect->column)) throw;
  }
  const toml::source_position at{defect->line, defect->column};
  // The description is copied (std::runtime_error).
  throw toml::parse_error(defect->message.c_str(), at, std::make_shared<const std::string>(source));
}

/// toml::parse_file(path) through parse_toml().
inline toml::table parse_toml_file(std::string_view path) {
  std::ifstream in{std::string(path), std::ios::binary};
  if (!in) {
    throw toml::parse_error("File could not be opened for reading", toml::source_position{},
                            std::make_shared<const std::string>(path));
  }
  // read() rather than istreambuf_iterator: GCC 12 at -O3 (the package build) reports a false
  // -Wnull-dereference inside the latter.
  std::string text;
  std::array<char, 65536> buf{};
  while (in.read(buf.data(), buf.size()) || in.gcount() > 0) {
    text.append(buf.data(), static_cast<std::size_t>(in.gcount()));
  }
  return parse_toml(text, path);
}

}  // namespace nccomp::formats
