// The one diagnostics type of every nccomp file format: a place (file:line:column and key path)
// and a message. Loaders collect every error instead of stopping at the first, so the operator
// sees all of them at once.
//
// Not real-time: everything here allocates.
#pragma once

#include <toml++/toml.h>

#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace nccomp::formats {

/// A position in a file, kept by loaders for errors found after parsing.
struct Where {
  std::string file;
  int line{0};
  int column{0};
  std::string key_path;
};

struct Diagnostic {
  Where where;
  std::string message;
};

/// "file:line:column: key.path: message" (the compilers' format, so editors jump to it); the
/// column is left out where it is unknown (0), line and column where the line is.
[[nodiscard]] std::string format(const Diagnostic& d);

/// Collects errors; parsing continues after an error so the operator sees all of them at once.
class Diagnostics {
 public:
  void error(Where where, std::string message);
  /// An error at node's source position.
  void error(const toml::node* node, std::string key_path, std::string message);
  /// Appends every error of `other`; those without a file name (tables built in memory) get
  /// `file`.
  void append(const Diagnostics& other, std::string_view file);
  [[nodiscard]] bool ok() const noexcept { return items_.empty(); }
  [[nodiscard]] const std::vector<Diagnostic>& items() const noexcept { return items_; }
  /// All errors, one per line.
  [[nodiscard]] std::string to_string() const;

 private:
  std::vector<Diagnostic> items_;
};

/// Thrown by the loaders a command calls (nccomp calibrate, nccomp plan) with every error; a
/// std::invalid_argument whose what() is every error, one per line.
class DiagnosticsError : public std::invalid_argument {
 public:
  /// Errors without a file name get `file`.
  DiagnosticsError(Diagnostics diagnostics, const std::string& file);
  /// A TOML syntax error, at its line and column in `file`.
  DiagnosticsError(const toml::parse_error& e, const std::string& file);
  [[nodiscard]] const Diagnostics& diagnostics() const noexcept { return diagnostics_; }

 private:
  explicit DiagnosticsError(Diagnostics diagnostics);
  Diagnostics diagnostics_;
};

/// node's source position (file, line, column) under key_path; no position if node is null.
[[nodiscard]] Where where_of(const toml::node* node, std::string key_path);

}  // namespace nccomp::formats
