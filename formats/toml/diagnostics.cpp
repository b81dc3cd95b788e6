#include "formats/toml/diagnostics.hpp"

#include <sstream>
#include <utility>

namespace nccomp::formats {

std::string format(const Diagnostic& d) {
  std::ostringstream s;
  s << (d.where.file.empty() ? "<config>" : d.where.file);
  if (d.where.line > 0) {
    s << ':' << d.where.line;
    if (d.where.column > 0) s << ':' << d.where.column;
  }
  s << ": ";
  if (!d.where.key_path.empty()) {
    s << d.where.key_path << ": ";
  }
  s << d.message;
  return s.str();
}

void Diagnostics::error(Where where, std::string message) {
  items_.push_back(Diagnostic{std::move(where), std::move(message)});
}

void Diagnostics::error(const toml::node* node, std::string key_path, std::string message) {
  error(where_of(node, std::move(key_path)), std::move(message));
}

void Diagnostics::append(const Diagnostics& other, std::string_view file) {
  for (Diagnostic item : other.items()) {
    if (item.where.file.empty()) item.where.file = std::string(file);
    items_.push_back(std::move(item));
  }
}

std::string Diagnostics::to_string() const {
  std::string out;
  for (const auto& d : items_) {
    out += format(d);
    out += '\n';
  }
  return out;
}

namespace {

Diagnostics with_file(const Diagnostics& d, const std::string& file) {
  Diagnostics out;
  out.append(d, file);
  return out;
}

std::string text_of(const Diagnostics& d) {
  std::string s = d.to_string();
  if (!s.empty() && s.back() == '\n') s.pop_back();
  return s;
}

Diagnostics syntax_error(const toml::parse_error& e, const std::string& file) {
  Diagnostics d;
  Where w;
  w.file = e.source().path ? *e.source().path : file;
  w.line = static_cast<int>(e.source().begin.line);
  w.column = static_cast<int>(e.source().begin.column);
  d.error(std::move(w), std::string(e.description()));
  return d;
}

}  // namespace

DiagnosticsError::DiagnosticsError(Diagnostics diagnostics)
    : std::invalid_argument(text_of(diagnostics)), diagnostics_(std::move(diagnostics)) {}

DiagnosticsError::DiagnosticsError(Diagnostics diagnostics, const std::string& file)
    : DiagnosticsError(with_file(std::move(diagnostics), file)) {}

DiagnosticsError::DiagnosticsError(const toml::parse_error& e, const std::string& file)
    : DiagnosticsError(syntax_error(e, file)) {}

Where where_of(const toml::node* node, std::string key_path) {
  Where w;
  w.key_path = std::move(key_path);
  if (node != nullptr) {
    const auto& src = node->source();
    if (src.path) {
      w.file = *src.path;
    }
    w.line = static_cast<int>(src.begin.line);
    w.column = static_cast<int>(src.begin.column);
  }
  return w;
}

}  // namespace nccomp::formats
