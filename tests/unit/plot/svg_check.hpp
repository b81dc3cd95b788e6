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

/// Every element (opening or self-closing tag), in document order.
inline std::vector<Element> parse(const std::string& svg) {
  std::vector<Element> out;
  static const std::regex tag(R"(<([a-z]+)((?:\s+[A-Za-z0-9:-]+="[^"]*")*)\s*(/?)>)");
  static const std::regex attr(R"re(([A-Za-z0-9:-]+)="([^"]*)")re");
  for (auto it = std::sregex_iterator(svg.begin(), svg.end(), tag); it != std::sregex_iterator();
       ++it) {
    Element e;
    e.tag = (*it)[1];
    const std::string attrs = (*it)[2];
    for (auto a = std::sregex_iterator(attrs.begin(), attrs.end(), attr);
         a != std::sregex_iterator(); ++a) {
      e.attr[(*a)[1]] = (*a)[2];
    }
    if (e.tag == "text" && (*it)[3].length() == 0) {
      const auto start = static_cast<std::size_t>(it->position() + it->length());
      e.text = decode(svg.substr(start, svg.find("</text>", start) - start));
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
