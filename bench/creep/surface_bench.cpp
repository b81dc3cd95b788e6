// Surface quality of creeping wear correction (issue 3, "Measured"): a synthetic flat face and a
// curved face, and the real PHM 2010 milling wear curves, each finished while the tool wears and
// corrected by the real core with today's strategies and the estimator's (issue 22), its process
// noise configured, or learned from the two other PHM cutters (held out) and optionally adapted
// within the tool's life, with the rate prior learned from them too or not; "measured when
// needed" also with a bound held out from the two other cutters. Prints markdown tables, or with
// --json one JSON object per PHM 2010 row and strategy (one a line).
//
//   bench_creep_surface [--json] [--wear-noise UM_PER_SQRT_M] [--rate-noise UM_PER_MM_PER_SQRT_M]
//                       [--max-sigma UM] [--adapt-window MEASUREMENTS]
//                       [--sweep [--seeds N] [--min-interval-cuts CUTS]]
//                       [PHM_DIR]
// --sweep prints only the curve "measurements against RMS (second half)" of PHM c1, c4, c6
// (L = 2 passes) as JSON rows: measured every k = 5..20 cuts, and measured when needed over a
// range of bounds max_sigma_um, for three estimator strategies; each point the mean over N noise
// draws (default 1: seed 2010, the seed of every other table); --min-interval-cuts sets the
// lower limit of the interval measured when needed (default 1 cut, 108 mm).
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "bench/creep/surface_model.hpp"

namespace {

using namespace nccomp::bench::creep;

bool g_json = false;
bool g_sweep = false;

void print_header(const Scenario& sc) {
  if (g_json) return;
  std::printf("\n### %s\n\n", sc.name.c_str());
  std::printf(
      "%d passes of %.0f mm, path sample spacing Δs = %.2f mm, measured every %d passes "
      "(mid-pass), creep length L = %.0f mm, measurement noise σ = %.2f µm, %zu edge "
      "support point(s)\n\n",
      sc.passes, sc.pass_length_mm, sc.ds_mm, sc.measure_every_passes, sc.creep_length_mm,
      sc.noise_um, sc.edge_points);
  std::printf(
      "| strategy | max step along a pass [µm] | max step between passes [µm] | max jump of the "
      "correction [µm] | RMS form error [µm] | RMS, second half [µm] | max form error [µm] |\n"
      "| --- | --- | --- | --- | --- | --- | --- |\n");
}

/// Every strategy's result, in the order of strategies().
std::vector<Result> print_rows(const Scenario& sc) {
  std::vector<Result> all;
  for (const auto& st : strategies()) {
    const Result r = run(sc, st);
    all.push_back(r);
    if (g_json) continue;
    std::printf("| %s | %.4f | %.3f | %.4f | %.3f | %.3f | %.3f |\n", st.name.c_str(),
                r.max_step_along_um, r.max_step_across_um, r.max_jump_um, r.rms_um,
                r.rms_second_half_um, r.max_abs_um);
  }
  const Result& first = all.front();
  if (g_json) return all;
  std::printf(
      "\n%d measurements; measured increment between measurements h: mean %.3f µm, "
      "max %.3f µm; h·Δs/L with the max h = %.4f µm\n",
      first.measurements, first.mean_increment_um, first.max_increment_um,
      first.max_increment_um * sc.ds_mm / sc.creep_length_mm);
  return all;
}

std::vector<std::string> split(const std::string& line) {
  std::vector<std::string> out;
  std::stringstream ss(line);
  std::string f;
  while (std::getline(ss, f, ',')) {
    while (!f.empty() && (f.back() == '\r' || f.back() == ' ')) f.pop_back();
    out.push_back(f);
  }
  return out;
}

double to_double(const std::string& s, const std::string& where) {
  std::size_t used = 0;
  double v = 0.0;
  try {
    v = std::stod(s, &used);
  } catch (const std::exception&) {
    throw std::runtime_error(where + ": not a number: '" + s + "'");
  }
  if (used != s.size() || !std::isfinite(v)) {
    throw std::runtime_error(where + ": not a finite number: '" + s + "'");
  }
  return v;
}

/// VB of the rotating envelope (max over flutes) per cut, from a per-flute table.
std::vector<double> read_flutes(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path + ": cannot open");
  std::string line;
  std::getline(in, line);
  if (split(line) != std::vector<std::string>{"cut", "flute_1", "flute_2", "flute_3"}) {
    throw std::runtime_error(path + ":1: unexpected header '" + line + "'");
  }
  std::vector<double> vb;
  int lineno = 1;
  while (std::getline(in, line)) {
    ++lineno;
    if (line.empty() || line == "\r") continue;
    const auto f = split(line);
    const std::string where = path + ":" + std::to_string(lineno);
    if (f.size() != 4) throw std::runtime_error(where + ": expected 4 columns");
    if (static_cast<int>(to_double(f[0], where)) != static_cast<int>(vb.size()) + 1) {
      throw std::runtime_error(where + ": cuts must be 1, 2, 3, ...");
    }
    vb.push_back(
        std::max({to_double(f[1], where), to_double(f[2], where), to_double(f[3], where)}));
  }
  return vb;
}

std::map<std::string, std::vector<double>> read_percut(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path + ": cannot open");
  std::string line;
  std::getline(in, line);
  if (split(line) != std::vector<std::string>{"cutter", "cut", "max_wear"}) {
    throw std::runtime_error(path + ":1: unexpected header '" + line + "'");
  }
  std::map<std::string, std::vector<double>> out;
  int lineno = 1;
  while (std::getline(in, line)) {
    ++lineno;
    if (line.empty() || line == "\r") continue;
    const auto f = split(line);
    const std::string where = path + ":" + std::to_string(lineno);
    if (f.size() != 3) throw std::runtime_error(where + ": expected 3 columns");
    auto& v = out[f[0]];
    if (static_cast<int>(to_double(f[1], where)) != static_cast<int>(v.size()) + 1) {
      throw std::runtime_error(where + ": cuts must be 1, 2, 3, ... per cutter");
    }
    v.push_back(to_double(f[2], where));
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  std::string phm_dir = NCCOMP_PHM_DIR;
  // The estimator of the PHM runs: the documented defaults unless given (docs/estimation.md).
  nccomp::core::creep::EstimatorConfig est;
  // "Measured when needed": the bound on the estimate's σ (the laser's σ: measure when the
  // estimate is no better than one measurement).
  double max_sigma_um = 1.0;
  int sweep_seeds = 1;
  double min_interval_cuts = 1.0;
  for (int a = 1; a < argc; ++a) {
    const std::string arg = argv[a];
    if (arg == "--json") {
      g_json = true;
    } else if (arg == "--sweep") {
      g_json = true;
      g_sweep = true;
    } else if (arg == "--seeds" && a + 1 < argc) {
      sweep_seeds = std::max(1, std::stoi(argv[++a]));
    } else if (arg == "--min-interval-cuts" && a + 1 < argc) {
      min_interval_cuts = std::stod(argv[++a]);
    } else if (arg == "--adapt-window" && a + 1 < argc) {
      est.adapt_window_measurements = std::stod(argv[++a]);
    } else if (arg == "--wear-noise" && a + 1 < argc) {
      est.wear_noise_um_per_sqrt_m = std::stod(argv[++a]);
    } else if (arg == "--max-sigma" && a + 1 < argc) {
      max_sigma_um = std::stod(argv[++a]);
    } else if (arg == "--rate-noise" && a + 1 < argc) {
      est.rate_noise_um_per_mm_per_sqrt_m = std::stod(argv[++a]);
    } else if (arg.starts_with("-")) {
      std::fprintf(
          stderr,
          "usage: bench_creep_surface [--json] [--wear-noise X] [--rate-noise X] "
          "[--max-sigma X] [--adapt-window N] [--sweep [--seeds N] [--min-interval-cuts N]] "
          "[PHM_DIR]\n");
      return 2;
    } else {
      phm_dir = arg;
    }
  }
  if (!g_sweep && !g_json) {
    std::printf(
        "## Synthetic faces\n\nTrue wear g(s) = 8·(1 − exp(−s/300 mm)) + 0.004·s µm "
        "(break-in, then linear); on the curved face w(θ, s) = g(s)·(0.6 + 0.8·sin θ) at "
        "engagement angle θ.\n");
  }
  if (!g_sweep) {
    Scenario flat;
    flat.name = "Flat face (tool axis normal to the face, wear at the tip, Z offset)";
    flat.wear_um = [](double, double s) { return 8.0 * (1.0 - std::exp(-s / 300.0)) + 0.004 * s; };
    print_header(flat);
    print_rows(flat);

    Scenario flat_long = flat;
    flat_long.name = "Flat face, creep length = measurement interval (L = 600 mm)";
    flat_long.creep_length_mm = 600.0;
    print_header(flat_long);
    print_rows(flat_long);

    Scenario flat_exact = flat;
    flat_exact.name = "Flat face, noise-free measurement (σ = 0)";
    flat_exact.noise_um = 0.0;
    print_header(flat_exact);
    print_rows(flat_exact);

    Scenario curved = flat;
    curved.name =
        "Curved face (cylinder R 50 mm, normal ±60°, ball-end mill, 7 support points "
        "0–90°, X/Z along the normal)";
    curved.curved = true;
    curved.edge_points = 7;
    curved.wear_um = [](double theta_deg, double s) {
      const double g = 8.0 * (1.0 - std::exp(-s / 300.0)) + 0.004 * s;
      return g * (0.6 + 0.8 * std::sin(theta_deg * std::numbers::pi / 180.0));
    };
    print_header(curved);
    print_rows(curved);
  }

  // ---- PHM 2010 -------------------------------------------------------------------------
  const double gamma_deg = 10.0;
  const double tan_g = std::tan(gamma_deg * std::numbers::pi / 180.0);
  const auto percut = read_percut(phm_dir + "/phm2010_wear_percut.csv");
  std::map<std::string, std::vector<double>> vb;
  vb["c1"] = percut.at("c1");
  vb["c4"] = read_flutes(phm_dir + "/c4_wear.csv");
  vb["c6"] = read_flutes(phm_dir + "/c6_wear.csv");
  for (const char* c : {"c4", "c6"}) {
    const auto& a = vb[c];
    const auto& b = percut.at(c);
    if (a.size() != b.size()) throw std::runtime_error(std::string(c) + ": cut counts differ");
    for (std::size_t i = 0; i < a.size(); ++i) {
      if (std::fabs(a[i] - b[i]) > 1e-6) {
        throw std::runtime_error(std::string(c) + ": max over flutes differs from percut at cut " +
                                 std::to_string(i + 1));
      }
    }
  }
  if (!g_json) {
    std::printf(
        "\n## PHM 2010 milling wear (real)\n\nVB of the rotating envelope (max over the "
        "three flutes; c4/c6 from the per-flute tables, checked equal to "
        "phm2010_wear_percut.csv; c1 from that file). Radial wear = (VB − VB at cut 1)·tan γ "
        "with clearance angle γ = %.0f° (tan γ = %.4f), linear in path within a cut; one "
        "cut = one pass of 108 mm (the data are successive face-milling cuts; the model lays them "
        "side by side as raster passes); radius-wear register (one support point).\n",
        gamma_deg, tan_g);
    std::printf(
        "\nEstimator ([creep.estimator]): measurement_sigma_um = σ = 1, "
        "wear_noise_um_per_sqrt_m = %g, rate_noise_um_per_mm_per_sqrt_m = %g, "
        "initial_rate_sigma_um_per_mm = %g, gate_sigmas = %g; the noise-free rows feed the same "
        "filter the true wear.\n",
        est.wear_noise_um_per_sqrt_m, est.rate_noise_um_per_mm_per_sqrt_m,
        est.initial_rate_sigma_um_per_mm, est.gate_sigmas);
  }
  // One cut = one pass of 108 mm. The creep length follows docs/creep.md's advice for raster
  // finishing: 2 and 3 pass lengths.
  struct Row {
    std::string cutter;
    int k;
    int passes_l;
    double h_max_um;
    double bound_um;
    std::vector<Result> r;
  };
  std::vector<Row> summary;
  const auto make_scenario = [&](const char* name, int k, int passes_l) {
    const std::vector<double> v = vb[name];
    Scenario sc;
    sc.name = std::string("PHM 2010 ") + name + ", measured every " + std::to_string(k) +
              " cuts, L = " + std::to_string(passes_l) + " passes";
    sc.passes = static_cast<int>(v.size()) - 1;
    sc.pass_length_mm = 108.0;
    sc.ds_mm = 0.5;
    sc.measure_every_passes = k;
    sc.creep_length_mm = 108.0 * passes_l;
    sc.tool_registers = true;
    sc.noise_um = 1.0;
    sc.seed = 2010;
    sc.estimator = est;
    sc.max_sigma_um = max_sigma_um;
    const auto wear_of = [tan_g](const std::vector<double>& vb_c) {
      return [vb_c, tan_g](double s) {
        const double c = s / 108.0;  // cuts done since cut 1
        const auto i = std::min(static_cast<std::size_t>(c), vb_c.size() - 2);
        const double t = std::min(1.0, c - static_cast<double>(i));
        return (vb_c[i] + t * (vb_c[i + 1] - vb_c[i]) - vb_c[0]) * tan_g;
      };
    };
    const auto own = wear_of(v);
    sc.wear_um = [own](double, double s) { return own(s); };
    // The learned process noise is held out: learned from the two other cutters.
    for (const char* other : {"c1", "c4", "c6"}) {
      if (std::string(other) == name) continue;
      sc.family.push_back(wear_of(vb[other]));
      sc.family_length_mm.push_back(108.0 * static_cast<double>(vb[other].size() - 1));
    }
    return sc;
  };
  if (g_sweep) {
    // Pairs of strategies() (measured every k cuts, measured when needed). One noise draw decides
    // where a schedule's measurements fall against the noise, so each point is the mean over
    // sweep_seeds draws (seeds 2010, 2011, ...).
    const std::array<std::pair<std::size_t, std::size_t>, 5> sweep_pairs{
        {{6, 9}, {10, 12}, {13, 15}, {16, 18}, {19, 21}}};
    const auto mean_run = [&](Scenario sc, const Strategy& st, double& rms, double& meas,
                              double& step) {
      rms = meas = step = 0.0;
      for (int i = 0; i < sweep_seeds; ++i) {
        sc.seed = 2010 + static_cast<std::uint64_t>(i);
        const Result r = run(sc, st);
        rms += r.rms_second_half_um / sweep_seeds;
        meas += static_cast<double>(r.measurements) / sweep_seeds;
        step = std::max(step, r.max_step_along_um);
      }
    };
    for (const char* name : {"c1", "c4", "c6"}) {
      for (const auto& [fixed, on_request] : sweep_pairs) {
        double rms = 0.0, meas = 0.0, step = 0.0;
        for (int k = 5; k <= 20; ++k) {
          mean_run(make_scenario(name, k, 2), strategies()[fixed], rms, meas, step);
          std::printf(
              "{\"cutter\": \"%s\", \"strategy\": \"%s\", \"schedule\": \"every k cuts\", "
              "\"k\": %d, \"seeds\": %d, \"rms_second_half_um\": %.6f, \"measurements\": %.2f, "
              "\"max_step_along_pass_um\": %.6f}\n",
              name, strategies()[fixed].name.c_str(), k, sweep_seeds, rms, meas, step);
        }
        for (int b = 6; b <= 30; ++b) {
          Scenario sc = make_scenario(name, 10, 2);
          sc.max_sigma_um = 0.1 * b;
          sc.min_interval_mm = 108.0 * min_interval_cuts;
          mean_run(sc, strategies()[on_request], rms, meas, step);
          std::printf(
              "{\"cutter\": \"%s\", \"strategy\": \"%s\", \"schedule\": \"when needed\", "
              "\"max_sigma_um\": %.2f, \"seeds\": %d, \"rms_second_half_um\": %.6f, "
              "\"measurements\": %.2f, \"max_step_along_pass_um\": %.6f}\n",
              name, strategies()[fixed].name.c_str(), sc.max_sigma_um, sweep_seeds, rms, meas,
              step);
        }
      }
    }
    return 0;
  }
  const auto print_json = [](const char* name, int k, int passes_l, const std::string& strategy,
                             const Result& r, double max_sigma) {
    std::printf(
        "{\"cutter\": \"%s\", \"k\": %d, \"creep_length_passes\": %d, \"strategy\": "
        "\"%s\", \"rms_second_half_um\": %.6f, \"max_step_along_pass_um\": %.6f, "
        "\"measurements\": %d, \"refused\": %d, \"rate_noise_um_per_mm_per_sqrt_m\": "
        "%.6g, \"rate_noise_end_um_per_mm_per_sqrt_m\": %.6g, "
        "\"sigma_before_measurement_um\": %.6g, \"max_sigma_um\": %.6g, "
        "\"rate_prior_um_per_mm\": %.6g, \"rate_prior_sigma_um_per_mm\": %.6g}\n",
        name, k, passes_l, strategy.c_str(), r.rms_second_half_um, r.max_step_along_um,
        r.measurements, r.refused, r.rate_noise_um_per_mm_per_sqrt_m,
        r.rate_noise_end_um_per_mm_per_sqrt_m,
        std::isnan(r.sigma_before_measurement_um) ? -1.0 : r.sigma_before_measurement_um, max_sigma,
        r.rate_prior_um_per_mm, r.rate_prior_sigma_um_per_mm);
  };
  for (int k : {5, 10, 20}) {
    for (int passes_l : {2, 3}) {
      for (const char* name : {"c1", "c4", "c6"}) {
        const Scenario sc = make_scenario(name, k, passes_l);
        print_header(sc);
        auto all = print_rows(sc);
        const double h = all.front().max_increment_um;
        if (g_json) {
          for (std::size_t i = 0; i < all.size(); ++i) {
            print_json(name, k, passes_l, strategies()[i].name, all[i], sc.max_sigma_um);
          }
        }
        summary.push_back({name, k, passes_l, h, h * sc.ds_mm / sc.creep_length_mm, all});
      }
    }
  }
  // Measured when needed with the bound an integrator can know before the tool (held out): the
  // estimate's σ just before a measurement in the second half of the life, averaged over the two
  // other cutters' runs measured every 10 cuts with the same strategy.
  // Pairs of strategies() (measured every k cuts, measured when needed): learned q, adapted, and
  // the same with the rate prior learned from the family.
  struct HeldPair {
    const char* label;
    std::size_t fixed;
    std::size_t on_request;
  };
  const std::array<HeldPair, 4> pairs{{{"learned q", 10, 12},
                                       {"learned q, adapted", 13, 15},
                                       {"learned q and rate prior", 16, 18},
                                       {"learned q and rate prior, adapted", 19, 21}}};
  struct Held {
    std::string cutter;
    int passes_l;
    std::array<double, 4> max_sigma;
    std::array<Result, 4> r;
  };
  std::vector<Held> held;
  for (const int passes_l : {2, 3}) {
    for (const char* name : {"c1", "c4", "c6"}) {
      Held h{name, passes_l, {}, {}};
      for (std::size_t p = 0; p < pairs.size(); ++p) {
        double bound = 0.0;
        for (const auto& row : summary) {
          if (row.k != 10 || row.passes_l != passes_l || row.cutter == name) continue;
          bound += 0.5 * row.r[pairs[p].fixed].sigma_before_measurement_um;
        }
        Scenario sc = make_scenario(name, 10, passes_l);
        sc.max_sigma_um = bound;
        h.max_sigma[p] = bound;
        h.r[p] = run(sc, strategies()[pairs[p].on_request]);
        if (g_json) {
          print_json(name, 10, passes_l,
                     strategies()[pairs[p].on_request].name + ", held-out bound", h.r[p], bound);
        }
      }
      held.push_back(h);
    }
  }
  if (g_json) return 0;
  // strategies(): 0 none, 1 step, 2 creeping linear, 3 creeping cosine, 4 predictive,
  // 5 creeping + estimator, 6 predictive + estimator, 7 and 8 the same fed noise-free,
  // 9 predictive + estimator measured when needed; 10, 11, 12 the same as 6, 8, 9 with the
  // process noise learned from the two other cutters; 13, 14, 15 the same, adapted within the
  // tool's life; 16..21 the same as 10..15 with the rate prior learned from the family too.
  std::printf(
      "\n### PHM 2010 summary (step = prior art, creep = creeping linear, pred = predictive "
      "creeping)\n\n"
      "| cutter | k | L [passes] | max h [µm] | h·Δs/L [µm] | jump of the correction: step / "
      "creep / pred [µm] | step along a pass: step / creep / pred [µm] | step between passes: "
      "none / step / creep / pred [µm] | RMS, second half: step / creep / pred [µm] |\n"
      "| --- | --- | --- | --- | --- | --- | --- | --- | --- |\n");
  for (const auto& row : summary) {
    const auto& r = row.r;
    std::printf(
        "| %s | %d | %d | %.3f | %.4f | %.3f / %.4f / %.4f | %.3f / %.4f / %.4f | %.2f / %.2f "
        "/ %.2f / %.2f | %.3f / %.3f / %.3f |\n",
        row.cutter.c_str(), row.k, row.passes_l, row.h_max_um, row.bound_um, r[1].max_jump_um,
        r[2].max_jump_um, r[4].max_jump_um, r[1].max_step_along_um, r[2].max_step_along_um,
        r[4].max_step_along_um, r[0].max_step_across_um, r[1].max_step_across_um,
        r[2].max_step_across_um, r[4].max_step_across_um, r[1].rms_second_half_um,
        r[2].rms_second_half_um, r[4].rms_second_half_um);
  }
  std::printf(
      "\n### PHM 2010 with the estimator (issue 22): RMS in the second half [µm]; limit = the same "
      "strategy fed noise-free measurements\n\n"
      "| cutter | k | L [passes] | step | creep | pred | creep + est | limit | ratio | pred + "
      "est | limit | ratio | step along a pass: creep + est / pred + est [µm] | refused |\n"
      "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n");
  for (const int passes_l : {2, 3}) {
    double sum_step = 0.0, sum_ce = 0.0, sum_pe = 0.0, worst_ce = 0.0, worst_pe = 0.0;
    double along_ce = 0.0, along_pe = 0.0;
    int rows = 0;
    for (const auto& row : summary) {
      if (row.passes_l != passes_l) continue;
      const auto& r = row.r;
      const double ratio_ce = r[5].rms_second_half_um / r[7].rms_second_half_um;
      const double ratio_pe = r[6].rms_second_half_um / r[8].rms_second_half_um;
      std::printf(
          "| %s | %d | %d | %.3f | %.3f | %.3f | %.3f | %.3f | %.2f | %.3f | %.3f | %.2f | %.4f / "
          "%.4f | %d / %d |\n",
          row.cutter.c_str(), row.k, row.passes_l, r[1].rms_second_half_um, r[2].rms_second_half_um,
          r[4].rms_second_half_um, r[5].rms_second_half_um, r[7].rms_second_half_um, ratio_ce,
          r[6].rms_second_half_um, r[8].rms_second_half_um, ratio_pe, r[5].max_step_along_um,
          r[6].max_step_along_um, r[5].refused, r[6].refused);
      sum_step += r[1].rms_second_half_um;
      sum_ce += r[5].rms_second_half_um;
      sum_pe += r[6].rms_second_half_um;
      worst_ce = std::max(worst_ce, ratio_ce);
      worst_pe = std::max(worst_pe, ratio_pe);
      along_ce = std::max(along_ce, r[5].max_step_along_um);
      along_pe = std::max(along_pe, r[6].max_step_along_um);
      ++rows;
    }
    std::printf(
        "\nL = %d passes, %d rows: worst ratio to the noise-free limit creep + est %.3f, pred + "
        "est %.3f (target ≤ 1.15); mean RMS / mean RMS of step: creep + est %.3f, pred + est "
        "%.3f (target ≤ 0.7); max step along a pass creep + est %.4f, pred + est %.4f µm "
        "(target ≤ 0.02)\n",
        passes_l, rows, worst_ce, worst_pe, sum_ce / sum_step, sum_pe / sum_step, along_ce,
        along_pe);
  }
  std::printf(
      "\n### PHM 2010, measured when needed (interval basis \"uncertainty\", max_sigma_um = %g, "
      "between %.0f and %.0f mm = 1 and 20 cuts) against predictive + estimator measured every "
      "10 cuts\n\n"
      "| cutter | L [passes] | every 10 cuts: RMS [µm] / measurements | when needed: RMS [µm] / "
      "measurements | fewer measurements | step along a pass [µm] |\n"
      "| --- | --- | --- | --- | --- | --- |\n",
      max_sigma_um, 108.0, 2160.0);
  for (const auto& row : summary) {
    if (row.k != 10) continue;
    const auto& r = row.r;
    std::printf("| %s | %d | %.3f / %d | %.3f / %d | %.0f %% | %.4f |\n", row.cutter.c_str(),
                row.passes_l, r[6].rms_second_half_um, r[6].measurements, r[9].rms_second_half_um,
                r[9].measurements, 100.0 * (1.0 - double(r[9].measurements) / r[6].measurements),
                r[9].max_step_along_um);
  }
  std::printf(
      "\n### PHM 2010, process noise learned from the tool family (held out: each cutter's q from "
      "the two others, measured as it is)\n\n"
      "| cutter | k | L [passes] | learned rate noise [µm/mm/√m] | step | pred + est (config q) | "
      "pred + est, learned q | limit | ratio | step along a pass [µm] | refused |\n"
      "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n");
  for (const int passes_l : {2, 3}) {
    double sum_step = 0.0, sum_pl = 0.0, worst = 0.0, along = 0.0;
    int rows = 0;
    for (const auto& row : summary) {
      if (row.passes_l != passes_l) continue;
      const auto& r = row.r;
      const double ratio = r[10].rms_second_half_um / r[11].rms_second_half_um;
      std::printf("| %s | %d | %d | %.5f | %.3f | %.3f | %.3f | %.3f | %.2f | %.4f | %d |\n",
                  row.cutter.c_str(), row.k, row.passes_l, r[10].rate_noise_um_per_mm_per_sqrt_m,
                  r[1].rms_second_half_um, r[6].rms_second_half_um, r[10].rms_second_half_um,
                  r[11].rms_second_half_um, ratio, r[10].max_step_along_um, r[10].refused);
      sum_step += r[1].rms_second_half_um;
      sum_pl += r[10].rms_second_half_um;
      worst = std::max(worst, ratio);
      along = std::max(along, r[10].max_step_along_um);
      ++rows;
    }
    std::printf(
        "\nL = %d passes, %d rows, learned q: worst ratio to the noise-free limit %.3f (target ≤ "
        "1.15); mean RMS / mean RMS of step %.3f (target ≤ 0.7); max step along a pass %.4f µm "
        "(target ≤ 0.02)\n",
        passes_l, rows, worst, sum_pl / sum_step, along);
  }
  std::printf(
      "\n### PHM 2010, learned q, measured when needed (max_sigma_um = %g) against learned q "
      "measured every 10 cuts\n\n"
      "| cutter | L [passes] | every 10 cuts: RMS [µm] / measurements | when needed: RMS [µm] / "
      "measurements | fewer measurements | step along a pass [µm] |\n"
      "| --- | --- | --- | --- | --- | --- |\n",
      max_sigma_um);
  for (const auto& row : summary) {
    if (row.k != 10) continue;
    const auto& r = row.r;
    std::printf(
        "| %s | %d | %.3f / %d | %.3f / %d | %.0f %% | %.4f |\n", row.cutter.c_str(), row.passes_l,
        r[10].rms_second_half_um, r[10].measurements, r[12].rms_second_half_um, r[12].measurements,
        100.0 * (1.0 - double(r[12].measurements) / r[10].measurements), r[12].max_step_along_um);
  }
  std::printf(
      "\n### PHM 2010, learned q adapted within the tool's life (adapt_rate_noise, window %g, "
      "%g..%g µm/mm/√m); limit A = the same strategy fed noise-free measurements, limit B = "
      "learned q without adaptation fed noise-free measurements\n\n"
      "| cutter | k | L [passes] | rate noise start / end [µm/mm/√m] | step | learned q | "
      "learned q, adapted | limit A | ratio A | limit B | ratio B | step along a pass [µm] | "
      "refused |\n"
      "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n",
      est.adapt_window_measurements, est.min_rate_noise_um_per_mm_per_sqrt_m,
      est.max_rate_noise_um_per_mm_per_sqrt_m);
  for (const int passes_l : {2, 3}) {
    double sum_step = 0.0, sum_a = 0.0, worst_a = 0.0, worst_b = 0.0, along = 0.0;
    int rows = 0, within_a = 0, within_b = 0;
    for (const auto& row : summary) {
      if (row.passes_l != passes_l) continue;
      const auto& r = row.r;
      const double ratio_a = r[13].rms_second_half_um / r[14].rms_second_half_um;
      const double ratio_b = r[13].rms_second_half_um / r[11].rms_second_half_um;
      std::printf(
          "| %s | %d | %d | %.5f / %.5f | %.3f | %.3f | %.3f | %.3f | %.2f | %.3f | %.2f | %.4f | "
          "%d |\n",
          row.cutter.c_str(), row.k, row.passes_l, r[13].rate_noise_um_per_mm_per_sqrt_m,
          r[13].rate_noise_end_um_per_mm_per_sqrt_m, r[1].rms_second_half_um,
          r[10].rms_second_half_um, r[13].rms_second_half_um, r[14].rms_second_half_um, ratio_a,
          r[11].rms_second_half_um, ratio_b, r[13].max_step_along_um, r[13].refused);
      sum_step += r[1].rms_second_half_um;
      sum_a += r[13].rms_second_half_um;
      worst_a = std::max(worst_a, ratio_a);
      worst_b = std::max(worst_b, ratio_b);
      within_a += ratio_a <= 1.15 ? 1 : 0;
      within_b += ratio_b <= 1.15 ? 1 : 0;
      along = std::max(along, r[13].max_step_along_um);
      ++rows;
    }
    std::printf(
        "\nL = %d passes, %d rows, learned q adapted: worst ratio to limit A %.3f (%d rows within "
        "1.15), to limit B %.3f (%d rows within 1.15); mean RMS / mean RMS of step %.3f (target "
        "≤ 0.7); max step along a pass %.4f µm (target ≤ 0.02)\n",
        passes_l, rows, worst_a, within_a, worst_b, within_b, sum_a / sum_step, along);
  }
  std::printf(
      "\n### PHM 2010, measured when needed with a held-out bound (max_sigma_um = the σ before a "
      "measurement of the two other cutters measured every 10 cuts, second half) against every "
      "10 cuts\n\n"
      "| cutter | L [passes] | strategy | max_sigma_um | every 10 cuts: RMS [µm] / measurements | "
      "when needed: RMS [µm] / measurements (first 50 cuts) | fewer measurements | RMS ratio | "
      "step along a pass [µm] |\n"
      "| --- | --- | --- | --- | --- | --- | --- | --- | --- |\n");
  for (const auto& h : held) {
    const Row* every10 = nullptr;
    for (const auto& row : summary) {
      if (row.k == 10 && row.passes_l == h.passes_l && row.cutter == h.cutter) every10 = &row;
    }
    const auto line = [&](const char* what, double bound, const Result& fixed, const Result& rq) {
      std::printf("| %s | %d | %s | %.3f | %.3f / %d | %.3f / %d (%d) | %.0f %% | %.2f | %.4f |\n",
                  h.cutter.c_str(), h.passes_l, what, bound, fixed.rms_second_half_um,
                  fixed.measurements, rq.rms_second_half_um, rq.measurements,
                  rq.measurements_first_50_passes,
                  100.0 * (1.0 - double(rq.measurements) / fixed.measurements),
                  rq.rms_second_half_um / fixed.rms_second_half_um, rq.max_step_along_um);
    };
    for (std::size_t p = 0; p < pairs.size(); ++p) {
      line(pairs[p].label, h.max_sigma[p], every10->r[pairs[p].fixed], h.r[p]);
    }
  }
  std::printf(
      "\n### PHM 2010, rate prior learned from the tool family (learn_rate_prior, held out: each "
      "cutter's prior from the two others' start rates over family_prior_path_mm = %g mm); limit "
      "= the same strategy fed noise-free measurements (A), for the adapted one also learned q "
      "and rate prior without adaptation fed noise-free measurements (B)\n\n"
      "| cutter | k | L [passes] | rate prior [µm/mm] | step | learned q | learned q and prior | "
      "limit | ratio | + adapted | limit A | ratio A | ratio B | step along a pass [µm] | "
      "refused |\n"
      "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- "
      "|\n",
      est.family_prior_path_mm);
  for (const int passes_l : {2, 3}) {
    double sum_step = 0.0, sum_p = 0.0, sum_pa = 0.0, worst = 0.0, worst_a = 0.0, along = 0.0;
    int rows = 0, within = 0, within_a = 0;
    for (const auto& row : summary) {
      if (row.passes_l != passes_l) continue;
      const auto& r = row.r;
      const double ratio = r[16].rms_second_half_um / r[17].rms_second_half_um;
      const double ratio_a = r[19].rms_second_half_um / r[20].rms_second_half_um;
      const double ratio_b = r[19].rms_second_half_um / r[17].rms_second_half_um;
      std::printf(
          "| %s | %d | %d | %.4f ± %.4f | %.3f | %.3f | %.3f | %.3f | %.2f | %.3f | %.3f | %.2f | "
          "%.2f | %.4f | %d |\n",
          row.cutter.c_str(), row.k, row.passes_l, r[16].rate_prior_um_per_mm,
          r[16].rate_prior_sigma_um_per_mm, r[1].rms_second_half_um, r[10].rms_second_half_um,
          r[16].rms_second_half_um, r[17].rms_second_half_um, ratio, r[19].rms_second_half_um,
          r[20].rms_second_half_um, ratio_a, ratio_b,
          std::max(r[16].max_step_along_um, r[19].max_step_along_um),
          r[16].refused + r[19].refused);
      sum_step += r[1].rms_second_half_um;
      sum_p += r[16].rms_second_half_um;
      sum_pa += r[19].rms_second_half_um;
      worst = std::max(worst, ratio);
      worst_a = std::max(worst_a, std::max(ratio_a, ratio_b));
      within += ratio <= 1.15 ? 1 : 0;
      within_a += std::max(ratio_a, ratio_b) <= 1.15 ? 1 : 0;
      along = std::max({along, r[16].max_step_along_um, r[19].max_step_along_um});
      ++rows;
    }
    std::printf(
        "\nL = %d passes, %d rows: learned q and prior: worst ratio to its limit %.3f (%d rows "
        "within 1.15), mean RMS / mean RMS of step %.3f; adapted: worst of ratios A and B %.3f (%d "
        "rows within 1.15), mean RMS / mean RMS of step %.3f (targets ≤ 1.15, ≤ 0.7); max step "
        "along a pass %.4f µm (target ≤ 0.02)\n",
        passes_l, rows, worst, within, sum_p / sum_step, worst_a, within_a, sum_pa / sum_step,
        along);
  }
  return 0;
}
