#include "sim/ncsim/result.hpp"

#include <toml++/toml.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include "formats/toml/diagnostics.hpp"
#include "formats/toml/guard.hpp"
#include "formats/toml/table_reader.hpp"
#include "sim/ncsim/config.hpp"

namespace nccomp::sim::ncsim {
namespace {

std::string num(double v) {
  char b[64];
  std::snprintf(b, sizeof(b), "%.9g", v);
  return b;
}

std::string quoted(const std::string& s) {
  std::string o(1, '"');
  for (char c : s) {
    if (c == '"' || c == '\\') {
      o += '\\';
      o += c;
    } else if (static_cast<unsigned char>(c) < 0x20) {
      char b[8];
      std::snprintf(b, sizeof(b), "\\u%04x", c);
      o += b;
    } else {
      o += c;
    }
  }
  return o.append(1, '"');
}

std::string vec(const Vec3& v) {
  // Appended piecewise: GCC 12 -O3 warns (-Wrestrict, a false positive) on "[" + string.
  std::string s(1, '[');
  s.append(num(v[0])).append(1, ',').append(num(v[1])).append(1, ',').append(num(v[2]));
  return s.append(1, ']');
}

class File {
 public:
  File(const std::filesystem::path& p, const char* header) : path_(p), out_(p) {
    if (!out_) {
      throw std::runtime_error("cannot write " + p.string());
    }
    out_ << header << '\n';
  }
  std::ofstream& out() { return out_; }
  ~File() = default;
  void close() {
    out_.close();
    if (!out_) {
      throw std::runtime_error("write failed: " + path_.string());
    }
  }

 private:
  std::filesystem::path path_;
  std::ofstream out_;
};

const char* b(bool v) { return v ? "true" : "false"; }

}  // namespace

std::string effects_json(const EffectsConfig& e) {
  std::ostringstream s;
  const char* curve = e.wear.curve == WearCurve::kLinear  ? "linear"
                      : e.wear.curve == WearCurve::kPower ? "power"
                                                          : "phm2010";
  s << "{\"wear\":{\"enabled\":" << b(e.wear.enabled) << ",\"curve\":\"" << curve
    << "\",\"initial_um\":" << num(e.wear.initial_um)
    << ",\"rate_um_per_m\":" << num(e.wear.rate_um_per_m)
    << ",\"coefficient_um\":" << num(e.wear.coefficient_um)
    << ",\"exponent\":" << num(e.wear.exponent) << ",\"source\":" << quoted(e.wear.table_source)
    << "}";
  s << ",\"pushoff\":{\"enabled\":" << b(e.pushoff.enabled)
    << ",\"base_um\":" << num(e.pushoff.base_um)
    << ",\"wear_gain_per_um\":" << num(e.pushoff.wear_gain_per_um)
    << ",\"clamp_z_mm\":" << num(e.pushoff.clamp_z_mm)
    << ",\"reference_lever_mm\":" << num(e.pushoff.reference_lever_mm) << "}";
  s << ",\"hardness\":{\"enabled\":" << b(e.hardness.enabled)
    << ",\"amplitude\":" << num(e.hardness.amplitude)
    << ",\"wavelength_mm\":" << num(e.hardness.wavelength_mm)
    << ",\"per_part\":" << b(e.hardness.per_part) << "}";
  s << ",\"thermal\":{\"enabled\":" << b(e.thermal.enabled) << ",\"mode\":\""
    << (e.thermal.mode == ThermalMode::kReplay ? "replay" : "first_order")
    << "\",\"gain_um\":" << vec(e.thermal.gain_um)
    << ",\"time_constant_s\":" << num(e.thermal.time_constant_s)
    << ",\"time_scale\":" << num(e.thermal.time_scale)
    << ",\"source\":" << quoted(e.thermal.replay_source) << "}";
  s << ",\"pitch\":{\"enabled\":" << b(e.pitch.enabled)
    << ",\"amplitude_um\":" << vec(e.pitch.amplitude_um)
    << ",\"pitch_mm\":" << num(e.pitch.pitch_mm)
    << ",\"slope_um_per_m\":" << vec(e.pitch.slope_um_per_m) << "}";
  s << ",\"probe_noise\":{\"enabled\":" << b(e.probe_noise.enabled)
    << ",\"sigma_um\":" << num(e.probe_noise.sigma_um) << "}";
  s << ",\"laser_noise\":{\"enabled\":" << b(e.laser_noise.enabled)
    << ",\"sigma_um\":" << num(e.laser_noise.sigma_um) << "}";
  s << ",\"broken_tool\":{\"enabled\":" << b(e.broken_tool.enabled)
    << ",\"at_path_mm\":" << num(e.broken_tool.at_path_mm)
    << ",\"wear_jump_um\":" << num(e.broken_tool.wear_jump_um)
    << ",\"report_flag\":" << b(e.broken_tool.report_flag) << "}";
  s << ",\"probe_outlier\":{\"enabled\":" << b(e.probe_outlier.enabled)
    << ",\"part\":" << e.probe_outlier.part << ",\"checkpoint\":" << e.probe_outlier.checkpoint
    << ",\"value_um\":" << num(e.probe_outlier.value_um) << "}}";
  return s.str();
}

void write_result(const std::string& dir, const Simulation& sim, const RunInfo& info) {
  namespace fs = std::filesystem;
  const fs::path d(dir);
  std::error_code ec;
  fs::create_directories(d, ec);
  if (ec) {
    throw std::runtime_error("cannot create " + dir + ": " + ec.message());
  }
  std::vector<std::string> files;
  const Results& r = sim.results();
  if (info.program == ProgramKind::kMouldFace || info.program == ProgramKind::kRoll) {
    File f(d / "surface.csv", "pass,path_mm,x_mm,y_mm,z_mm,error_um,offset_um");
    for (const SurfaceRow& s : r.surface) {
      f.out() << s.pass << ',' << num(s.path_mm) << ',' << num(s.x_mm) << ',' << num(s.y_mm) << ','
              << num(s.z_mm) << ',' << num(s.error_um) << ',' << num(s.offset_um) << '\n';
    }
    f.close();
    files.emplace_back("surface.csv");
  }
  if (info.program == ProgramKind::kSideWall) {
    File w(d / "walls.csv", "part,layer,z_mm,s_mm,error_um,offset_um");
    for (const WallRow& s : r.walls) {
      w.out() << s.part << ',' << s.layer << ',' << num(s.z_mm) << ',' << num(s.s_mm) << ','
              << num(s.error_um) << ',' << num(s.offset_um) << '\n';
    }
    w.close();
    File c(d / "checkpoints.csv", "part,checkpoint,layer,z_mm,s_mm,error_um,probed_um");
    for (const CheckpointRow& s : r.checkpoints) {
      c.out() << s.part << ',' << s.checkpoint << ',' << s.layer << ',' << num(s.z_mm) << ','
              << num(s.s_mm) << ',' << num(s.error_um) << ',' << num(s.probed_um) << '\n';
    }
    c.close();
    files.emplace_back("walls.csv");
    files.emplace_back("checkpoints.csv");
  }
  if (info.program == ProgramKind::kMouldFace || info.program == ProgramKind::kSideWall) {
    File m(d / "measurements.csv",
           "t_s,kind,part,checkpoint,cut_path_mm,true_um,reading_um,broken");
    for (const MeasurementRow& s : r.measurements) {
      m.out() << num(s.t_s) << ',' << (s.kind == MeasurementKind::kLaser ? "laser" : "probe") << ','
              << s.part << ',' << s.checkpoint << ',' << num(s.cut_path_mm) << ',' << num(s.true_um)
              << ',' << num(s.reading_um) << ',' << (s.broken ? 1 : 0) << '\n';
    }
    m.close();
    files.emplace_back("measurements.csv");
  }
  if (info.program == ProgramKind::kTouch) {
    File t(d / "touches.csv",
           "cycle,probe,axis,direction,variant,trigger_position_mm,true_drift_um");
    for (const TouchRow& s : r.touches) {
      t.out() << s.cycle << ',' << s.probe << ',' << s.axis << ',' << s.direction << ','
              << s.variant << ',' << num(s.trigger_position_mm) << ',' << num(s.true_drift_um)
              << '\n';
    }
    t.close();
    files.emplace_back("touches.csv");
  }
  {
    File w(d / "writes.csv", "t_s,register_index,value_um,effective_t_s");
    for (const WriteRow& s : sim.registers().log()) {
      w.out() << num(s.t_s) << ',' << s.register_index << ',' << num(s.value_um) << ','
              << num(s.effective_t_s) << '\n';
    }
    w.close();
    files.emplace_back("writes.csv");
  }
  std::ostringstream j;
  j << "{\"format\":\"ncsim-result-1\",\"program\":\"" << program_name(info.program)
    << "\",\"bus\":\"" << bus_name(info.bus) << "\",\"sim_time_s\":" << num(sim.time_s())
    << ",\"parts\":" << sim.config().parts << ",\"seed\":" << sim.config().seed
    << ",\"effects\":" << effects_json(sim.config().effects)
    << ",\"writes_received\":" << sim.registers().log().size()
    << ",\"writes_refused\":" << sim.registers().refused() + info.refused_on_bus
    << ",\"registers\":{";
  bool first = true;
  for (const auto& [index, value] : sim.registers().last_values()) {
    j << (first ? "" : ",") << '"' << index << "\":" << num(value);
    first = false;
  }
  j << "},\"alarms_seen\":" << sim.alarms_seen() << ",\"alarms\":[";
  for (std::size_t i = 0; i < r.alarms.size(); ++i) {
    j << (i == 0 ? "" : ",") << "{\"t_s\":" << num(r.alarms[i].t_s)
      << ",\"register\":" << r.alarms[i].register_index << ",\"value\":" << num(r.alarms[i].value)
      << '}';
  }
  j << "]";
  const EndState end = sim.end_state();
  if (end.valid) {
    j << ",\"first_part\":" << sim.config().first_part
      << ",\"end\":{\"next_part\":" << end.next_part
      << ",\"tool_cut_path_mm\":" << num(end.tool_cut_path_mm) << '}';
    // What `ncsim --continue DIR` reads.
    std::ofstream e(d / "end_state.toml");
    e << "# Where this ncsim run left the machine; `ncsim --continue " << dir
      << "` starts the next run here.\n[ncsim]\n# The next part's number.\nfirst_part = "
      << end.next_part << "\n# Cut path of the tool in the spindle [mm] (its wear continues).\n"
      << "tool_cut_path_mm = " << std::fixed << end.tool_cut_path_mm << '\n';
    // The NC keeps its offset registers: the continued run starts with them in force.
    std::string indices;
    std::string values;
    for (const auto& [index, value] : sim.registers().held_values()) {
      indices += indices.empty() ? "" : ", ";
      indices += std::to_string(index);
      values += values.empty() ? "" : ", ";
      values += num(value);
    }
    e << "# Offset registers the NC held at the end (logical index, value [um]).\n"
      << "initial_register_indices = [" << indices << "]\ninitial_registers_um = [" << values
      << "]\n";
    e.close();
    if (!e) {
      throw std::runtime_error("write failed: " + (d / "end_state.toml").string());
    }
  }
  j << ",\"files\":[";
  for (std::size_t i = 0; i < files.size(); ++i) {
    j << (i == 0 ? "" : ",") << quoted(files[i]);
  }
  j << "]}\n";
  std::ofstream out(d / "result.json");
  out << j.str();
  out.close();
  if (!out) {
    throw std::runtime_error("write failed: " + (d / "result.json").string());
  }
}

std::vector<std::string> continuation_overrides(const std::string& dir) {
  const std::string path = (std::filesystem::path(dir) / "end_state.toml").string();
  toml::table t;
  try {
    t = formats::parse_toml_file(path);
  } catch (const toml::parse_error& e) {
    formats::Diagnostics diag;
    diag.error(formats::Where{path, static_cast<int>(e.source().begin.line),
                              static_cast<int>(e.source().begin.column), ""},
               std::string(e.description()) +
                   " (--continue needs the end_state.toml of a finished mould_face "
                   "or side_wall run)");
    throw formats::DiagnosticsError(std::move(diag), path);
  }
  formats::Diagnostics diag;
  std::vector<std::string> out;
  {
    formats::TableReader top(t, "", diag);
    if (const toml::table* n = top.table("ncsim")) {
      formats::TableReader r(*n, "ncsim", diag);
      if (n->contains("first_part")) {
        out.push_back("ncsim.first_part=" + std::to_string(r.integer("first_part", 1, 1, 1000000)));
      }
      if (n->contains("tool_cut_path_mm")) {
        char b[64];
        std::snprintf(b, sizeof(b), "%.17g", r.number("tool_cut_path_mm", 0.0, 0.0, 1e9));
        // Always a float literal for the TOML override.
        std::string val = b;
        if (val.find_first_of(".eEn") == std::string::npos) {
          val += ".0";
        }
        out.push_back("ncsim.tool_cut_path_mm=" + val);
      }
      if (n->contains("initial_register_indices") || n->contains("initial_registers_um")) {
        std::string indices;
        for (const std::int64_t i : r.integer_list("initial_register_indices", 0, 65535)) {
          indices += indices.empty() ? "" : ",";
          indices += std::to_string(i);
        }
        std::string values;
        for (const double v : r.number_list("initial_registers_um", -1e6, 1e6)) {
          char b[64];
          std::snprintf(b, sizeof(b), "%.17g", v);
          values += values.empty() ? "" : ",";
          values += b;
        }
        out.push_back("ncsim.initial_register_indices=[" + indices + "]");
        out.push_back("ncsim.initial_registers_um=[" + values + "]");
      }
    } else if (!t.contains("ncsim")) {
      top.error("ncsim", "missing [ncsim] table");
    }
  }
  if (!diag.ok()) {
    throw formats::DiagnosticsError(std::move(diag), path);
  }
  return out;
}

}  // namespace nccomp::sim::ncsim
