// Readers of an ncsim result directory (contract C3): the numeric CSVs (surface.csv, walls.csv,
// checkpoints.csv, touches.csv, writes.csv) and result.json.
//
// The CSVs are external input: the header must be exactly the expected one (a different file is
// an error naming the file), while a bad data row (wrong field count, a field that is not a
// finite number, a fraction in an integer column) is skipped, counted and remembered with its
// file:line, so a report on a partly damaged file says how much it left out.
#pragma once

#include <cstddef>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace nccomp::tools::report {

/// Invalid input that stops the report (missing file, wrong header, malformed result.json).
class ReportInputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// A column of a CSV schema: its header name and whether values must be whole numbers.
struct CsvColumn {
  std::string_view name;
  bool integer{false};
};

/// A parsed numeric CSV: row-major finite doubles, the source line of every kept row.
struct CsvTable {
  std::string file;
  std::vector<std::string> columns;
  std::vector<double> values;
  std::vector<std::size_t> lines;
  std::size_t bad_rows{0};
  /// The first kMaxBadRowMessages bad rows as "file:line: what".
  std::vector<std::string> bad_row_messages;

  static constexpr std::size_t kMaxBadRowMessages = 10;

  [[nodiscard]] std::size_t rows() const { return lines.size(); }
  [[nodiscard]] double at(std::size_t row, std::size_t col) const {
    return values[row * columns.size() + col];
  }
  /// Index of a column by name; throws ReportInputError when absent.
  [[nodiscard]] std::size_t column(std::string_view name) const;
};

/// Parses `text` (the contents of `file`) against `schema`. Throws ReportInputError (with
/// file:1) when the header line is not exactly the schema's names joined by commas. A trailing
/// '\r' per line is accepted; the last line may lack its '\n'.
CsvTable parse_csv(std::string_view text, const std::string& file,
                   const std::vector<CsvColumn>& schema);

/// The C3 schemas.
const std::vector<CsvColumn>& surface_schema();
const std::vector<CsvColumn>& walls_schema();
const std::vector<CsvColumn>& checkpoints_schema();
const std::vector<CsvColumn>& touches_schema();
const std::vector<CsvColumn>& writes_schema();

/// A JSON value (result.json). Objects keep their key order.
struct Json {
  // Defined below the struct: clang would otherwise check std::pair<std::string, Json> while
  // Json is still incomplete.
  Json();
  enum class Type { kNull, kBool, kNumber, kString, kArray, kObject };
  Type type{Type::kNull};
  bool boolean{false};
  double number{0.0};
  std::string string;
  std::vector<Json> array;
  std::vector<std::pair<std::string, Json>> object;

  /// Member by key, or nullptr (also when this is not an object).
  [[nodiscard]] const Json* find(std::string_view key) const;
};
inline Json::Json() = default;

/// Parses a JSON document; throws ReportInputError "file:line:col: what". Nesting is limited to
/// 64 levels (a hostile file cannot exhaust the stack).
Json parse_json(std::string_view text, const std::string& file);

/// What result.json says (C3), validated.
struct ResultInfo {
  std::string format;
  std::string program;  // mould_face, side_wall, roll, touch
  std::string bus;
  double sim_time_s{0.0};
  long long parts{0};
  long long seed{0};
  /// Effect name → enabled, and its parameters as "key=value" text in file order.
  struct Effect {
    bool enabled{false};
    std::vector<std::pair<std::string, std::string>> params;
  };
  std::vector<std::pair<std::string, Effect>> effects;
  long long writes_received{0};
  std::map<int, double> registers;  // register index → last value [µm]
  long long alarms_seen{0};
  std::vector<std::string> files;
};

/// Validates a parsed result.json against C3; throws ReportInputError naming the key.
ResultInfo result_info_from_json(const Json& j, const std::string& file);

/// Reads a whole file; throws ReportInputError when it cannot.
std::string read_text_file(const std::string& path);

}  // namespace nccomp::tools::report
