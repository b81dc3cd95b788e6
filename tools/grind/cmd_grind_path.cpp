// `nccomp grind-path`: the wheel-midpoint trajectory that grinds a roll profile exactly (S2).
// Reads the profile (CSV or a family), computes the exact envelope and the seed's three-case
// rule, reports where they differ and what cannot be ground, verifies every trajectory with an
// independent implementation, and writes the trajectory, an NC correction table and G-code.
#include <unistd.h>
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <numbers>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "core/grind/compare.hpp"
#include "core/grind/envelope.hpp"
#include "core/grind/local_rule.hpp"
#include "core/grind/path.hpp"
#include "core/grind/profile.hpp"
#include "core/grind/verify.hpp"
#include "core/grind/verify_grid.hpp"
#include "core/grind/wheel.hpp"
#include "tools/nccomp/command.hpp"

namespace {

namespace g = nccomp::core::grind;
using nccomp::tools::CommandError;

struct Options {
  std::string profile_path;
  std::string family;
  g::FamilySpec spec;
  double phase_deg{0.0};
  double resample_mm{0.0};
  double width_mm{0.0};
  std::optional<double> arc_height_mm;
  std::optional<double> arc_radius_mm;
  std::string method{"exact"};
  int fit_degree{2};
  int fit_points{0};
  double tolerance_um{0.1};
  std::size_t verify_points{2001};
  bool skip_sample_verify{false};
  std::size_t max_regions{12};
  std::string trajectory_out;
  std::string table_out;
  double table_spacing_mm{10.0};
  std::string gcode_out;
  double chord_tol_um{1.0};
  std::string gcode_band{"above"};
  double max_move_mm{0.0};
  int decimals{4};
  double feed_mm_min{0.0};
  std::string u_axis{"X"};
  std::string z_axis{"Z"};
};

// printf-style formatting checked by the compiler (the format attribute).
__attribute__((format(printf, 1, 2))) std::string fmt(const char* f, ...) {
  char buf[512];
  va_list ap;
  va_start(ap, f);
  std::vsnprintf(buf, sizeof buf, f, ap);
  va_end(ap);
  return buf;
}

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// The profile CSV read in chunks: the file's text is never held whole (at 2·10⁷ samples it
// is about 400 MB).
g::SampledProfile read_profile_csv(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    throw CommandError(nccomp::tools::kExitInvalidInput, "cannot open profile file " + path);
  }
  g::ProfileCsvParser parser(path);
  std::vector<char> buf(std::size_t{1} << 22);
  while (in) {
    in.read(buf.data(), static_cast<std::streamsize>(buf.size()));
    const auto got = static_cast<std::size_t>(in.gcount());
    if (got > 0) {
      parser.feed(std::string_view(buf.data(), got));
    }
  }
  if (in.bad()) {
    throw CommandError(nccomp::tools::kExitInvalidInput,
                       "reading profile file " + path + " failed");
  }
  return parser.finish();
}

// An output path the command will be able to write: checked before any computation, so that a
// typo in a directory does not cost a long run (and no file is created for a failed command).
void check_writable(const std::string& path, const char* option) {
  if (path.empty()) {
    return;
  }
  namespace fs = std::filesystem;
  const fs::path p(path);
  const fs::path dir = p.has_parent_path() ? p.parent_path() : fs::path(".");
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) {
    throw std::invalid_argument(std::string(option) + " " + path + ": directory " + dir.string() +
                                " does not exist");
  }
  if (fs::is_directory(p, ec)) {
    throw std::invalid_argument(std::string(option) + " " + path + " is a directory");
  }
  const bool exists = fs::exists(p, ec);
  if (::access(exists ? p.c_str() : dir.c_str(), W_OK) != 0) {
    throw std::invalid_argument(std::string(option) + " " + path + ": not writable (" +
                                (exists ? "file" : "directory " + dir.string()) + ")");
  }
}

std::ofstream open_out(const std::string& path) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) {
    throw CommandError(nccomp::tools::kExitFailure, "cannot write " + path);
  }
  return out;
}

void print_regions(std::ostream& os, const std::vector<g::Region>& regions, std::size_t limit,
                   double tol_um) {
  if (regions.empty()) {
    os << fmt("    none above %.3g um\n", tol_um);
    return;
  }
  std::vector<g::Region> sorted = regions;
  std::sort(sorted.begin(), sorted.end(),
            [](const g::Region& a, const g::Region& b) { return a.worst_mm > b.worst_mm; });
  os << fmt("    %zu region(s) above %.3g um, largest first:\n", regions.size(), tol_um);
  for (std::size_t i = 0; i < sorted.size() && i < limit; ++i) {
    const auto& r = sorted[i];
    std::string cause;
    if (r.concave_below_radius) {
      cause += fmt(" concave radius %.0f mm < R;", r.min_concave_radius_mm);
    }
    if (r.arc_end_contact) {
      cause += " steep flank (arc end grinds);";
    }
    if (r.near_end) {
      cause += " profile end (wheel overhangs);";
    }
    if (cause.empty()) {
      cause = " -";
    }
    os << fmt("    z %10.4f .. %10.4f mm  worst %9.4f um at z %10.4f mm  cause:", r.z_from_mm,
              r.z_to_mm, r.worst_mm * 1000.0, r.z_worst_mm)
       << cause << "\n";
  }
  if (sorted.size() > limit) {
    os << fmt("    ... %zu more (--max-regions)\n", sorted.size() - limit);
  }
}

g::UniformProfile load_profile(const Options& o, std::string& description) {
  if (!o.profile_path.empty()) {
    auto samples = read_profile_csv(o.profile_path);
    const std::size_t read = samples.z_mm.size();
    auto p = g::to_uniform(std::move(samples), o.resample_mm, o.profile_path);
    description = o.profile_path + (p.size() != read ? " (resampled)" : "");
    return p;
  }
  auto spec = o.spec;
  spec.family = g::parse_family(o.family);
  spec.phase_rad = o.phase_deg * std::numbers::pi / 180.0;
  description = "family " + o.family;
  return g::generate_profile(spec);
}

// Memory: at 2·10⁷ samples every N-sized double array is 160 MB. Alive at once: the profile and
// the exact envelope, plus one more during the rule comparison (the rule's lowest pass on the
// grid, kept only for --method local). Everything else is evaluated sample by sample (the
// three-case rule, B of the envelope, the verification's paths): about 3 arrays ≈ 0.5 GB. The
// verification on every sample adds its stack while it runs: 8 bytes per wheel position
// (172 MB for the envelope's N + 2M) and the table of g (8 bytes per sample of W/2).
void run(const Options& o) {
  const auto t_start = std::chrono::steady_clock::now();
  // Options first: nothing is printed or computed for a command that cannot finish.
  if (o.method != "exact" && o.method != "local") {
    throw std::invalid_argument("--method must be exact or local, got '" + o.method + "'");
  }
  if (!(o.tolerance_um > 0.0) || !(o.chord_tol_um > 0.0) || !std::isfinite(o.tolerance_um) ||
      !std::isfinite(o.chord_tol_um)) {
    throw std::invalid_argument("--tolerance-um and --chord-tol-um must be finite and > 0");
  }
  if (o.u_axis.size() != 1 || o.z_axis.size() != 1 ||
      !std::isalpha(static_cast<unsigned char>(o.u_axis[0])) ||
      !std::isalpha(static_cast<unsigned char>(o.z_axis[0]))) {
    throw std::invalid_argument("--u-axis and --z-axis must be one letter each");
  }
  const bool gouge_free = o.gcode_band == "above";
  if (!gouge_free && o.gcode_band != "both") {
    throw std::invalid_argument("--gcode-band must be above or both, got '" + o.gcode_band + "'");
  }
  if (o.decimals < 0 || o.decimals > 9) {
    throw std::invalid_argument(fmt("--decimals must be 0..9, got %d", o.decimals));
  }
  // The chord band leaves one output unit for rounding, so the written G-code honours it.
  const double unit_mm = std::pow(10.0, -o.decimals);
  const double band_mm = o.chord_tol_um * 1e-3 - (gouge_free ? unit_mm : 0.5 * unit_mm);
  if (!(band_mm > 0.0)) {
    throw std::invalid_argument(fmt("--chord-tol-um %g is not above the rounding of %d decimals",
                                    o.chord_tol_um, o.decimals));
  }
  if (!o.table_out.empty() && (!(o.table_spacing_mm > 0.0) || !std::isfinite(o.table_spacing_mm))) {
    throw std::invalid_argument(fmt("--table-spacing-mm must be > 0, got %g", o.table_spacing_mm));
  }
  if (!(o.max_move_mm >= 0.0) || !std::isfinite(o.max_move_mm) || !(o.feed_mm_min >= 0.0) ||
      !std::isfinite(o.feed_mm_min)) {
    throw std::invalid_argument("--max-move-mm and --feed-mm-min must be finite and >= 0");
  }
  check_writable(o.trajectory_out, "--trajectory-out");
  check_writable(o.table_out, "--table-out");
  check_writable(o.gcode_out, "--gcode-out");
  const double tol_mm = o.tolerance_um * 1e-3;

  std::string description;
  const g::UniformProfile p = load_profile(o, description);
  const g::Wheel wheel = o.arc_radius_mm ? g::Wheel::from_radius(o.width_mm, *o.arc_radius_mm)
                                         : g::Wheel::from_arc_height(o.width_mm, *o.arc_height_mm);
  // Validates the fit against the profile before anything is printed.
  const g::LocalRule rule(p, g::FitSpec{o.fit_degree, o.fit_points}, wheel);
  auto& os = std::cout;
  os << fmt("profile: %s, %zu samples, z %.4f .. %.4f mm, spacing %.6g mm\n", description.c_str(),
            p.size(), p.z0_mm, p.z_last_mm(), p.spacing_mm);
  os << fmt(
      "wheel: W %.4g mm, h %.6g mm, R %s, arc end slope %.6f\n", wheel.width_mm(),
      wheel.arc_height_mm(),
      wheel.straight() ? "inf (straight grinding line)" : fmt("%.6g mm", wheel.radius_mm()).c_str(),
      wheel.end_slope());

  auto t0 = std::chrono::steady_clock::now();
  const g::GridTrajectory exact = g::exact_trajectory(p, wheel);
  const double t_exact = seconds_since(t0);
  os << fmt(
      "exact envelope: %zu points, z %.4f .. %.4f mm (wheel overhangs the ends by %.4f mm), "
      "%.3f s\n",
      exact.u_mm.size(), exact.z0_mm,
      exact.z_at(static_cast<std::ptrdiff_t>(exact.u_mm.size()) - 1), p.z0_mm - exact.z0_mm,
      t_exact);

  // Local rule against the envelope on the envelope's grid (deepest pass of the rule's path).
  std::vector<double> rule_grid;
  const auto cmp = g::compare_rule_with_envelope(rule, exact, tol_mm,
                                                 o.method == "local" ? &rule_grid : nullptr);
  os << fmt(
      "three-case rule (degree %d through %d samples): tangent %zu, front end %zu, "
      "rear end %zu samples\n",
      o.fit_degree, rule.fit_points(), cmp.tangent, cmp.front_end, cmp.rear_end);
  os << fmt(
      "three-case rule vs exact envelope (U_T): rule below envelope (gouges) by up to %.4f "
      "um, above by up to %.4f um\n",
      cmp.max_below_mm * 1000.0, cmp.max_above_mm * 1000.0);
  print_regions(os, cmp.regions, o.max_regions, o.tolerance_um);

  // What this wheel cannot grind at all: B of the exact envelope above P.
  const auto unreachable = g::unreachable_regions(rule, exact, tol_mm);
  os << "unreachable by this wheel (exact envelope grinds B > P):\n";
  print_regions(os, unreachable.regions, o.max_regions, o.tolerance_um);

  // The trajectory the outputs follow.
  const g::GridTrajectory rule_path{exact.z0_mm, exact.spacing_mm, std::move(rule_grid)};
  const g::GridTrajectory& chosen = o.method == "local" ? rule_path : exact;
  const auto poly = gouge_free
                        ? g::simplify_polyline(chosen, 0.0, band_mm, o.max_move_mm)
                        : g::simplify_polyline(chosen, 0.5 * band_mm, 0.5 * band_mm, o.max_move_mm);
  const auto rounded = g::round_vertices(poly, o.decimals, gouge_free);
  const auto chord = g::chord_error(chosen, rounded);
  const double chord_err = chord.max_mm();

  constexpr const char* kVerifyColumns =
      "    path                            max|B-P| um    RMS um  gouge um   left um   at z mm\n";
  const auto row = [&](const char* name, const g::GroundError& e) {
    os << fmt("    %-30s %11.4f %9.4f %9.4f %9.4f %9.3f", name, e.max_abs_mm * 1000.0,
              e.rms_mm * 1000.0, e.max_gouge_mm * 1000.0, e.max_left_mm * 1000.0, e.z_at_max_mm);
    if (e.unreached > 0) {
      os << fmt("  (%zu points not reached)", e.unreached);
    }
    os << "\n";
  };
  std::size_t polyline_points = 0;
  if (o.verify_points > 0) {
    t0 = std::chrono::steady_clock::now();
    const std::size_t n = p.size();
    const std::size_t want = std::max<std::size_t>(2, o.verify_points);
    const std::size_t stride = n <= want ? 1 : (n - 1 + want - 2) / (want - 1);
    std::vector<double> z_eval;
    std::vector<double> p_eval;
    for (std::size_t i = 0; i < n; i += stride) {
      z_eval.push_back(p.z_at(static_cast<std::ptrdiff_t>(i)));
      p_eval.push_back(p.u_mm[i]);
    }
    if ((n - 1) % stride != 0) {
      z_eval.push_back(p.z_last_mm());
      p_eval.push_back(p.u_mm.back());
    }
    polyline_points = z_eval.size();
    os << fmt(
        "verification (independent: what each path grinds, B(z) = min over the path of "
        "U + g(z - Z),\n  brute force over path segments at %zu points every %.6g mm):\n",
        z_eval.size(), p.spacing_mm * static_cast<double>(stride));
    os << kVerifyColumns;
    // Each path is read where it lies (no copies): T follows P, the rule sample by sample, the
    // envelope on its grid, the G-code polyline as written.
    const auto at_points = [&](const std::vector<double>& b) {
      return g::compare_ground(z_eval, b, p_eval);
    };
    row("usual practice (T follows P)",
        at_points(g::ground_by_grid_path(p.z0_mm, p.spacing_mm, p.u_mm, wheel, z_eval)));
    row("three-case rule", at_points(g::ground_by_polyline(rule, z_eval)));
    row("exact envelope", at_points(g::ground_by_grid_path(exact.z0_mm, exact.spacing_mm,
                                                           exact.u_mm, wheel, z_eval)));
    row("G-code polyline", at_points(g::ground_by_polyline(rounded, wheel, z_eval)));
    os << fmt("    (%.3f s)\n", seconds_since(t0));
  }
  if (!o.skip_sample_verify) {
    // B at every sample, streamed (no N-sized B): the wheel at each grid point of the path.
    t0 = std::chrono::steady_clock::now();
    os << fmt(
        "verification on every sample (independent: B at all %zu profile samples, the wheel at "
        "every grid\n  point of the path, lower envelope of its arcs; ",
        p.size());
    if (polyline_points > 0) {
      os << fmt("the polyline check above is at %zu points):\n", polyline_points);
    } else {
      os << "the rule's path and the G-code are\n  checked at --verify-points):\n";
    }
    os << kVerifyColumns;
    row("usual practice (T follows P)",
        g::verify_grid_every_sample({p.z0_mm, p.spacing_mm, p.u_mm}, p, wheel));
    row("exact envelope",
        g::verify_grid_every_sample({exact.z0_mm, exact.spacing_mm, exact.u_mm}, p, wheel));
    os << fmt("    (%.3f s)\n", seconds_since(t0));
  }

  os << "outputs (" << o.method << " trajectory):\n";
  if (!o.trajectory_out.empty()) {
    auto out = open_out(o.trajectory_out);
    std::size_t rows = 0;
    if (o.method == "exact") {
      out << "z_mm,u_mm\n";
      for (std::size_t i = 0; i < exact.u_mm.size(); ++i) {
        out << fmt("%.7f,%.7f\n", exact.z_at(static_cast<std::ptrdiff_t>(i)), exact.u_mm[i]);
      }
      rows = exact.u_mm.size();
    } else {
      out << "z_mm,u_mm,contact\n";  // one T per profile sample, in sample order
      for (std::size_t i = 0; i < rule.size(); ++i) {
        const auto s = rule.at(i);
        out << fmt("%.7f,%.7f,%d\n", s.point.z_mm, s.point.u_mm, static_cast<int>(s.contact));
      }
      rows = rule.size();
    }
    out.flush();
    if (!out) {
      throw CommandError(nccomp::tools::kExitFailure, "writing " + o.trajectory_out + " failed");
    }
    os << fmt("    trajectory: %s (%zu points)\n", o.trajectory_out.c_str(), rows);
  }
  if (!o.table_out.empty()) {
    const auto table = g::correction_table(chosen, p, o.table_spacing_mm);
    auto out = open_out(o.table_out);
    out << "z_mm,u_target_mm,u_wheel_mm,correction_um\n";
    for (const auto& r : table) {
      out << fmt("%.4f,%.6f,%.6f,%.3f\n", r.z_mm, r.u_target_mm, r.u_wheel_mm, r.correction_um);
    }
    out.flush();
    if (!out) {
      throw CommandError(nccomp::tools::kExitFailure, "writing " + o.table_out + " failed");
    }
    os << fmt(
        "    table: %s (%zu rows every %.6g mm; linear interpolation between rows errs by up "
        "to %.4f um)\n",
        o.table_out.c_str(), table.size(), o.table_spacing_mm,
        g::table_interpolation_error_mm(chosen, p, table) * 1000.0);
  }
  os << fmt(
      "    G-code: %zu linear moves, max chord error %.4f um (%.4f below, %.4f above the "
      "trajectory; tolerance %.4g um %s, %d decimals)",
      rounded.size() - 1, chord_err * 1000.0, chord.below_mm * 1000.0, chord.above_mm * 1000.0,
      o.chord_tol_um, gouge_free ? "above only: gouge-free" : "both sides", o.decimals);
  if (!o.gcode_out.empty()) {
    g::GcodeSpec spec;
    spec.u_axis = o.u_axis[0];
    spec.z_axis = o.z_axis[0];
    spec.decimals = o.decimals;
    spec.feed_mm_per_min = o.feed_mm_min;
    spec.header_comments = {
        "nccomp grind-path: " + o.method + " trajectory of the wheel midpoint T, " + description,
        fmt("wheel W %.4g mm, h %.6g mm; %zu moves, max chord error %.4f um", wheel.width_mm(),
            wheel.arc_height_mm(), rounded.size() - 1, chord_err * 1000.0)};
    auto out = open_out(o.gcode_out);
    out << g::gcode_blocks(rounded, spec);
    out.flush();
    if (!out) {
      throw CommandError(nccomp::tools::kExitFailure, "writing " + o.gcode_out + " failed");
    }
    os << " -> " << o.gcode_out;
  }
  os << fmt("\ntotal %.3f s\n", seconds_since(t_start));
}

void setup(CLI::App& app) {
  auto opt = std::make_shared<Options>();
  auto* sub = app.add_subcommand(
      "grind-path",
      "Wheel-midpoint trajectory that grinds a roll profile exactly (S2): exact envelope, "
      "three-case rule, verification, NC table and G-code");
  auto* in = sub->add_option_group("profile", "the target profile P (one of)");
  // No CLI::ExistingFile check: a missing file is invalid input (exit 3, "cannot open ...").
  auto* file = in->add_option("--profile", opt->profile_path, "CSV file of z_mm,u_mm samples");
  auto* fam = in->add_option("--family", opt->family,
                             "profile family: straight, convex, concave, cvc, sine, poly");
  in->require_option(1);
  sub->add_option("--resample-mm", opt->resample_mm,
                  "resample a non-uniform CSV at this spacing (mm)")
      ->needs(file);
  auto& s = opt->spec;
  auto family_opt = [&](const char* name, double& v, const char* help) {
    sub->add_option(name, v, help)->needs(fam);
  };
  family_opt("--z-from-mm", s.z_from_mm, "family: first z (mm)");
  family_opt("--z-to-mm", s.z_to_mm, "family: last z (mm)");
  family_opt("--spacing-mm", s.spacing_mm, "family: sample spacing (mm)");
  family_opt("--offset-mm", s.offset_mm, "family: constant term (mm)");
  family_opt("--slope", s.slope, "straight: du/dz");
  family_opt("--height-mm", s.height_mm, "convex/concave: crown height / valley depth (mm)");
  family_opt("--amplitude-mm", s.amplitude_mm, "sine: amplitude (mm)");
  family_opt("--wavelength-mm", s.wavelength_mm, "sine: wavelength (mm)");
  family_opt("--phase-deg", opt->phase_deg, "sine: phase (degrees)");
  sub->add_option("--coef", s.coef, "cvc (4) / poly: coefficients c0,c1,... of (z - z_ref)^k")
      ->delimiter(',')
      ->needs(fam);
  sub->add_option_function<double>(
         "--z-ref-mm",
         [opt](double v) {
           opt->spec.z_ref_mm = v;
           opt->spec.z_ref_given = true;
         },
         "family: reference z of x = z - z_ref (default: middle of the range)")
      ->needs(fam);
  sub->add_option("--wheel-width-mm", opt->width_mm, "chord width W of the grinding line (mm)")
      ->required();
  auto* h = sub->add_option("--arc-height-mm", opt->arc_height_mm,
                            "arc height h (mm), 0 <= h < W/2; 0 = straight grinding line");
  auto* r =
      sub->add_option("--arc-radius-mm", opt->arc_radius_mm, "arc radius R (mm), instead of h");
  h->excludes(r);
  sub->add_option("--method", opt->method, "trajectory for the outputs: exact or local")
      ->capture_default_str();
  sub->add_option("--fit-degree", opt->fit_degree, "three-case rule: slope fit degree")
      ->capture_default_str();
  sub->add_option("--fit-points", opt->fit_points, "three-case rule: samples per fit (0: degree+1)")
      ->capture_default_str();
  sub->add_option("--tolerance-um", opt->tolerance_um, "report deviations above this (um)")
      ->capture_default_str();
  sub->add_option("--verify-points", opt->verify_points,
                  "evaluation points of the polyline verification of every path (0: skip)")
      ->capture_default_str();
  sub->add_flag("--no-verify-samples", opt->skip_sample_verify,
                "skip the verification on every sample of the usual practice and the envelope");
  sub->add_option("--max-regions", opt->max_regions, "regions listed per report")
      ->capture_default_str();
  sub->add_option("--trajectory-out", opt->trajectory_out, "write the trajectory as CSV");
  sub->add_option("--table-out", opt->table_out, "write the NC correction table as CSV");
  sub->add_option("--table-spacing-mm", opt->table_spacing_mm, "row spacing of the table (mm)")
      ->capture_default_str();
  sub->add_option("--gcode-out", opt->gcode_out, "write the G-code block list");
  sub->add_option("--chord-tol-um", opt->chord_tol_um, "G-code: max chord error (um)")
      ->capture_default_str();
  sub->add_option("--gcode-band", opt->gcode_band,
                  "G-code: chords 'above' the trajectory only (gouge-free) or on 'both' sides")
      ->capture_default_str();
  sub->add_option("--max-move-mm", opt->max_move_mm, "G-code: longest move in Z (0: no limit)")
      ->capture_default_str();
  sub->add_option("--decimals", opt->decimals, "G-code: decimals of coordinates")
      ->capture_default_str();
  sub->add_option("--feed-mm-min", opt->feed_mm_min, "G-code: F word on the first move (0: none)");
  sub->add_option("--u-axis", opt->u_axis, "G-code: letter of the infeed axis U")
      ->capture_default_str();
  sub->add_option("--z-axis", opt->z_axis, "G-code: letter of the longitudinal axis Z")
      ->capture_default_str();
  sub->callback([opt] {
    if (!opt->arc_height_mm && !opt->arc_radius_mm) {
      throw CommandError(nccomp::tools::kExitUsage,
                         "grind-path: give --arc-height-mm or --arc-radius-mm");
    }
    try {
      run(*opt);
    } catch (const std::invalid_argument& e) {
      throw CommandError(nccomp::tools::kExitInvalidInput, e.what());
    }
  });
}

}  // namespace

NCCOMP_REGISTER_COMMAND(grind_path, setup)
