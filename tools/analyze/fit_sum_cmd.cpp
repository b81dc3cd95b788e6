// `nccomp fit-sum --log LOG.csv [--map MAP.toml] --input COL=SENSOR ... [--lag COL:TAU_S=SENSOR ...]
// --sensor N [--before TIME_S] [--kind KIND] [--point P]`: fits the log's measured deviation (measured_um +
// applied_um, as `nccomp analyze` reads it) as one shrunk (ridge) linear model of many columns
// and first-order lags of them (core/model/ridge.hpp: the weight λ chosen by a rolling-origin
// error on the rows), and prints the nccompd tables that compute it as a sensor: the
// [[input_lags]] of the lagged columns and one [[input_sums]] (docs/calibration.md, "A drift
// model of many sensors, per slot").
#include <cmath>
#include <cstdio>
#include <iostream>
#include <memory>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "core/engine/input_lag.hpp"
#include "core/engine/input_sum.hpp"
#include "core/model/analysis.hpp"
#include "core/model/ridge.hpp"
#include "formats/model/model_io.hpp"
#include "formats/toml/diagnostics.hpp"
#include "tools/analyze/fleet.hpp"
#include "tools/nccomp/command.hpp"

namespace {

namespace cm = nccomp::core::model;
namespace io = nccomp::formats::model_io;
using nccomp::tools::CommandError;
using nccomp::tools::kExitInvalidInput;
using nccomp::tools::kExitUsage;

struct Options {
  std::vector<std::string> logs;
  std::string map;
  std::vector<std::string> inputs;  // COL=SENSOR
  std::vector<std::string> lags;    // COL:TAU_S=SENSOR
  std::vector<std::string> sources;  // COL=SENSOR: read only as the input of lags
  int sensor{-1};
  double before_s{std::nan("")};
  std::string kind;
  std::vector<double> points;
  std::vector<double> lambdas{1e-4, 1e-3, 1e-2, 1e-1, 1.0};
  int blocks{4};
};

struct Input {
  std::string column;
  double tau_s{0.0};  // 0: the column itself
  int sensor{-1};
  int input_sensor{-1};  // a lag's: the column's own sensor (from --input)
};

int parse_sensor(const std::string& text, const std::string& what) {
  std::size_t used = 0;
  long v = -1;
  try {
    v = std::stol(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != text.size() || v < 0 || v > 255) {
    throw CommandError(kExitUsage, what + ": the sensor must be a number 0..255, got '" + text + "'");
  }
  return static_cast<int>(v);
}

// COL=SENSOR, or with_tau: COL:TAU_S=SENSOR.
Input parse_input(const std::string& arg, bool with_tau) {
  const std::string what = std::string(with_tau ? "--lag " : "--input ") + arg;
  const auto eq = arg.rfind('=');
  if (eq == std::string::npos || eq == 0) {
    throw CommandError(kExitUsage, what + ": expected " +
                                       (with_tau ? "COLUMN:TAU_S=SENSOR" : "COLUMN=SENSOR"));
  }
  Input in;
  in.sensor = parse_sensor(arg.substr(eq + 1), what);
  in.column = arg.substr(0, eq);
  if (with_tau) {
    const auto colon = in.column.rfind(':');
    std::size_t used = 0;
    double tau = 0.0;
    try {
      tau = std::stod(in.column.substr(colon == std::string::npos ? 0 : colon + 1), &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (colon == std::string::npos || colon == 0 ||
        used != in.column.size() - colon - 1 || !(tau > 0.0) || !std::isfinite(tau)) {
      throw CommandError(kExitUsage, what + ": expected COLUMN:TAU_S=SENSOR with TAU_S > 0");
    }
    in.tau_s = tau;
    in.column.resize(colon);
  }
  return in;
}

std::string number(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.9g", v);
  return buf;
}

void run(const Options& opt) {
  if (opt.inputs.empty()) throw CommandError(kExitUsage, "give at least one --input");
  if (opt.blocks < 2) throw CommandError(kExitUsage, "--blocks must be at least 2");
  std::vector<Input> inputs;
  std::set<int> sensors{opt.sensor};
  const auto claim = [&sensors](const Input& in, const std::string& what) {
    if (!sensors.insert(in.sensor).second) {
      throw CommandError(kExitUsage, what + ": sensor " + std::to_string(in.sensor) +
                                         " is used twice (or is the --sensor of the sum)");
    }
  };
  for (const auto& a : opt.inputs) {
    inputs.push_back(parse_input(a, false));
    claim(inputs.back(), "--input " + a);
  }
  const std::size_t direct = inputs.size();
  std::vector<Input> sources;
  for (const auto& a : opt.sources) {
    sources.push_back(parse_input(a, false));
    for (const auto& in : inputs) {
      if (in.column == sources.back().column) {
        throw CommandError(kExitUsage, "--source " + a + ": " + in.column + " is an --input already");
      }
    }
    claim(sources.back(), "--source " + a);
  }
  for (const auto& a : opt.lags) {
    Input in = parse_input(a, true);
    for (std::size_t i = 0; i < direct; ++i) {
      if (inputs[i].column == in.column) in.input_sensor = inputs[i].sensor;
    }
    for (const auto& src : sources) {
      if (src.column == in.column) in.input_sensor = src.sensor;
    }
    if (in.input_sensor < 0) {
      throw CommandError(kExitUsage, "--lag " + a + ": the column " + in.column +
                                         " needs an --input or --source (the sensor the lag reads)");
    }
    claim(in, "--lag " + a);
    inputs.push_back(in);
  }

  if (inputs.size() > nccomp::core::engine::kMaxSumInputs) {
    throw CommandError(kExitUsage, std::to_string(inputs.size()) +
                                       " inputs and lags: an [[input_sums]] takes at most " +
                                       std::to_string(nccomp::core::engine::kMaxSumInputs));
  }
  if (inputs.size() - direct > nccomp::core::engine::kMaxInputLags) {
    throw CommandError(kExitUsage, std::to_string(inputs.size() - direct) +
                                       " lags: nccompd computes at most " +
                                       std::to_string(nccomp::core::engine::kMaxInputLags));
  }
  cm::Dataset data;
  for (std::size_t i = 0; i < direct; ++i) {
    if (cm::column_index(inputs[i].column, {}) < 0) data.extra_columns.push_back(inputs[i].column);
  }
  for (const auto& src : sources) {
    if (cm::column_index(src.column, {}) < 0) data.extra_columns.push_back(src.column);
  }
  try {
    // The logs as `nccomp analyze` takes them: a directory of nccompd's logs stands for its
    // logs with their rotated files, oldest first (one machine's); with --map, a directory
    // stands for its *.csv files in name order.
    std::vector<std::string> files;
    io::Mapping mapping;
    if (opt.map.empty()) {
      const auto machines = nccomp::tools::analyze::group_logs(opt.logs);
      if (machines.size() > 1) {
        std::string names;
        for (const auto& m : machines) names += (names.empty() ? "" : ", ") + m.machine;
        throw CommandError(kExitInvalidInput, "the logs are of " +
                                                  std::to_string(machines.size()) +
                                                  " machines (" + names +
                                                  "): fit-sum fits one machine's log");
      }
      files = machines.empty() ? opt.logs : machines[0].files;
    } else {
      mapping = io::read_mapping_file(opt.map);
      for (const auto& log : opt.logs) {
        for (auto& f : nccomp::tools::analyze::foreign_log_files(log)) files.push_back(std::move(f));
      }
    }
    for (const auto& f : files) io::read_log_file(f, mapping, data);
  } catch (const nccomp::formats::DiagnosticsError& e) {
    throw CommandError(kExitInvalidInput, e.what());
  } catch (const std::invalid_argument& e) {
    throw CommandError(kExitInvalidInput, e.what());
  }
  const std::size_t n = data.rows();
  std::vector<const std::vector<double>*> column(inputs.size());
  for (std::size_t j = 0; j < inputs.size(); ++j) {
    const int c = cm::column_index(inputs[j].column, data.extra_columns);
    if (c < 0 || data.column(c).size() != n) {
      throw CommandError(kExitInvalidInput, "column " + inputs[j].column + " is not in the log" +
                                                (opt.map.empty() ? "" : " (or not mapped)"));
    }
    column[j] = &data.column(c);
  }
  const auto& time = data.column(static_cast<int>(cm::Column::kTime));
  const auto& kinds = data.column(static_cast<int>(cm::Column::kKind));
  const int kind = opt.kind.empty() ? -1 : io::kind_from_name(opt.kind);
  if (!opt.kind.empty() && kind < 0) {
    throw CommandError(kExitUsage, "--kind " + opt.kind + ": one of tool_wear, contour, calib");
  }
  // Every row's inputs, the lags advanced over time_s as nccompd does (the input held since the
  // previous row; started at the column's first value, again where time goes back: a new file).
  std::vector<std::vector<double>> x(n, std::vector<double>(inputs.size()));
  std::vector<double> lag(inputs.size(), std::nan(""));
  std::vector<double> held(inputs.size(), std::nan(""));
  for (std::size_t i = 0; i < n; ++i) {
    const double t = time.size() == n ? time[i] : std::nan("");
    const bool restart = i == 0 || !std::isfinite(t) || !std::isfinite(time[i - 1]) ||
                         t < time[i - 1];
    for (std::size_t j = 0; j < inputs.size(); ++j) {
      const double v = (*column[j])[i];
      if (inputs[j].tau_s > 0.0) {
        if (restart || !std::isfinite(lag[j])) {
          lag[j] = v;
        } else if (std::isfinite(held[j])) {
          lag[j] = nccomp::core::engine::lag_step(lag[j], held[j], t - time[i - 1], inputs[j].tau_s);
        }
        if (std::isfinite(v)) held[j] = v;
        x[i][j] = lag[j];
      } else {
        x[i][j] = v;
      }
    }
  }
  std::vector<std::size_t> rows;
  std::size_t skipped = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (kind >= 0 && !(kinds.size() == n && std::isfinite(kinds[i]) &&
                       static_cast<int>(kinds[i]) == kind)) {
      continue;
    }
    if (!opt.points.empty()) {
      const auto& point = data.column(static_cast<int>(cm::Column::kPoint));
      bool match = false;
      for (const double p : opt.points) {
        match = match || (point.size() == n && std::isfinite(point[i]) &&
                          std::fabs(point[i] - p) < 0.5);
      }
      if (!match) continue;
    }
    if (std::isfinite(opt.before_s) && !(time.size() == n && time[i] < opt.before_s)) continue;
    bool ok = std::isfinite(data.target_um[i]);
    for (const double v : x[i]) ok = ok && std::isfinite(v);
    if (ok) {
      rows.push_back(i);
    } else {
      ++skipped;
    }
  }
  if (rows.size() < 2 * static_cast<std::size_t>(opt.blocks)) {
    throw CommandError(kExitInvalidInput,
                       std::to_string(rows.size()) + " rows with every input and a measured value (" +
                           std::to_string(skipped) + " with an empty cell): at least " +
                           std::to_string(2 * opt.blocks) + " needed");
  }
  Eigen::MatrixXd xm(static_cast<Eigen::Index>(rows.size()), static_cast<Eigen::Index>(inputs.size()));
  Eigen::VectorXd y(static_cast<Eigen::Index>(rows.size()));
  for (std::size_t r = 0; r < rows.size(); ++r) {
    for (std::size_t j = 0; j < inputs.size(); ++j) {
      xm(static_cast<Eigen::Index>(r), static_cast<Eigen::Index>(j)) = x[rows[r]][j];
    }
    y(static_cast<Eigen::Index>(r)) = data.target_um[rows[r]];
  }
  cm::RidgeFit fit;
  try {
    fit = cm::fit_ridge_rolling(xm, y, opt.lambdas, static_cast<std::size_t>(opt.blocks));
  } catch (const std::invalid_argument& e) {
    throw CommandError(kExitInvalidInput, e.what());
  }
  double ss = 0.0;
  for (std::size_t r = 0; r < rows.size(); ++r) {
    const double e = data.target_um[rows[r]] - fit.predict(x[rows[r]]);
    ss += e * e;
  }
  for (const double w : fit.weight) {
    if (!std::isfinite(w)) throw CommandError(kExitInvalidInput, "the fit gave a non-finite weight");
  }
  std::ostringstream out;
  out << "# nccomp fit-sum: a ridge fit of the measured deviation [um] on " << rows.size()
      << " rows";
  if (skipped > 0) out << " (" << skipped << " rows with an empty cell left out)";
  out << "\n# lambda " << number(fit.lambda) << ", chosen by the rolling-origin error over "
      << opt.blocks << " blocks of the rows:";
  for (std::size_t i = 0; i < opt.lambdas.size(); ++i) {
    out << (i == 0 ? " " : ", ") << number(opt.lambdas[i]) << " -> " << number(fit.rolling_rms[i])
        << " um";
  }
  out << "\n# RMS error on the fitted rows: " << number(std::sqrt(ss / static_cast<double>(rows.size())))
      << " um\n";
  for (std::size_t j = direct; j < inputs.size(); ++j) {
    out << "\n[[input_lags]]   # " << inputs[j].column << " through a first-order lag\nsensor = "
        << inputs[j].sensor << "\ninput_sensor = " << inputs[j].input_sensor
        << "\ntau_s = " << number(inputs[j].tau_s) << "\n";
  }
  out << "\n[[input_sums]]\nsensor = " << opt.sensor << "\noffset = " << number(fit.offset)
      << "\ninputs = [";
  for (std::size_t j = 0; j < inputs.size(); ++j) out << (j ? ", " : "") << inputs[j].sensor;
  out << "]   # ";
  for (std::size_t j = 0; j < inputs.size(); ++j) {
    out << (j ? ", " : "") << inputs[j].column;
    if (inputs[j].tau_s > 0.0) out << " lag " << number(inputs[j].tau_s) << " s";
  }
  out << "\nweights = [";
  for (std::size_t j = 0; j < inputs.size(); ++j) out << (j ? ", " : "") << number(fit.weight[j]);
  out << "]\n";
  std::cout << out.str();
}

void setup(CLI::App& app) {
  auto opt = std::make_shared<Options>();
  auto* sub = app.add_subcommand(
      "fit-sum",
      "Fit a log's measured deviation as one shrunk linear model of many columns and lags of "
      "them; print the [[input_lags]] and [[input_sums]] that make nccompd compute it as a sensor");
  sub->add_option("--log", opt->logs,
                  "measurement log CSV, or a directory of them (repeat for several, oldest first)")
      ->required();
  sub->add_option("--map", opt->map, "column mapping TOML for a foreign CSV");
  sub->add_option("--input", opt->inputs,
                  "COLUMN=SENSOR: a column of the log and the sensor nccompd reads it on (repeat)")
      ->required();
  sub->add_option("--lag", opt->lags,
                  "COLUMN:TAU_S=SENSOR: also a first-order lag of an --input column, published on "
                  "SENSOR (repeat)");
  sub->add_option("--source", opt->sources,
                  "COLUMN=SENSOR: a column read only as the input of --lag, not in the sum (repeat)");
  sub->add_option("--sensor", opt->sensor, "the sensor the sum is published on")
      ->required()
      ->check(CLI::Range(0, 255));
  sub->add_option("--before", opt->before_s,
                  "fit only rows with time_s before this (e.g. the earlier shifts)");
  sub->add_option("--kind", opt->kind, "fit only rows of this kind (tool_wear, contour, calib)");
  sub->add_option("--point", opt->points,
                  "fit only rows of this point (an axis of the calibration: 0 X, 1 Y, 2 Z; repeat)");
  sub->add_option("--lambda", opt->lambdas, "the ridge weights to choose from (repeat)")
      ->check(CLI::PositiveNumber);
  sub->add_option("--blocks", opt->blocks, "blocks of the rolling-origin error")
      ->capture_default_str();
  sub->callback([opt] { run(*opt); });
}

}  // namespace

NCCOMP_REGISTER_COMMAND(fit_sum, setup);
