// Follows nccompd's measurement log (daemon/measurement_log.hpp) as the daemon writes and rotates
// it: measurements.csv, rotated to measurements.csv.1, .2, … Reads complete rows only, oldest
// file first, and turns each v2 row into a JSON object (columns in header order). A cursor (the
// file's inode, the offset after the last row taken, a hash of the file's first bytes against a
// reused inode) says where to go on; the publisher keeps it with its queue, so a restart resumes
// exactly after the last row it queued. Not real-time: a process of its own reads the files the
// daemon has written.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace nccomp::tools::mqtt {

struct LogCursor {
  std::uint64_t inode{0};  // 0 = none yet: start at the beginning of the current file
  std::uint64_t offset{0};
  /// Hash of the file's first min(offset, 1024) bytes.
  std::uint64_t head_hash{0};

  /// "inode:offset:hash" (no tabs, no newlines) and back; throws std::invalid_argument.
  [[nodiscard]] std::string to_string() const;
  static LogCursor parse(const std::string& s);
  friend bool operator==(const LogCursor&, const LogCursor&) = default;
};

/// Columns whose cells are text; the others are numbers (integers for these four).
[[nodiscard]] bool is_text_column(const std::string& name);
[[nodiscard]] bool is_integer_column(const std::string& name);

/// One log row: its columns as JSON, where it was, and the cursor after it.
struct LogRow {
  nlohmann::ordered_json columns;
  std::string file;
  std::size_t line{0};
  LogCursor after;
};

/// A row that is not a measurement row, or a file that is skipped: what and where.
struct LogProblem {
  std::string file;
  std::size_t line{0};
  std::string message;
};

/// Turns a CSV row into JSON by the header's columns: text columns as strings, empty cells as
/// null, the others as numbers. Returns false (with `error`) for a wrong field count or a cell
/// that is not a number.
[[nodiscard]] bool row_to_json(const std::vector<std::string>& header, const std::string& line,
                               nlohmann::ordered_json& out, std::string& error);

/// The inverse for the collector: one CSV row of `header` from a JSON object (absent / null =
/// empty cell). Numbers are written as they came.
[[nodiscard]] std::string json_to_row(const std::vector<std::string>& header,
                                      const nlohmann::ordered_json& row);

class LogSource {
 public:
  explicit LogSource(std::string directory) : directory_(std::move(directory)) {}

  void set_cursor(const LogCursor& c) { cursor_ = c; }
  [[nodiscard]] const LogCursor& cursor() const noexcept { return cursor_; }

  /// Reads up to max_rows complete rows after the cursor, advancing it. Rows that cannot be
  /// taken (a v1 file, a malformed row) are skipped and reported in `problems`; a file rotated
  /// away before its rows were read is reported too (the rows of the oldest remaining file
  /// follow). Never throws for file content; throws std::system_error if the directory cannot
  /// be read.
  std::vector<LogRow> poll(std::size_t max_rows, std::vector<LogProblem>& problems);

  /// Files rotated away unread (their rows are lost to the publisher).
  [[nodiscard]] std::uint64_t files_missed() const noexcept { return files_missed_; }

 private:
  struct File {
    std::string path;
    std::uint64_t inode{0};
    std::uint64_t size{0};
  };
  [[nodiscard]] std::vector<File> list() const;

  std::string directory_;
  LogCursor cursor_;
  std::uint64_t files_missed_{0};
  // The header of the file the cursor is in (read again when the cursor moves to another file).
  std::uint64_t header_inode_{0};
  std::vector<std::string> header_;
  bool header_v2_{false};
};

/// FNV-1a of the bytes.
[[nodiscard]] std::uint64_t fnv1a(const char* data, std::size_t n) noexcept;

}  // namespace nccomp::tools::mqtt
