#include "tools/report/report.hpp"

#include <algorithm>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <filesystem>
#include <map>
#include <numeric>
#include <tuple>

namespace nccomp::tools::report {

namespace {

namespace fs = std::filesystem;

// printf-style formatting checked by the compiler.
__attribute__((format(printf, 1, 2))) std::string fmt(const char* f, ...) {
  char buf[1024];
  va_list ap;
  va_start(ap, f);
  std::vsnprintf(buf, sizeof buf, f, ap);
  va_end(ap);
  return buf;
}

long long as_int(double v) { return static_cast<long long>(v); }

// Row indices grouped by an integer key, each group sorted (stably) by a position column.
template <typename Key, typename KeyFn>
std::map<Key, std::vector<std::size_t>> group_rows(const CsvTable& t, KeyFn key,
                                                   std::size_t position_col) {
  std::map<Key, std::vector<std::size_t>> groups;
  for (std::size_t r = 0; r < t.rows(); ++r) groups[key(r)].push_back(r);
  for (auto& [k, rows] : groups) {
    std::stable_sort(rows.begin(), rows.end(), [&](std::size_t a, std::size_t b) {
      return t.at(a, position_col) < t.at(b, position_col);
    });
  }
  return groups;
}

FormError form_of(const CsvTable& t, const std::vector<std::size_t>& rows, std::size_t err_col,
                  std::size_t group_col, std::size_t pos_col) {
  FormError f;
  f.samples = rows.size();
  if (rows.empty()) return f;
  double sum = 0.0;
  double sum_sq = 0.0;
  for (const std::size_t r : rows) {
    const double e = t.at(r, err_col);
    sum += e;
    sum_sq += e * e;
    if (std::fabs(e) > std::fabs(f.max_abs.value_um) || f.max_abs.line == 0) {
      f.max_abs = {e, as_int(t.at(r, group_col)), t.at(r, pos_col), t.lines[r]};
    }
  }
  const auto n = static_cast<double>(rows.size());
  f.mean_um = sum / n;
  f.rms_um = std::sqrt(sum_sq / n);
  return f;
}

std::vector<std::size_t> all_rows(const CsvTable& t) {
  std::vector<std::size_t> rows(t.rows());
  std::iota(rows.begin(), rows.end(), std::size_t{0});
  return rows;
}

// Largest |Δ column| between neighbours of each group (groups already sorted by position).
template <typename Groups>
Located max_neighbour_change(const CsvTable& t, const Groups& groups, std::size_t col,
                             std::size_t group_col, std::size_t pos_col) {
  Located best;
  for (const auto& [key, rows] : groups) {
    for (std::size_t i = 1; i < rows.size(); ++i) {
      const double d = std::fabs(t.at(rows[i], col) - t.at(rows[i - 1], col));
      if (d > best.value_um || best.line == 0) {
        best = {d, as_int(t.at(rows[i], group_col)), t.at(rows[i], pos_col), t.lines[rows[i]]};
      }
    }
  }
  return best;
}

}  // namespace

SurfaceFigures analyze_surface(const CsvTable& s) {
  if (s.rows() == 0) throw ReportInputError(s.file + ": no valid rows");
  const std::size_t c_pass = s.column("pass");
  const std::size_t c_path = s.column("path_mm");
  const std::size_t c_err = s.column("error_um");
  const std::size_t c_off = s.column("offset_um");
  const std::size_t c_xyz[3] = {s.column("x_mm"), s.column("y_mm"), s.column("z_mm")};

  SurfaceFigures f;
  const auto passes = group_rows<long long>(
      s, [&](std::size_t r) { return as_int(s.at(r, c_pass)); }, c_path);
  f.passes = passes.size();
  f.form = form_of(s, all_rows(s), c_err, c_pass, c_path);
  f.max_step = max_neighbour_change(s, passes, c_err, c_pass, c_path);
  f.max_offset_step = max_neighbour_change(s, passes, c_off, c_pass, c_path);
  if (passes.size() < 2) return f;

  // The coordinate along a pass: the one that varies most within passes (X on a raster in X,
  // Z on a roll). Neighbouring passes are compared at equal values of it.
  double spread[3] = {0.0, 0.0, 0.0};
  for (const auto& [p, rows] : passes) {
    for (int a = 0; a < 3; ++a) {
      double lo = s.at(rows.front(), c_xyz[a]);
      double hi = lo;
      for (const std::size_t r : rows) {
        lo = std::min(lo, s.at(r, c_xyz[a]));
        hi = std::max(hi, s.at(r, c_xyz[a]));
      }
      spread[a] += hi - lo;
    }
  }
  const int along = static_cast<int>(std::max_element(spread, spread + 3) - spread);
  f.along = along == 0 ? "x_mm" : (along == 1 ? "y_mm" : "z_mm");
  const std::size_t c_along = c_xyz[along];

  std::vector<std::pair<double, double>> prev;  // (along, error) of the previous pass, sorted
  const std::vector<std::size_t>* prev_rows = nullptr;
  for (const auto& [p, rows] : passes) {
    if (prev_rows != nullptr) {
      const std::size_t last = prev_rows->back();
      const double jump = std::fabs(s.at(rows.front(), c_off) - s.at(last, c_off));
      if (jump > f.max_offset_jump_between_passes.value_um ||
          f.max_offset_jump_between_passes.line == 0) {
        f.max_offset_jump_between_passes = {jump, p, s.at(rows.front(), c_path),
                                            s.lines[rows.front()]};
      }
      for (const std::size_t r : rows) {
        const double a = s.at(r, c_along);
        if (prev.empty() || a < prev.front().first || a > prev.back().first) continue;
        auto hi = std::lower_bound(prev.begin(), prev.end(), std::make_pair(a, -1e300));
        double e_prev = hi->second;
        if (hi != prev.begin() && hi->first > a) {
          const auto lo = hi - 1;
          const double w = (a - lo->first) / (hi->first - lo->first);
          e_prev = lo->second + w * (hi->second - lo->second);
        }
        const double d = std::fabs(s.at(r, c_err) - e_prev);
        if (d > f.max_step_between_passes.value_um || f.max_step_between_passes.line == 0) {
          f.max_step_between_passes = {d, p, s.at(r, c_path), s.lines[r]};
        }
      }
    }
    prev.clear();
    for (const std::size_t r : rows) prev.emplace_back(s.at(r, c_along), s.at(r, c_err));
    std::stable_sort(prev.begin(), prev.end(),
                     [](const auto& x, const auto& y) { return x.first < y.first; });
    prev_rows = &rows;
  }
  return f;
}

WallFigures analyze_walls(const CsvTable& w) {
  if (w.rows() == 0) throw ReportInputError(w.file + ": no valid rows");
  const std::size_t c_part = w.column("part");
  const std::size_t c_layer = w.column("layer");
  const std::size_t c_s = w.column("s_mm");
  const std::size_t c_err = w.column("error_um");
  const std::size_t c_off = w.column("offset_um");
  using Key = std::pair<long long, long long>;
  const auto groups = group_rows<Key>(
      w,
      [&](std::size_t r) {
        return Key{as_int(w.at(r, c_part)), as_int(w.at(r, c_layer))};
      },
      c_s);
  WallFigures f;
  std::map<long long, std::vector<std::size_t>> by_part;
  std::map<long long, int> layers;
  for (const auto& [key, rows] : groups) {
    auto& v = by_part[key.first];
    v.insert(v.end(), rows.begin(), rows.end());
    layers[key.second] = 1;
  }
  f.parts = by_part.size();
  f.layers = layers.size();
  f.form = form_of(w, all_rows(w), c_err, c_part, c_s);
  f.max_step = max_neighbour_change(w, groups, c_err, c_part, c_s);
  f.max_offset_step = max_neighbour_change(w, groups, c_off, c_part, c_s);
  for (const auto& [part, rows] : by_part) {
    f.per_part.push_back({part, form_of(w, rows, c_err, c_part, c_s)});
  }
  return f;
}

std::vector<CheckpointFigures> analyze_checkpoints(const CsvTable& c) {
  const std::size_t c_part = c.column("part");
  const std::size_t c_cp = c.column("checkpoint");
  const std::size_t c_layer = c.column("layer");
  const std::size_t c_z = c.column("z_mm");
  const std::size_t c_s = c.column("s_mm");
  const std::size_t c_err = c.column("error_um");
  const std::size_t c_probe = c.column("probed_um");
  const auto groups = group_rows<long long>(
      c, [&](std::size_t r) { return as_int(c.at(r, c_cp)); }, c_part);
  std::vector<CheckpointFigures> out;
  for (const auto& [cp, rows] : groups) {
    CheckpointFigures f;
    f.checkpoint = cp;
    f.layer = as_int(c.at(rows.front(), c_layer));
    f.z_mm = c.at(rows.front(), c_z);
    f.s_mm = c.at(rows.front(), c_s);
    f.parts = rows.size();
    f.first_part = as_int(c.at(rows.front(), c_part));
    f.last_part = as_int(c.at(rows.back(), c_part));
    f.first_error_um = c.at(rows.front(), c_err);
    f.last_error_um = c.at(rows.back(), c_err);
    double sq = 0.0;
    double probe_sq = 0.0;
    for (const std::size_t r : rows) {
      const double e = c.at(r, c_err);
      f.max_abs_error_um = std::max(f.max_abs_error_um, std::fabs(e));
      sq += e * e;
      const double pe = c.at(r, c_probe) - e;
      probe_sq += pe * pe;
    }
    const auto n = static_cast<double>(rows.size());
    f.rms_error_um = std::sqrt(sq / n);
    f.probe_rms_um = std::sqrt(probe_sq / n);
    out.push_back(f);
  }
  return out;
}

std::vector<TouchGroup> analyze_touches(const CsvTable& t) {
  const std::size_t c_cycle = t.column("cycle");
  const std::size_t c_probe = t.column("probe");
  const std::size_t c_axis = t.column("axis");
  const std::size_t c_dir = t.column("direction");
  const std::size_t c_var = t.column("variant");
  const std::size_t c_pos = t.column("trigger_position_mm");
  const std::size_t c_drift = t.column("true_drift_um");
  using Key = std::tuple<long long, long long, long long, long long>;
  const auto groups = group_rows<Key>(
      t,
      [&](std::size_t r) {
        return Key{as_int(t.at(r, c_probe)), as_int(t.at(r, c_axis)), as_int(t.at(r, c_dir)),
                   as_int(t.at(r, c_var))};
      },
      c_cycle);
  std::vector<TouchGroup> out;
  for (const auto& [key, rows] : groups) {
    TouchGroup g;
    std::tie(g.probe, g.axis, g.direction, g.variant) = key;
    g.touches = rows.size();
    double lo = t.at(rows.front(), c_pos);
    double hi = lo;
    double sum = 0.0;
    double track_sq = 0.0;
    double track_neg_sq = 0.0;
    const double pos0 = t.at(rows.front(), c_pos);
    const double drift0 = t.at(rows.front(), c_drift);
    for (const std::size_t r : rows) {
      const double p = t.at(r, c_pos);
      lo = std::min(lo, p);
      hi = std::max(hi, p);
      sum += p;
      // true_drift_um is the machine's drift at that touch (C3); a touch that measures it
      // moves its trigger by the same amount, with a sign that depends on the approach: the
      // better-matching sign is taken.
      const double moved_um = (p - pos0) * 1000.0;
      const double drift_um = t.at(r, c_drift) - drift0;
      track_sq += (moved_um - drift_um) * (moved_um - drift_um);
      track_neg_sq += (moved_um + drift_um) * (moved_um + drift_um);
    }
    const auto n = static_cast<double>(rows.size());
    g.trigger_mean_mm = sum / n;
    g.trigger_spread_um = (hi - lo) * 1000.0;
    g.drift_first_um = drift0;
    g.drift_last_um = t.at(rows.back(), c_drift);
    g.tracking_rms_um = std::sqrt(std::min(track_sq, track_neg_sq) / n);
    out.push_back(g);
  }
  return out;
}

std::vector<RegisterWrites> analyze_writes(const CsvTable& w) {
  const std::size_t c_t = w.column("t_s");
  const std::size_t c_reg = w.column("register_index");
  const std::size_t c_val = w.column("value_um");
  const std::size_t c_eff = w.column("effective_t_s");
  const auto groups = group_rows<long long>(
      w, [&](std::size_t r) { return as_int(w.at(r, c_reg)); }, c_t);
  std::vector<RegisterWrites> out;
  for (const auto& [reg, rows] : groups) {
    RegisterWrites g;
    g.register_index = reg;
    g.writes = rows.size();
    g.first_value_um = w.at(rows.front(), c_val);
    g.last_value_um = w.at(rows.back(), c_val);
    g.min_value_um = g.first_value_um;
    g.max_value_um = g.first_value_um;
    double latency = 0.0;
    for (std::size_t i = 0; i < rows.size(); ++i) {
      const double v = w.at(rows[i], c_val);
      g.min_value_um = std::min(g.min_value_um, v);
      g.max_value_um = std::max(g.max_value_um, v);
      if (i > 0)
        g.max_change_um = std::max(g.max_change_um, std::fabs(v - w.at(rows[i - 1], c_val)));
      latency += w.at(rows[i], c_eff) - w.at(rows[i], c_t);
    }
    g.mean_latency_s = latency / static_cast<double>(rows.size());
    out.push_back(g);
  }
  return out;
}

Report load_report(const std::string& dir, ResultTables* tables) {
  Report r;
  r.dir = dir;
  const fs::path base(dir);
  const std::string json_file = (base / "result.json").string();
  r.info = result_info_from_json(parse_json(read_text_file(json_file), json_file), json_file);
  const auto listed = [&](const std::string& name) {
    return std::find(r.info.files.begin(), r.info.files.end(), name) != r.info.files.end();
  };
  ResultTables local;
  ResultTables& t = tables != nullptr ? *tables : local;
  // A file is read when the program needs it, when result.json lists it, or when it is there.
  auto read = [&](const char* name, const std::vector<CsvColumn>& schema, bool needed,
                  std::optional<CsvTable>& into) {
    const fs::path p = base / name;
    if (!needed && !listed(name) && !fs::exists(p)) return;
    if (!fs::exists(p)) {
      throw ReportInputError(p.string() + ": missing (program " + r.info.program +
                             (listed(name) ? ", listed in result.json)" : " needs it)"));
    }
    into = parse_csv(read_text_file(p.string()), p.string(), schema);
    r.files.push_back({name, into->rows(), into->bad_rows});
    r.bad_rows += into->bad_rows;
    r.bad_row_messages.insert(r.bad_row_messages.end(), into->bad_row_messages.begin(),
                              into->bad_row_messages.end());
  };
  const std::string& prog = r.info.program;
  read("surface.csv", surface_schema(), prog == "mould_face" || prog == "roll", t.surface);
  read("walls.csv", walls_schema(), prog == "side_wall", t.walls);
  read("checkpoints.csv", checkpoints_schema(), prog == "side_wall", t.checkpoints);
  read("touches.csv", touches_schema(), prog == "touch", t.touches);
  read("writes.csv", writes_schema(), false, t.writes);
  if (t.surface) r.surface = analyze_surface(*t.surface);
  if (t.walls) r.walls = analyze_walls(*t.walls);
  if (t.checkpoints) r.checkpoints = analyze_checkpoints(*t.checkpoints);
  if (t.touches) r.touches = analyze_touches(*t.touches);
  if (t.writes) r.writes = analyze_writes(*t.writes);
  return r;
}

// ---------------------------------------------------------------------------------------------
// Text

namespace {

std::string at_text(const Located& l, const char* group, const char* pos) {
  return fmt("%s %lld, %s %.3f mm, line %zu", group, l.group, pos, l.position_mm, l.line);
}

}  // namespace

std::string report_text(const Report& r) {
  std::string o;
  const auto& i = r.info;
  o += fmt("result   %s\n", r.dir.c_str());
  o += fmt("run      program %s over %s, %lld part(s), seed %lld, %.1f s simulated\n",
           i.program.c_str(), i.bus.c_str(), i.parts, i.seed, i.sim_time_s);
  std::string on;
  std::string off;
  for (const auto& [name, e] : i.effects) {
    std::string& list = e.enabled ? on : off;
    if (!list.empty()) list += ' ';
    list += name;
  }
  o += fmt("effects  on: %s | off: %s\n", on.empty() ? "-" : on.c_str(),
           off.empty() ? "-" : off.c_str());
  o += fmt("NC       %lld offset writes received, %lld alarm(s) seen\n", i.writes_received,
           i.alarms_seen);
  for (const auto& f : r.files) {
    o += fmt("file     %-16s %zu rows, %zu bad\n", f.file.c_str(), f.rows, f.bad_rows);
  }
  for (const auto& m : r.bad_row_messages) o += "  bad row: " + m + "\n";
  if (r.surface) {
    const auto& s = *r.surface;
    o += fmt("\nsurface: %zu passes, %zu samples\n", s.passes, s.form.samples);
    o += fmt("  form error       RMS %.3f um, max %.3f um (%s), mean %.3f um\n", s.form.rms_um,
             s.form.max_abs.value_um, at_text(s.form.max_abs, "pass", "path").c_str(),
             s.form.mean_um);
    o += fmt("  max step         %.3f um within a pass (%s)\n", s.max_step.value_um,
             at_text(s.max_step, "pass", "path").c_str());
    if (s.passes > 1) {
      o += fmt("                   %.3f um between neighbouring passes along %s (%s)\n",
               s.max_step_between_passes.value_um, s.along.c_str(),
               at_text(s.max_step_between_passes, "pass", "path").c_str());
    }
    o += fmt("  offset change    %.3f um within a pass (%s)\n", s.max_offset_step.value_um,
             at_text(s.max_offset_step, "pass", "path").c_str());
    if (s.passes > 1) {
      o += fmt("                   %.3f um from one pass to the next (%s)\n",
               s.max_offset_jump_between_passes.value_um,
               at_text(s.max_offset_jump_between_passes, "pass", "path").c_str());
    }
  }
  if (r.walls) {
    const auto& w = *r.walls;
    o += fmt("\nwalls: %zu parts, %zu layers, %zu samples\n", w.parts, w.layers, w.form.samples);
    o += fmt("  form error       RMS %.3f um, max %.3f um (%s)\n", w.form.rms_um,
             w.form.max_abs.value_um, at_text(w.form.max_abs, "part", "s").c_str());
    o += fmt("  max step         %.3f um along a layer (%s)\n", w.max_step.value_um,
             at_text(w.max_step, "part", "s").c_str());
    o += fmt("  offset change    %.3f um along a layer\n", w.max_offset_step.value_um);
    o += "  part   RMS [um]   max [um]\n";
    for (const auto& p : w.per_part) {
      o += fmt("  %4lld  %9.3f  %9.3f\n", p.part, p.form.rms_um, p.form.max_abs.value_um);
    }
  }
  if (!r.checkpoints.empty()) {
    o += "\ncheckpoints (wall error after machining [um]; probe error = probed - true)\n";
    o +=
        "  cp  layer   z [mm]   s [mm]  parts  first part  last part  max |err|   RMS  probe RMS\n";
    for (const auto& c : r.checkpoints) {
      o += fmt("  %2lld  %5lld  %7.2f  %7.2f  %5zu  %10.3f  %9.3f  %9.3f  %5.3f  %9.3f\n",
               c.checkpoint, c.layer, c.z_mm, c.s_mm, c.parts, c.first_error_um, c.last_error_um,
               c.max_abs_error_um, c.rms_error_um, c.probe_rms_um);
    }
  }
  if (!r.touches.empty()) {
    o += "\ntouches (trigger positions; tracking = RMS of trigger movement - true drift)\n";
    o += "  probe axis dir variant  n   mean [mm]   spread [um]  drift first..last [um]  "
         "tracking [um]\n";
    const char* axes = "XYZ";
    for (const auto& g : r.touches) {
      o += fmt("  %5lld %4c %3s %7lld %3zu  %10.4f  %11.3f  %8.3f .. %-8.3f  %13.3f\n", g.probe,
               g.axis >= 0 && g.axis < 3 ? axes[g.axis] : '?', g.direction > 0 ? "+" : "-",
               g.variant, g.touches, g.trigger_mean_mm, g.trigger_spread_um, g.drift_first_um,
               g.drift_last_um, g.tracking_rms_um);
    }
  }
  if (!r.writes.empty()) {
    o += "\nwrites (offsets the NC took)\n";
    o += "  register  writes   first [um]    last [um]  min..max [um]          max change [um]  "
         "latency [s]\n";
    for (const auto& w : r.writes) {
      o += fmt("  %8lld  %6zu  %11.3f  %11.3f  %9.3f .. %-9.3f  %15.3f  %11.4f\n", w.register_index,
               w.writes, w.first_value_um, w.last_value_um, w.min_value_um, w.max_value_um,
               w.max_change_um, w.mean_latency_s);
    }
  }
  return o;
}

// ---------------------------------------------------------------------------------------------
// JSON

namespace {

std::string jstr(const std::string& s) {
  std::string o = "\"";
  for (const char c : s) {
    switch (c) {
      case '"':
        o += "\\\"";
        break;
      case '\\':
        o += "\\\\";
        break;
      case '\n':
        o += "\\n";
        break;
      default:
        if (static_cast<unsigned char>(c) < 0x20) {
          o += fmt("\\u%04x", static_cast<unsigned>(static_cast<unsigned char>(c)));
        } else {
          o += c;
        }
    }
  }
  return o + "\"";
}

// Appends every part; used instead of `"literal" + std::string` temporaries, which GCC 12 at -O3
// flags with a false -Wrestrict.
template <typename... Parts>
void put(std::string& o, const Parts&... parts) {
  (o.append(parts), ...);
}

std::string jnum(double v) { return std::isfinite(v) ? fmt("%.9g", v) : "null"; }

std::string jloc(const Located& l) {
  return fmt("{\"value_um\":%s,\"group\":%lld,\"position_mm\":%s,\"line\":%zu}",
             jnum(l.value_um).c_str(), l.group, jnum(l.position_mm).c_str(), l.line);
}

std::string jform(const FormError& f) {
  return fmt("{\"samples\":%zu,\"mean_um\":%s,\"rms_um\":%s,\"max_abs_um\":%s,\"max_at\":%s}",
             f.samples, jnum(f.mean_um).c_str(), jnum(f.rms_um).c_str(),
             jnum(std::fabs(f.max_abs.value_um)).c_str(), jloc(f.max_abs).c_str());
}

}  // namespace

std::string report_json(const Report& r) {
  const auto& i = r.info;
  std::string o = "{";
  put(o, "\"format\":\"nccomp-report-1\",\"dir\":", jstr(r.dir));
  put(o, ",\"program\":", jstr(i.program), ",\"bus\":", jstr(i.bus));
  o += fmt(",\"sim_time_s\":%s,\"parts\":%lld,\"seed\":%lld", jnum(i.sim_time_s).c_str(), i.parts,
           i.seed);
  o += ",\"effects\":{";
  for (std::size_t k = 0; k < i.effects.size(); ++k) {
    put(o, k ? "," : "", jstr(i.effects[k].first), ":",
        i.effects[k].second.enabled ? "true" : "false");
  }
  o += fmt("},\"writes_received\":%lld,\"alarms_seen\":%lld", i.writes_received, i.alarms_seen);
  o += ",\"registers\":{";
  bool first = true;
  for (const auto& [idx, v] : i.registers) {
    o += fmt("%s\"%d\":%s", first ? "" : ",", idx, jnum(v).c_str());
    first = false;
  }
  o += "},\"files\":[";
  for (std::size_t k = 0; k < r.files.size(); ++k) {
    o += fmt("%s{\"file\":%s,\"rows\":%zu,\"bad_rows\":%zu}", k ? "," : "",
             jstr(r.files[k].file).c_str(), r.files[k].rows, r.files[k].bad_rows);
  }
  o += fmt("],\"bad_rows\":%zu,\"bad_row_messages\":[", r.bad_rows);
  for (std::size_t k = 0; k < r.bad_row_messages.size(); ++k) {
    put(o, k ? "," : "", jstr(r.bad_row_messages[k]));
  }
  o += "]";
  if (r.surface) {
    const auto& s = *r.surface;
    o += fmt(",\"surface\":{\"passes\":%zu,\"along\":%s,\"form\":%s", s.passes,
             jstr(s.along).c_str(), jform(s.form).c_str());
    put(o, ",\"max_step_um\":", jnum(s.max_step.value_um), ",\"max_step_at\":", jloc(s.max_step));
    put(o, ",\"max_step_between_passes_um\":", jnum(s.max_step_between_passes.value_um),
        ",\"max_step_between_passes_at\":", jloc(s.max_step_between_passes));
    put(o, ",\"max_offset_step_um\":", jnum(s.max_offset_step.value_um),
        ",\"max_offset_step_at\":", jloc(s.max_offset_step));
    put(o,
        ",\"max_offset_jump_between_passes_um\":", jnum(s.max_offset_jump_between_passes.value_um),
        "}");
  }
  if (r.walls) {
    const auto& w = *r.walls;
    o += fmt(",\"walls\":{\"parts\":%zu,\"layers\":%zu,\"form\":%s", w.parts, w.layers,
             jform(w.form).c_str());
    put(o, ",\"max_step_um\":", jnum(w.max_step.value_um), ",\"max_step_at\":", jloc(w.max_step));
    put(o, ",\"max_offset_step_um\":", jnum(w.max_offset_step.value_um), ",\"per_part\":[");
    for (std::size_t k = 0; k < w.per_part.size(); ++k) {
      o += fmt("%s{\"part\":%lld,\"form\":%s}", k ? "," : "", w.per_part[k].part,
               jform(w.per_part[k].form).c_str());
    }
    o += "]}";
  }
  if (!r.checkpoints.empty()) {
    o += ",\"checkpoints\":[";
    for (std::size_t k = 0; k < r.checkpoints.size(); ++k) {
      const auto& c = r.checkpoints[k];
      o +=
          fmt("%s{\"checkpoint\":%lld,\"layer\":%lld,\"z_mm\":%s,\"s_mm\":%s,\"parts\":%zu,"
              "\"first_part\":%lld,\"last_part\":%lld,\"first_error_um\":%s,"
              "\"last_error_um\":%s,\"max_abs_error_um\":%s,\"rms_error_um\":%s,"
              "\"probe_rms_um\":%s}",
              k ? "," : "", c.checkpoint, c.layer, jnum(c.z_mm).c_str(), jnum(c.s_mm).c_str(),
              c.parts, c.first_part, c.last_part, jnum(c.first_error_um).c_str(),
              jnum(c.last_error_um).c_str(), jnum(c.max_abs_error_um).c_str(),
              jnum(c.rms_error_um).c_str(), jnum(c.probe_rms_um).c_str());
    }
    o += "]";
  }
  if (!r.touches.empty()) {
    o += ",\"touches\":[";
    for (std::size_t k = 0; k < r.touches.size(); ++k) {
      const auto& g = r.touches[k];
      o +=
          fmt("%s{\"probe\":%lld,\"axis\":%lld,\"direction\":%lld,\"variant\":%lld,"
              "\"touches\":%zu,\"trigger_mean_mm\":%s,\"trigger_spread_um\":%s,"
              "\"drift_first_um\":%s,\"drift_last_um\":%s,\"tracking_rms_um\":%s}",
              k ? "," : "", g.probe, g.axis, g.direction, g.variant, g.touches,
              jnum(g.trigger_mean_mm).c_str(), jnum(g.trigger_spread_um).c_str(),
              jnum(g.drift_first_um).c_str(), jnum(g.drift_last_um).c_str(),
              jnum(g.tracking_rms_um).c_str());
    }
    o += "]";
  }
  o += ",\"writes\":[";
  for (std::size_t k = 0; k < r.writes.size(); ++k) {
    const auto& w = r.writes[k];
    o += fmt(
        "%s{\"register_index\":%lld,\"writes\":%zu,\"first_value_um\":%s,"
        "\"last_value_um\":%s,\"min_value_um\":%s,\"max_value_um\":%s,"
        "\"max_change_um\":%s,\"mean_latency_s\":%s}",
        k ? "," : "", w.register_index, w.writes, jnum(w.first_value_um).c_str(),
        jnum(w.last_value_um).c_str(), jnum(w.min_value_um).c_str(), jnum(w.max_value_um).c_str(),
        jnum(w.max_change_um).c_str(), jnum(w.mean_latency_s).c_str());
  }
  o += "]}\n";
  return o;
}

}  // namespace nccomp::tools::report
