#include "formats/calib/script.hpp"

#include <charconv>
#include <cmath>
#include <utility>
#include <vector>

namespace nccomp::formats::calib {

namespace {

std::vector<std::string_view> split(std::string_view line) {
  std::vector<std::string_view> words;
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && (line[i] == ' ' || line[i] == '\t' || line[i] == '\r')) {
      ++i;
    }
    std::size_t j = i;
    while (j < line.size() && line[j] != ' ' && line[j] != '\t' && line[j] != '\r') {
      ++j;
    }
    if (j > i) {
      words.push_back(line.substr(i, j - i));
    }
    i = j;
  }
  return words;
}

/// The line being parsed: refusals name its number and the offending word's column.
struct At {
  std::string_view text;
  std::size_t line;

  [[noreturn]] void refuse(std::string_view word, std::string why) const {
    throw ScriptError(line, static_cast<std::size_t>(word.data() - text.data()) + 1,
                      std::move(why));
  }
};

double number(std::string_view w, const At& at, const char* what) {
  double v = 0.0;
  const char* first = w.data();
  if (!w.empty() && w.front() == '+') {
    ++first;  // from_chars refuses a leading '+', operators write it
  }
  const auto res = std::from_chars(first, w.data() + w.size(), v);
  if (res.ec != std::errc() || res.ptr != w.data() + w.size() || !std::isfinite(v)) {
    at.refuse(w, std::string(what) + " must be a finite number, got '" + std::string(w) + "'");
  }
  return v;
}

void expect_words(const std::vector<std::string_view>& w, std::size_t lo, std::size_t hi,
                  const At& at, const char* usage) {
  if (w.size() < lo || w.size() > hi) {
    at.refuse(w.front(), std::string("usage: ") + usage);
  }
}

std::string lower(std::string_view w) {
  std::string s(w);
  for (auto& ch : s) {
    if (ch >= 'A' && ch <= 'Z') {
      ch = static_cast<char>(ch - 'A' + 'a');
    }
  }
  return s;
}

}  // namespace

ScriptError::ScriptError(std::size_t line, std::size_t column, std::string why)
    : formats::DiagnosticsError(
          [&] {
            formats::Diagnostics d;
            d.error(formats::Where{"", static_cast<int>(line), static_cast<int>(column), ""}, why);
            return d;
          }(),
          ""),
      text_("line " + std::to_string(line) +
            (column > 0 ? ", column " + std::to_string(column) : std::string()) + ": " + why) {}

const formats::Diagnostic& ScriptError::diagnostic() const noexcept {
  return diagnostics().items().front();
}

std::string ScriptError::in_file(std::string_view file) const {
  formats::Diagnostic d = diagnostic();
  d.where.file = std::string(file);
  return formats::format(d);
}

const char* script_help() noexcept {
  return "commands:\n"
         "  time <s>                 set the clock [s]\n"
         "  wait <s>                 let time pass (registers creep), one step per second\n"
         "  temperature <sensor> <degC>\n"
         "  begin                    start an initial calibration\n"
         "  touch reference|machine x|y|z +|- [lateral|axial] <trigger_mm>\n"
         "  facets lateral|end-face <chord_plus_mm> <chord_minus_mm>\n"
         "  facets-file <path> [row]  chords from a measuring device's CSV export (last row)\n"
         "  recalibrate              ask the NC for a recalibration touch cycle now\n"
         "  await <phase> [timeout_s] (with --daemon) wait until the daemon reaches <phase>\n"
         "  status | discard | help | quit\n";
}

bool parse_phase(std::string_view name, core::calib::Phase& out) noexcept {
  using core::calib::Phase;
  for (const Phase p : {Phase::kUncalibrated, Phase::kReferenceTouches, Phase::kTestGrindLateral,
                        Phase::kTestGrindEndFace, Phase::kNominalTouches, Phase::kReady}) {
    if (name == core::calib::to_string(p)) {
      out = p;
      return true;
    }
  }
  return false;
}

Command parse_line(std::string_view line, std::size_t line_no) {
  const auto hash = line.find('#');
  if (hash != std::string_view::npos) {
    line = line.substr(0, hash);
  }
  const auto w = split(line);
  const At at{line, line_no};
  if (w.empty()) {
    return CmdEmpty{};
  }
  const std::string verb = lower(w[0]);
  if (verb == "time") {
    expect_words(w, 2, 2, at, "time <s>");
    const double t = number(w[1], at, "time");
    if (t < 0.0 || t > 1e9) {
      at.refuse(w[1], "time must be in 0..1e9 s");
    }
    return CmdTime{t};
  }
  if (verb == "wait") {
    expect_words(w, 2, 2, at, "wait <s>");
    const double d = number(w[1], at, "wait");
    if (d < 0.0 || d > 7.0 * 86400.0) {
      at.refuse(w[1], "wait must be in 0..604800 s");
    }
    return CmdWait{d};
  }
  if (verb == "temperature") {
    expect_words(w, 3, 3, at, "temperature <sensor> <degC>");
    int s = -1;
    const auto res = std::from_chars(w[1].data(), w[1].data() + w[1].size(), s);
    if (res.ec != std::errc() || res.ptr != w[1].data() + w[1].size() || s < 0 || s > 255) {
      at.refuse(w[1], "sensor must be an integer 0..255, got '" + std::string(w[1]) + "'");
    }
    const double t = number(w[2], at, "temperature");
    if (t < -50.0 || t > 200.0) {
      at.refuse(w[2], "temperature must be in -50..200 degC");
    }
    return CmdTemperature{static_cast<std::uint8_t>(s), t};
  }
  if (verb == "begin") {
    expect_words(w, 1, 1, at, "begin");
    return CmdBegin{};
  }
  if (verb == "touch") {
    const char* usage = "touch reference|machine x|y|z +|- [lateral|axial] <trigger_mm>";
    expect_words(w, 5, 6, at, usage);
    CmdTouch c;
    const std::string probe = lower(w[1]);
    if (probe == "reference") {
      c.touch.probe = core::ProbeKind::kReferenceProbe;
    } else if (probe == "machine") {
      c.touch.probe = core::ProbeKind::kMachineProbe;
    } else {
      at.refuse(w[1], "probe must be 'reference' or 'machine', got '" + std::string(w[1]) + "'");
    }
    const std::string axis = lower(w[2]);
    if (axis == "x") {
      c.touch.axis = 0;
    } else if (axis == "y") {
      c.touch.axis = 1;
    } else if (axis == "z") {
      c.touch.axis = 2;
    } else {
      at.refuse(w[2], "axis must be x, y or z, got '" + std::string(w[2]) + "'");
    }
    if (w[3] == "+") {
      c.touch.direction = 1;
    } else if (w[3] == "-") {
      c.touch.direction = -1;
    } else {
      at.refuse(w[3], "direction must be + or -, got '" + std::string(w[3]) + "'");
    }
    std::size_t pos = 4;
    if (w.size() == 6) {
      const std::string variant = lower(w[4]);
      if (variant == "lateral") {
        c.touch.variant = 0;
      } else if (variant == "axial") {
        if (c.touch.axis != 0) {
          at.refuse(w[4], "only X is touched axially (along the stylus)");
        }
        c.touch.variant = 1;
      } else {
        at.refuse(w[4], "variant must be lateral or axial, got '" + std::string(w[4]) + "'");
      }
      pos = 5;
    }
    c.touch.trigger_position_mm = number(w[pos], at, "trigger position");
    if (std::fabs(c.touch.trigger_position_mm) > 1e5) {
      at.refuse(w[pos], "trigger position beyond +-100000 mm");
    }
    return c;
  }
  if (verb == "facets") {
    expect_words(w, 4, 4, at, "facets lateral|end-face <chord_plus_mm> <chord_minus_mm>");
    CmdFacets c;
    const std::string face = lower(w[1]);
    if (face == "lateral") {
      c.face = core::calib::Face::kLateral;
    } else if (face == "end-face") {
      c.face = core::calib::Face::kEndFace;
    } else {
      at.refuse(w[1], "face must be lateral or end-face, got '" + std::string(w[1]) + "'");
    }
    c.chord_plus_mm = number(w[2], at, "chord_plus_mm");
    c.chord_minus_mm = number(w[3], at, "chord_minus_mm");
    if (c.chord_plus_mm <= 0.0 || c.chord_minus_mm <= 0.0) {
      at.refuse(c.chord_plus_mm <= 0.0 ? w[2] : w[3], "chords must be positive [mm]");
    }
    return c;
  }
  if (verb == "facets-file") {
    expect_words(w, 2, 3, at, "facets-file <path> [row]");
    CmdFacetsFile c;
    c.path = std::string(w[1]);
    if (w.size() == 3) {
      std::size_t row = 0;
      const auto res = std::from_chars(w[2].data(), w[2].data() + w[2].size(), row);
      if (res.ec != std::errc() || res.ptr != w[2].data() + w[2].size() || row < 1 || row > 10000) {
        at.refuse(w[2], "row must be an integer 1..10000, got '" + std::string(w[2]) + "'");
      }
      c.row = row;
    }
    return c;
  }
  if (verb == "recalibrate") {
    expect_words(w, 1, 1, at, "recalibrate");
    return CmdRecalibrate{};
  }
  if (verb == "await") {
    expect_words(w, 2, 3, at, "await <phase> [timeout_s]");
    CmdAwait c;
    if (!parse_phase(lower(w[1]), c.phase)) {
      at.refuse(w[1],
                "phase must be uncalibrated, reference-touches, test-grind-lateral, "
                "test-grind-end-face, nominal-touches or ready, got '" +
                    std::string(w[1]) + "'");
    }
    if (w.size() == 3) {
      c.timeout_s = number(w[2], at, "timeout");
      if (c.timeout_s <= 0.0 || c.timeout_s > 86400.0) {
        at.refuse(w[2], "timeout must be in (0, 86400] s");
      }
    }
    return c;
  }
  if (verb == "status") {
    expect_words(w, 1, 1, at, "status");
    return CmdStatus{};
  }
  if (verb == "discard") {
    expect_words(w, 1, 1, at, "discard");
    return CmdDiscard{};
  }
  if (verb == "help") {
    return CmdHelp{};
  }
  if (verb == "quit" || verb == "exit") {
    return CmdQuit{};
  }
  at.refuse(w[0], "unknown command '" + std::string(w[0]) + "' (try 'help')");
}

}  // namespace nccomp::formats::calib
