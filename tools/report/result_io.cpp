#include "tools/report/result_io.hpp"

#include <charconv>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <sstream>

namespace nccomp::tools::report {

namespace {

std::string where(const std::string& file, std::size_t line) {
  return file + ":" + std::to_string(line);
}

// Splits one line at commas (no quoting: C3 files hold numbers only).
void split_fields(std::string_view line, std::vector<std::string_view>& out) {
  out.clear();
  std::size_t start = 0;
  while (true) {
    const std::size_t comma = line.find(',', start);
    if (comma == std::string_view::npos) {
      out.push_back(line.substr(start));
      return;
    }
    out.push_back(line.substr(start, comma - start));
    start = comma + 1;
  }
}

// A finite number in the whole field, or an error message.
bool parse_number(std::string_view field, double& value, std::string& why) {
  // Surrounding blanks are tolerated (hand-edited files); anything else must be the number.
  while (!field.empty() && (field.front() == ' ' || field.front() == '\t')) field.remove_prefix(1);
  while (!field.empty() && (field.back() == ' ' || field.back() == '\t')) field.remove_suffix(1);
  if (field.empty()) {
    why = "empty field";
    return false;
  }
  if (field.front() == '+') field.remove_prefix(1);
  const char* end = field.data() + field.size();
  const auto res = std::from_chars(field.data(), end, value);
  if (res.ec != std::errc() || res.ptr != end) {
    why = "not a number: '" + std::string(field.substr(0, 40)) + "'";
    return false;
  }
  if (!std::isfinite(value)) {
    why = "not finite: '" + std::string(field.substr(0, 40)) + "'";
    return false;
  }
  return true;
}

}  // namespace

std::size_t CsvTable::column(std::string_view name) const {
  for (std::size_t i = 0; i < columns.size(); ++i) {
    if (columns[i] == name) return i;
  }
  throw ReportInputError(file + ": no column '" + std::string(name) + "'");
}

CsvTable parse_csv(std::string_view text, const std::string& file,
                   const std::vector<CsvColumn>& schema) {
  CsvTable t;
  t.file = file;
  std::string expected;
  for (const auto& c : schema) {
    if (!expected.empty()) expected += ',';
    expected += c.name;
    t.columns.emplace_back(c.name);
  }
  std::size_t pos = 0;
  std::size_t line_no = 0;
  std::vector<std::string_view> fields;
  bool header_seen = false;
  while (pos < text.size()) {
    std::size_t nl = text.find('\n', pos);
    const bool last = nl == std::string_view::npos;
    if (last) nl = text.size();
    std::string_view line = text.substr(pos, nl - pos);
    pos = nl + 1;
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    if (!header_seen) {
      if (line != expected) {
        throw ReportInputError(where(file, line_no) + ": header must be '" + expected + "', got '" +
                               std::string(line.substr(0, 200)) + "'");
      }
      header_seen = true;
      continue;
    }
    auto bad = [&](const std::string& why) {
      ++t.bad_rows;
      if (t.bad_row_messages.size() < CsvTable::kMaxBadRowMessages) {
        t.bad_row_messages.push_back(where(file, line_no) + ": " + why);
      }
    };
    if (line.empty()) {
      // A blank last line is just the file's final newline written twice; elsewhere a gap.
      if (!last && pos < text.size()) bad("empty line");
      continue;
    }
    split_fields(line, fields);
    if (fields.size() != schema.size()) {
      bad("expected " + std::to_string(schema.size()) + " fields, got " +
          std::to_string(fields.size()));
      continue;
    }
    const std::size_t base = t.values.size();
    bool ok = true;
    for (std::size_t i = 0; i < fields.size() && ok; ++i) {
      double v = 0.0;
      std::string why;
      if (!parse_number(fields[i], v, why)) {
        bad("column " + std::string(schema[i].name) + ": " + why);
        ok = false;
      } else if (schema[i].integer && (v - std::floor(v) > 0.0 || std::fabs(v) > 9.0e15)) {
        bad("column " + std::string(schema[i].name) + ": not an integer: '" +
            std::string(fields[i].substr(0, 40)) + "'");
        ok = false;
      } else {
        t.values.push_back(v);
      }
    }
    if (!ok) {
      t.values.resize(base);
      continue;
    }
    t.lines.push_back(line_no);
  }
  if (!header_seen) {
    throw ReportInputError(where(file, 1) + ": empty file, header '" + expected + "' expected");
  }
  return t;
}

const std::vector<CsvColumn>& surface_schema() {
  static const std::vector<CsvColumn> s{{"pass", true}, {"path_mm"},  {"x_mm"},     {"y_mm"},
                                        {"z_mm"},       {"error_um"}, {"offset_um"}};
  return s;
}
const std::vector<CsvColumn>& walls_schema() {
  static const std::vector<CsvColumn> s{{"part", true}, {"layer", true}, {"z_mm"},
                                        {"s_mm"},       {"error_um"},    {"offset_um"}};
  return s;
}
const std::vector<CsvColumn>& checkpoints_schema() {
  static const std::vector<CsvColumn> s{
      {"part", true}, {"checkpoint", true}, {"layer", true}, {"z_mm"},
      {"s_mm"},       {"error_um"},         {"probed_um"}};
  return s;
}
const std::vector<CsvColumn>& touches_schema() {
  static const std::vector<CsvColumn> s{
      {"cycle", true},   {"probe", true},         {"axis", true},   {"direction", true},
      {"variant", true}, {"trigger_position_mm"}, {"true_drift_um"}};
  return s;
}
const std::vector<CsvColumn>& writes_schema() {
  static const std::vector<CsvColumn> s{
      {"t_s"}, {"register_index", true}, {"value_um"}, {"effective_t_s"}};
  return s;
}

// ---------------------------------------------------------------------------------------------
// JSON

const Json* Json::find(std::string_view key) const {
  if (type != Type::kObject) return nullptr;
  for (const auto& [k, v] : object) {
    if (k == key) return &v;
  }
  return nullptr;
}

namespace {

class JsonParser {
 public:
  JsonParser(std::string_view text, const std::string& file) : text_(text), file_(file) {}

  Json document() {
    Json v = value(0);
    skip_ws();
    if (pos_ != text_.size()) fail("trailing characters after the document");
    return v;
  }

 private:
  static constexpr int kMaxDepth = 64;

  [[noreturn]] void fail(const std::string& what) const {
    std::size_t line = 1;
    std::size_t col = 1;
    for (std::size_t i = 0; i < pos_ && i < text_.size(); ++i) {
      if (text_[i] == '\n') {
        ++line;
        col = 1;
      } else {
        ++col;
      }
    }
    throw ReportInputError(file_ + ":" + std::to_string(line) + ":" + std::to_string(col) + ": " +
                           what);
  }
  void skip_ws() {
    while (pos_ < text_.size() && (text_[pos_] == ' ' || text_[pos_] == '\t' ||
                                   text_[pos_] == '\n' || text_[pos_] == '\r')) {
      ++pos_;
    }
  }
  bool consume(char c) {
    skip_ws();
    if (pos_ < text_.size() && text_[pos_] == c) {
      ++pos_;
      return true;
    }
    return false;
  }
  void expect(char c) {
    if (!consume(c)) fail(std::string("expected '") + c + "'");
  }
  bool literal(std::string_view word) {
    if (text_.substr(pos_, word.size()) == word) {
      pos_ += word.size();
      return true;
    }
    return false;
  }

  Json value(int depth) {
    if (depth > kMaxDepth) fail("nested deeper than 64 levels");
    skip_ws();
    if (pos_ >= text_.size()) fail("unexpected end of input");
    Json v;
    const char c = text_[pos_];
    if (c == '{') {
      ++pos_;
      v.type = Json::Type::kObject;
      if (consume('}')) return v;
      do {
        skip_ws();
        if (pos_ >= text_.size() || text_[pos_] != '"') fail("expected a string key");
        std::string key = string();
        expect(':');
        v.object.emplace_back(std::move(key), value(depth + 1));
      } while (consume(','));
      expect('}');
    } else if (c == '[') {
      ++pos_;
      v.type = Json::Type::kArray;
      if (consume(']')) return v;
      do {
        v.array.push_back(value(depth + 1));
      } while (consume(','));
      expect(']');
    } else if (c == '"') {
      v.type = Json::Type::kString;
      v.string = string();
    } else if (literal("true")) {
      v.type = Json::Type::kBool;
      v.boolean = true;
    } else if (literal("false")) {
      v.type = Json::Type::kBool;
    } else if (literal("null")) {
      v.type = Json::Type::kNull;
    } else {
      v.type = Json::Type::kNumber;
      v.number = number();
    }
    return v;
  }

  double number() {
    const std::size_t start = pos_;
    while (pos_ < text_.size()) {
      const char c = text_[pos_];
      if ((c >= '0' && c <= '9') || c == '-' || c == '+' || c == '.' || c == 'e' || c == 'E') {
        ++pos_;
      } else {
        break;
      }
    }
    const std::string_view s = text_.substr(start, pos_ - start);
    if (s.empty()) fail("unexpected character");
    double v = 0.0;
    const auto res = std::from_chars(s.data(), s.data() + s.size(), v);
    if (res.ec != std::errc() || res.ptr != s.data() + s.size() || !std::isfinite(v)) {
      pos_ = start;
      fail("invalid number '" + std::string(s.substr(0, 40)) + "'");
    }
    return v;
  }

  static void append_utf8(std::string& out, std::uint32_t cp) {
    if (cp < 0x80) {
      out += static_cast<char>(cp);
    } else if (cp < 0x800) {
      out += static_cast<char>(0xC0 | (cp >> 6));
      out += static_cast<char>(0x80 | (cp & 0x3F));
    } else if (cp < 0x10000) {
      out += static_cast<char>(0xE0 | (cp >> 12));
      out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
      out += static_cast<char>(0x80 | (cp & 0x3F));
    } else {
      out += static_cast<char>(0xF0 | (cp >> 18));
      out += static_cast<char>(0x80 | ((cp >> 12) & 0x3F));
      out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
      out += static_cast<char>(0x80 | (cp & 0x3F));
    }
  }

  std::uint32_t hex4() {
    if (pos_ + 4 > text_.size()) fail("truncated \\u escape");
    std::uint32_t cp = 0;
    for (int i = 0; i < 4; ++i) {
      const char h = text_[pos_++];
      cp <<= 4;
      if (h >= '0' && h <= '9') {
        cp |= static_cast<std::uint32_t>(h - '0');
      } else if (h >= 'a' && h <= 'f') {
        cp |= static_cast<std::uint32_t>(h - 'a' + 10);
      } else if (h >= 'A' && h <= 'F') {
        cp |= static_cast<std::uint32_t>(h - 'A' + 10);
      } else {
        fail("bad \\u escape");
      }
    }
    return cp;
  }

  std::string string() {
    ++pos_;  // opening quote
    std::string out;
    while (true) {
      if (pos_ >= text_.size()) fail("unterminated string");
      const char c = text_[pos_++];
      if (c == '"') return out;
      if (static_cast<unsigned char>(c) < 0x20) fail("control character in a string");
      if (c != '\\') {
        out += c;
        continue;
      }
      if (pos_ >= text_.size()) fail("unterminated string");
      const char e = text_[pos_++];
      switch (e) {
        case '"':
        case '\\':
        case '/':
          out += e;
          break;
        case 'b':
          out += '\b';
          break;
        case 'f':
          out += '\f';
          break;
        case 'n':
          out += '\n';
          break;
        case 'r':
          out += '\r';
          break;
        case 't':
          out += '\t';
          break;
        case 'u': {
          std::uint32_t cp = hex4();
          if (cp >= 0xD800 && cp < 0xDC00 && text_.substr(pos_, 2) == "\\u") {
            pos_ += 2;
            const std::uint32_t lo = hex4();
            if (lo < 0xDC00 || lo >= 0xE000) fail("bad surrogate pair");
            cp = 0x10000 + ((cp - 0xD800) << 10) + (lo - 0xDC00);
          }
          append_utf8(out, cp);
          break;
        }
        default:
          fail("bad escape");
      }
    }
  }

  std::string_view text_;
  const std::string& file_;
  std::size_t pos_{0};
};

std::string json_scalar_text(const Json& v) {
  switch (v.type) {
    case Json::Type::kBool:
      return v.boolean ? "true" : "false";
    case Json::Type::kNumber: {
      std::ostringstream s;
      s << v.number;
      return s.str();
    }
    case Json::Type::kString:
      return v.string;
    case Json::Type::kNull:
      return "null";
    default:
      return v.type == Json::Type::kArray ? "[...]" : "{...}";
  }
}

}  // namespace

Json parse_json(std::string_view text, const std::string& file) {
  return JsonParser(text, file).document();
}

ResultInfo result_info_from_json(const Json& j, const std::string& file) {
  auto err = [&](const std::string& what) { return ReportInputError(file + ": " + what); };
  if (j.type != Json::Type::kObject) throw err("top level must be an object");
  auto str = [&](const char* key) -> std::string {
    const Json* v = j.find(key);
    if (v == nullptr || v->type != Json::Type::kString) {
      throw err(std::string("\"") + key + "\" must be a string");
    }
    return v->string;
  };
  auto num = [&](const Json& obj, const char* key) -> double {
    const Json* v = obj.find(key);
    if (v == nullptr || v->type != Json::Type::kNumber) {
      throw err(std::string("\"") + key + "\" must be a number");
    }
    return v->number;
  };
  auto count = [&](const char* key) -> long long {
    const double v = num(j, key);
    if (v < 0 || v - std::floor(v) > 0.0 || v > 9.0e15) {
      throw err(std::string("\"") + key + "\" must be a whole number >= 0");
    }
    return static_cast<long long>(v);
  };
  ResultInfo r;
  r.format = str("format");
  if (r.format != "ncsim-result-1") {
    throw err("format \"" + r.format + "\" is not \"ncsim-result-1\"");
  }
  r.program = str("program");
  if (r.program != "mould_face" && r.program != "side_wall" && r.program != "roll" &&
      r.program != "touch") {
    throw err("program \"" + r.program + "\" is not mould_face, side_wall, roll or touch");
  }
  r.bus = str("bus");
  r.sim_time_s = num(j, "sim_time_s");
  r.parts = count("parts");
  r.seed = count("seed");
  r.writes_received = count("writes_received");
  r.alarms_seen = count("alarms_seen");
  if (const Json* e = j.find("effects"); e != nullptr) {
    if (e->type != Json::Type::kObject) throw err("\"effects\" must be an object");
    for (const auto& [name, body] : e->object) {
      if (body.type != Json::Type::kObject) throw err("effects." + name + " must be an object");
      ResultInfo::Effect eff;
      const Json* en = body.find("enabled");
      if (en == nullptr || en->type != Json::Type::kBool) {
        throw err("effects." + name + ".enabled must be true or false");
      }
      eff.enabled = en->boolean;
      for (const auto& [k, v] : body.object) {
        if (k != "enabled") eff.params.emplace_back(k, json_scalar_text(v));
      }
      r.effects.emplace_back(name, std::move(eff));
    }
  } else {
    throw err("\"effects\" missing");
  }
  if (const Json* regs = j.find("registers"); regs != nullptr) {
    if (regs->type != Json::Type::kObject) throw err("\"registers\" must be an object");
    for (const auto& [k, v] : regs->object) {
      int index = 0;
      const auto res = std::from_chars(k.data(), k.data() + k.size(), index);
      if (res.ec != std::errc() || res.ptr != k.data() + k.size() || index < 0) {
        throw err("registers key \"" + k + "\" is not a register index");
      }
      if (v.type != Json::Type::kNumber) throw err("registers." + k + " must be a number");
      r.registers[index] = v.number;
    }
  } else {
    throw err("\"registers\" missing");
  }
  if (const Json* f = j.find("files"); f != nullptr) {
    if (f->type != Json::Type::kArray) throw err("\"files\" must be an array");
    for (const auto& v : f->array) {
      if (v.type != Json::Type::kString) throw err("\"files\" entries must be strings");
      if (v.string.find('/') != std::string::npos || v.string == ".." || v.string.empty()) {
        throw err("\"files\" entry \"" + v.string + "\" is not a plain file name");
      }
      r.files.push_back(v.string);
    }
  } else {
    throw err("\"files\" missing");
  }
  return r;
}

std::string read_text_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ReportInputError(path + ": cannot open");
  std::ostringstream s;
  s << in.rdbuf();
  if (in.bad()) throw ReportInputError(path + ": read error");
  return s.str();
}

}  // namespace nccomp::tools::report
