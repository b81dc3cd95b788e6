// A small reader of the SVG that tools/plot writes, for tests: its elements and attributes, and
// the box each one covers. Text is measured as 0.6 × font size per character (the same estimate
// the library lays out with; sans-serif digits and lower-case letters are narrower), from the
// baseline up one font size and down a quarter of one for descenders.
#pragma once

#include <map>
#include <optional>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

namespace nccomp::test::svg {

struct Element {
  std::string tag;
  std::map<std::string, std::string> attr;
  std::string text;  // of <text>, entities decoded
  [[nodiscard]] double num(const std::string& a, double fallback = 0.0) const {
    const auto it = attr.find(a);
    return it == attr.end() ? fallback : std::stod(it->second);
  }
  [[nodiscard]] std::string get(const std::string& a) const {
    const auto it = attr.find(a);
    return it == attr.end() ? std::string() : it->second;
  }
};

inline std::string decode(std::string s) {
  const std::pair<const char*, const char*> ents[] = {
      {"&lt;", "<"}, {"&gt;", ">"}, {"&quot;", "\""}, {"&amp;", "&"}};
  for (const auto& [from, to] : ents) {
    for (auto p = s.find(from); p != std::string::npos; p = s.find(from, p + 1)) {
      s.replace(p, std::string(from).size(), to);
    }
  }
  return s;
}

/// Every element (opening or self-closing tag), in document order. A scan, not std::regex:
/// libstdc++'s regex recurses once per character of a repeat, and a long path's `d` overflowed
/// the stack in the ASan build at -O1.
inline std::vector<Element> parse(const std::string& svg) {
  std::vector<Element> out;
  const std::size_t n = svg.size();
  auto space = [](char c) { return c == ' ' || c == '\t' || c == '\n' || c == '\r'; };
  auto name_char = [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == ':' ||
           c == '-';
  };
  for (std::size_t i = svg.find('<'); i != std::string::npos; i = svg.find('<', i + 1)) {
    std::size_t p = i + 1;
    while (p < n && svg[p] >= 'a' && svg[p] <= 'z') ++p;
    if (p == i + 1) continue;
    Element e;
    e.tag = svg.substr(i + 1, p - i - 1);
    bool closed = false;
    bool self_closing = false;
    while (p < n) {
      std::size_t q = p;
      while (q < n && space(svg[q])) ++q;
      if (q < n && svg[q] == '>') {
        closed = true;
        p = q + 1;
        break;
      }
      if (q + 1 < n && svg[q] == '/' && svg[q + 1] == '>') {
        closed = self_closing = true;
        p = q + 2;
        break;
      }
      std::size_t k = q;
      while (k < n && name_char(svg[k])) ++k;
      if (q == p || k == q || k + 1 >= n || svg[k] != '=' || svg[k + 1] != '"') break;
      const std::size_t value_end = svg.find('"', k + 2);
      if (value_end == std::string::npos) break;
      e.attr[svg.substr(q, k - q)] = svg.substr(k + 2, value_end - k - 2);
      p = value_end + 1;
    }
    if (!closed) continue;
    if (e.tag == "text" && !self_closing) {
      e.text = decode(svg.substr(p, svg.find("</text>", p) - p));
    }
    out.push_back(std::move(e));
  }
  return out;
}

struct Box {
  double x0, y0, x1, y1;
  [[nodiscard]] bool intersects(const Box& o) const {
    return x0 < o.x1 && o.x0 < x1 && y0 < o.y1 && o.y0 < y1;
  }
  [[nodiscard]] bool inside(const Box& o) const {
    return x0 >= o.x0 && x1 <= o.x1 && y0 >= o.y0 && y1 <= o.y1;
  }
};

inline double chars(const std::string& s) {
  double n = 0;
  for (char c : s) n += (static_cast<unsigned char>(c) & 0xC0U) != 0x80U ? 1 : 0;
  return n;
}

/// The box of a text, a shape or a polyline (nullopt for anything else).
inline std::optional<Box> box(const Element& e, double default_font = 12.0) {
  if (e.tag == "text") {
    const double fs = e.num("font-size", default_font);
    const double w = 0.6 * fs * chars(e.text);
    const std::string anchor = e.get("text-anchor");
    const double before = anchor == "middle" ? w / 2 : anchor == "end" ? w : 0.0;
    const std::string tr = e.get("transform");
    if (tr.empty()) {
      const double x = e.num("x");
      const double y = e.num("y");
      return Box{x - before, y - fs, x - before + w, y + 0.25 * fs};
    }
    std::smatch m;
    static const std::regex rot(R"(translate\(([-0-9.]+),([-0-9.]+)\) rotate\((-?90)\))");
    if (!std::regex_match(tr, m, rot)) return std::nullopt;
    const double x = std::stod(m[1]);
    const double y = std::stod(m[2]);
    if (m[3] == "-90") return Box{x - fs, y - w + before, x + 0.25 * fs, y + before};
    return Box{x - 0.25 * fs, y - before, x + fs, y - before + w};
  }
  if (e.tag == "rect") {
    const double x = e.num("x");
    const double y = e.num("y");
    return Box{x, y, x + e.num("width"), y + e.num("height")};
  }
  if (e.tag == "line") {
    return Box{std::min(e.num("x1"), e.num("x2")), std::min(e.num("y1"), e.num("y2")),
               std::max(e.num("x1"), e.num("x2")), std::max(e.num("y1"), e.num("y2"))};
  }
  if (e.tag == "circle") {
    const double r = e.num("r");
    return Box{e.num("cx") - r, e.num("cy") - r, e.num("cx") + r, e.num("cy") + r};
  }
  if (e.tag == "polyline") {
    std::istringstream in(e.get("points"));
    Box b{1e300, 1e300, -1e300, -1e300};
    double x = 0;
    double y = 0;
    char comma = 0;
    while (in >> x >> comma >> y) {
      b = Box{std::min(b.x0, x), std::min(b.y0, y), std::max(b.x1, x), std::max(b.y1, y)};
    }
    return b;
  }
  return std::nullopt;
}

/// The root's viewBox as a box.
inline std::optional<Box> view_box(const std::vector<Element>& doc) {
  if (doc.empty() || doc[0].tag != "svg" || doc[0].get("viewBox").empty()) return std::nullopt;
  std::istringstream in(doc[0].get("viewBox"));
  double x = 0;
  double y = 0;
  double w = 0;
  double h = 0;
  in >> x >> y >> w >> h;
  return Box{x, y, x + w, y + h};
}

/// Texts whose class attribute is `cls`.
inline std::vector<const Element*> texts(const std::vector<Element>& doc, const std::string& cls) {
  std::vector<const Element*> out;
  for (const auto& e : doc) {
    if (e.tag == "text" && e.get("class") == cls) out.push_back(&e);
  }
  return out;
}

}  // namespace nccomp::test::svg
