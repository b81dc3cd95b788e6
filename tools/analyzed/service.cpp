#include "tools/analyzed/service.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <stdexcept>
#include <system_error>

#include "client/protocol.hpp"
#include "core/model/analysis.hpp"
#include "formats/measurement_log/measurement_log.hpp"
#include "formats/model/model_io.hpp"
#include "formats/toml/diagnostics.hpp"
#include "tools/analyze/report.hpp"

namespace nccomp::tools::analyzed {

namespace fs = std::filesystem;
namespace cm = nccomp::core::model;
namespace io = nccomp::formats::model_io;
namespace ml = nccomp::formats::measurement_log;

namespace {

constexpr std::size_t kMaxRowsPerPoll = 50'000;
constexpr std::size_t kBatchFailed = static_cast<std::size_t>(-1);
constexpr std::size_t kOutcomesKept = 100;

std::system_error sys_error(const std::string& what) {
  return std::system_error(errno, std::generic_category(), what);
}

// Write temp, fsync, rename, fsync the directory: the file is the old one or the new one.
void write_atomic(const fs::path& path, const std::string& text) {
  const fs::path tmp = path.string() + ".tmp";
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0640);
  if (fd < 0) throw sys_error(tmp.string() + ": cannot create");
  const bool ok = ::write(fd, text.data(), text.size()) == static_cast<ssize_t>(text.size()) &&
                  ::fsync(fd) == 0;
  ::close(fd);
  if (!ok || ::rename(tmp.c_str(), path.c_str()) != 0)
    throw sys_error(path.string() + ": cannot write");
  const int dfd = ::open(path.parent_path().c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
}

void write_file(const fs::path& p, const std::string& text) {
  std::ofstream f(p, std::ios::binary | std::ios::trunc);
  f << text;
  f.close();
  if (!f) throw std::runtime_error(p.string() + ": cannot write");
}

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path + ": cannot open");
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::string join(const std::vector<std::string>& v) {
  std::string s;
  for (const auto& x : v) s += (s.empty() ? "" : ",") + x;
  return s;
}

double rms_um(const std::vector<double>& r) {
  if (r.empty()) return 0.0;
  double sum = 0.0;
  for (const double x : r) sum += x * x;
  return std::sqrt(sum / static_cast<double>(r.size()));
}

std::string fmt(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.3f", v);
  return b;
}

std::string utc_stamp() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  ::gmtime_r(&t, &tm);
  char b[32];
  std::strftime(b, sizeof b, "%Y%m%dT%H%M%SZ", &tm);
  return b;
}

// The oldest file of the log (measurements.csv.N with the largest N, else measurements.csv):
// where a first start begins, so that the rows already rotated are analysed too.
mqtt::LogCursor oldest_file(const std::string& directory) {
  long best = -1;
  fs::path best_path;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(directory, ec)) {
    const std::string name = e.path().filename().string();
    std::string log;
    const long rank = ml::rotation_number(name, log);
    if (log == "measurements.csv" && rank > best) {
      best = rank;
      best_path = e.path();
    }
  }
  struct stat st {};
  if (best < 0 || ::stat(best_path.c_str(), &st) != 0) return {};
  return mqtt::LogCursor{static_cast<std::uint64_t>(st.st_ino), 0, 0};
}

}  // namespace

std::string ServiceState::to_text() const {
  std::ostringstream o;
  o << "cursor " << cursor.to_string() << "\nrows_bytes " << rows_bytes << "\nrows_total "
    << rows_total << "\nrows_at_last_run " << rows_at_last_run << "\nruns " << runs
    << "\nsubmitted " << submitted << "\nrows_skipped " << rows_skipped << "\nlast_submitted_hash "
    << last_submitted_hash << "\n";
  const std::string body = o.str();
  return body + "check " + std::to_string(mqtt::fnv1a(body.data(), body.size())) + "\n";
}

ServiceState ServiceState::parse(const std::string& text) {
  const std::size_t check = text.rfind("check ");
  if (check == std::string::npos) throw std::invalid_argument("no check line");
  const std::string body = text.substr(0, check);
  if (text.substr(check + 6) != std::to_string(mqtt::fnv1a(body.data(), body.size())) + "\n") {
    throw std::invalid_argument("the check does not match the contents");
  }
  ServiceState s;
  std::istringstream in(body);
  std::string key;
  std::string value;
  int seen = 0;
  while (in >> key >> value) {
    std::uint64_t* field = key == "rows_bytes"            ? &s.rows_bytes
                           : key == "rows_total"          ? &s.rows_total
                           : key == "rows_at_last_run"    ? &s.rows_at_last_run
                           : key == "runs"                ? &s.runs
                           : key == "submitted"           ? &s.submitted
                           : key == "rows_skipped"        ? &s.rows_skipped
                           : key == "last_submitted_hash" ? &s.last_submitted_hash
                                                          : nullptr;
    if (key == "cursor") {
      s.cursor = mqtt::LogCursor::parse(value);
    } else if (field == nullptr) {
      throw std::invalid_argument("unknown key '" + key + "'");
    } else {
      const auto [p, ec] = std::from_chars(value.data(), value.data() + value.size(), *field);
      if (ec != std::errc() || p != value.data() + value.size()) {
        throw std::invalid_argument(key + ": '" + value + "' is not a count");
      }
    }
    ++seen;
  }
  if (seen != 8) throw std::invalid_argument("expected 8 keys, found " + std::to_string(seen));
  return s;
}

Service::Service(AnalyzedConfig config, ServiceDeps deps)
    : config_(std::move(config)), deps_(std::move(deps)), source_(config_.log_directory) {
  const fs::path work(config_.work_directory);
  fs::create_directories(work / "runs");
  const fs::path state_path = work / "state";
  if (fs::exists(state_path)) {
    try {
      state_ = ServiceState::parse(read_text(state_path.string()));
    } catch (const std::exception& e) {
      // Start over rather than stop: the rows are read again from the oldest file.
      deps_.log("error", state_path.string() + ": not a state file (" + e.what() +
                             "): kept as state.bad, starting from the oldest log file");
      fs::rename(state_path, work / "state.bad");
      state_ = ServiceState{};
    }
  }
  const fs::path rows = rows_path();
  const std::uint64_t size = fs::exists(rows) ? fs::file_size(rows) : 0;
  if (size < state_.rows_bytes) {
    deps_.log("error", rows.string() + ": shorter (" + std::to_string(size) +
                           " bytes) than the state says (" + std::to_string(state_.rows_bytes) +
                           "): the rows taken so far are dropped, the log is followed on");
    state_.rows_bytes = state_.rows_total = state_.rows_at_last_run = 0;
  }
  cut_back_rows();
  if (state_.cursor.inode == 0) state_.cursor = oldest_file(config_.log_directory);
  source_.set_cursor(state_.cursor);
}

void Service::cut_back_rows() {
  // Rows appended after the last state was written are read from the log again.
  const std::string rows = rows_path();
  if (::truncate(rows.c_str(), static_cast<off_t>(state_.rows_bytes)) != 0 && errno != ENOENT) {
    throw sys_error(rows + ": cannot truncate");
  }
  header_.clear();
  if (state_.rows_bytes > 0) {
    std::ifstream in(rows);
    std::string line;
    std::getline(in, line);
    std::istringstream cells(line);
    for (std::string c; std::getline(cells, c, ',');) header_.push_back(c);
  }
}

std::string Service::rows_path() const {
  return (fs::path(config_.work_directory) / "rows.csv").string();
}

void Service::save_state() {
  write_atomic(fs::path(config_.work_directory) / "state", state_.to_text());
}

void Service::take_rows(std::vector<mqtt::LogRow>& rows) {
  const std::string path = rows_path();
  std::string text;
  std::uint64_t added = 0;
  bool restart = false;
  for (const auto& row : rows) {
    std::vector<std::string> names;
    for (const auto& [k, v] : row.columns.items()) names.push_back(k);
    if (names != header_) {
      if (!header_.empty()) {
        deps_.log("warning", "the log's columns changed in " + row.file + " (" + join(names) +
                                 " after " + join(header_) +
                                 "): the next analysis starts with "
                                 "the rows from here on");
      }
      header_ = names;
      restart = true;
      text = join(header_) + "\n";
      added = 0;
    }
    text += mqtt::json_to_row(header_, row.columns) + "\n";
    ++added;
  }
  const int flags = O_WRONLY | O_CREAT | O_CLOEXEC | (restart ? O_TRUNC : O_APPEND);
  const int fd = ::open(path.c_str(), flags, 0640);
  if (fd < 0) throw sys_error(path + ": cannot open");
  const bool ok = ::write(fd, text.data(), text.size()) == static_cast<ssize_t>(text.size()) &&
                  ::fsync(fd) == 0;
  ::close(fd);
  if (!ok) throw sys_error(path + ": cannot append the rows");
  if (restart) {
    state_.rows_bytes = 0;
    state_.rows_total = state_.rows_at_last_run = 0;
  }
  state_.rows_bytes += text.size();
  state_.rows_total += added;
}

void Service::poll() {
  // Everything there is, in batches: a run counts every row that is already in the files.
  for (;;) {
    const std::size_t taken = take_batch();
    if (taken == kBatchFailed) return;
    if (taken < kMaxRowsPerPoll) break;
  }
  if (state_.rows_total - state_.rows_at_last_run >=
      static_cast<std::uint64_t>(config_.min_new_rows)) {
    outcomes_.push_back(run());
    if (outcomes_.size() > kOutcomesKept) outcomes_.erase(outcomes_.begin());
  }
}

std::size_t Service::take_batch() {
  std::vector<mqtt::LogProblem> problems;
  std::vector<mqtt::LogRow> rows;
  try {
    rows = source_.poll(kMaxRowsPerPoll, problems);
  } catch (const std::exception& e) {
    deps_.log("error", e.what());
    return kBatchFailed;
  }
  for (const auto& p : problems) {
    ++state_.rows_skipped;
    // Appended, not "…" + std::to_string(…): GCC 12 at -O3 reports a false -Wrestrict there.
    std::string where = "log " + p.file;
    if (p.line > 0) where.append(":").append(std::to_string(p.line));
    deps_.log("warning", where + ": " + p.message);
  }
  const bool moved = !(source_.cursor() == state_.cursor);
  try {
    if (!rows.empty()) take_rows(rows);
    state_.cursor = source_.cursor();
    if (moved || !problems.empty()) save_state();
  } catch (const std::exception& e) {
    // Nothing is lost: the state still names the rows before these, which are read again.
    deps_.log("error", std::string(e.what()) + ": the rows are read again at the next poll");
    source_.set_cursor(state_.cursor);
    try {
      cut_back_rows();
    } catch (const std::exception& e2) {
      deps_.log("error", e2.what());
    }
    return kBatchFailed;
  }
  return rows.size();
}

RunOutcome Service::run() {
  RunOutcome out;
  const std::uint64_t new_rows = state_.rows_total - state_.rows_at_last_run;
  ++state_.runs;
  state_.rows_at_last_run = state_.rows_total;
  char number[16];
  std::snprintf(number, sizeof number, "%06llu", static_cast<unsigned long long>(state_.runs));
  const fs::path dir =
      fs::path(config_.work_directory) / "runs" / (std::string(number) + "-" + utc_stamp());
  out.directory = dir.string();
  try {
    fs::create_directories(dir / "plots");
    // The latest max_rows rows: the run's measurements.csv, a v2 log `nccomp analyze` reads.
    std::ifstream in(rows_path(), std::ios::binary);
    std::string header;
    std::getline(in, header);
    std::vector<std::string> lines;
    for (std::string l; std::getline(in, l);) lines.push_back(std::move(l));
    const std::size_t keep =
        std::min<std::size_t>(lines.size(), static_cast<std::size_t>(config_.max_rows));
    std::string csv = header + "\n";
    for (std::size_t i = lines.size() - keep; i < lines.size(); ++i) csv += lines[i] + "\n";
    write_file(dir / "measurements.csv", csv);
    out.rows = keep;
    if (lines.size() > 2 * static_cast<std::size_t>(config_.max_rows)) {
      // Older rows are never analysed again: the work directory keeps max_rows of them.
      write_atomic(rows_path(), csv);
      state_.rows_bytes = csv.size();
      state_.rows_total = state_.rows_at_last_run = keep;
      save_state();
    }

    const io::ModelFile cfg =
        io::read_model_text(read_text(config_.analysis_config), config_.analysis_config, false);
    cm::Dataset data;
    data.extra_columns = cfg.extra_columns;
    io::read_log_file((dir / "measurements.csv").string(), io::Mapping{}, data);
    const cm::AnalysisResult result = cm::analyze(data, cfg.config);
    namespace an = nccomp::tools::analyze;
    write_file(dir / "summary.json", an::summary_json(data, result));
    const auto plotted = an::plotted_columns(data);
    for (int c : plotted) {
      const std::string name = cm::column_name(c, data.extra_columns);
      write_file(dir / "plots" / ("residual_" + an::safe_name(name) + ".svg"),
                 an::residual_svg(data, result, c));
    }
    write_file(
        dir / "report.md",
        an::report_markdown(
            data, result, {(dir / "measurements.csv").string(), config_.analysis_config}, plotted));
    // The terms alone identify the model (the header names the run).
    const std::string terms = io::write_model_toml(result.final_model, cfg.config, {});
    const std::uint64_t hash = mqtt::fnv1a(terms.data(), terms.size());
    write_file(dir / "model.toml",
               io::write_model_toml(
                   result.final_model, cfg.config,
                   {"Compensation model fitted by nccomp-analyzed (run " + std::string(number) +
                        ") on the " + std::to_string(keep) + " rows of measurements.csv beside it.",
                    "Load it in nccompd as an include; use it as --config to analyze again."}));
    out.analysed = true;
    out.effects_added = result.effects.size();
    out.new_rms_um = rms_um(cm::residuals(data, result.final_model));
    deps_.log("info", "run " + std::string(number) + ": " + std::to_string(new_rows) +
                          " new rows, analysed the latest " + std::to_string(keep) +
                          "; declared model RMS " + fmt(result.declared.fitted.rms_um) +
                          " um, final RMS " + fmt(result.final_stats.fitted.rms_um) +
                          " um, effects added " + std::to_string(result.effects.size()) +
                          ", noise floor " + fmt(result.noise_floor_um) + " um; " + dir.string());
    // The live model as it is (not refitted) on the same rows.
    std::string status;
    try {
      status = deps_.query(client::kStatusJson);
    } catch (const std::exception& e) {
      out.decision = "failed";
      out.reason = std::string("the daemon is away: ") + e.what();
    }
    if (out.decision.empty()) {
      const auto j = nlohmann::json::parse(status, nullptr, false);
      const std::string live_file =
          j.is_object() ? j.value("/model/live/file"_json_pointer, std::string()) : "";
      const std::string phase =
          j.is_object() ? j.value("/shadow/phase"_json_pointer, std::string()) : "";
      bool comparable = true;
      if (!j.is_object()) {
        out.decision = "failed";
        out.reason = "the daemon's status is not JSON";
      } else if (live_file.empty()) {
        out.live_rms_um = rms_um(cm::residuals(data, cm::Model(data.extra_columns, {})));
        out.live_known = true;
      } else {
        try {
          const cm::Model live = io::load_model_file(live_file);
          // A model of other extra columns cannot be evaluated on these rows: taken as different.
          comparable = live.extra_columns() == data.extra_columns;
          if (comparable) out.live_rms_um = rms_um(cm::residuals(data, live));
          out.live_known = comparable;
        } catch (const std::exception& e) {
          out.decision = "failed";
          out.reason = "cannot read the live model " + live_file + ": " + e.what();
        }
      }
      if (!out.decision.empty()) {
      } else if (comparable && out.live_rms_um - out.new_rms_um < config_.min_improvement_um) {
        out.decision = "written";
        out.reason = "not better than the live model " +
                     (live_file.empty() ? std::string("(none)") : live_file) + " by " +
                     fmt(config_.min_improvement_um) + " um (RMS live " + fmt(out.live_rms_um) +
                     " um, new " + fmt(out.new_rms_um) + " um)";
      } else if (hash == state_.last_submitted_hash) {
        out.decision = "written";
        out.reason = "the same model as the last candidate submitted";
      } else if (!phase.empty() && phase != "none") {
        out.decision = "written";
        out.reason = "the daemon is still deciding on a candidate (shadow phase " + phase + ")";
      } else if (!config_.submit) {
        out.decision = "written";
        out.reason = "submit = false";
      } else {
        const std::string model_path = fs::absolute(dir / "model.toml").lexically_normal().string();
        std::string answer;
        try {
          answer = deps_.query(client::model_candidate_request(model_path));
        } catch (const std::exception& e) {
          out.decision = "failed";
          out.reason = std::string("the daemon is away: ") + e.what();
        }
        if (!out.decision.empty()) {
        } else if (client::is_error(answer)) {
          out.decision = "refused";
          out.reason = client::error_reason(answer);
        } else {
          out.decision = "submitted";
          out.reason = answer.substr(0, answer.find('\n'));
          state_.last_submitted_hash = hash;
          ++state_.submitted;
        }
      }
    }
    if ((out.decision == "failed" && config_.submit) || out.decision == "refused") {
      ++submit_errors_;
    }
  } catch (const std::exception& e) {
    ++failed_runs_;
    out.decision = "failed";
    out.reason = std::string("analysis: ") + e.what();
  }
  nlohmann::ordered_json d;
  d["run"] = state_.runs;
  d["rows"] = out.rows;
  d["new_rows"] = new_rows;
  d["analysed"] = out.analysed;
  d["effects_added"] = out.effects_added;
  d["live_rms_um"] = out.live_known ? nlohmann::ordered_json(out.live_rms_um) : nullptr;
  d["new_rms_um"] = out.new_rms_um;
  d["min_improvement_um"] = config_.min_improvement_um;
  d["decision"] = out.decision;
  d["reason"] = out.reason;
  try {
    write_atomic(dir / "decision.json", d.dump(2) + "\n");
    save_state();
  } catch (const std::exception& e) {
    deps_.log("error", e.what());
  }
  const bool bad = out.decision == "failed" || out.decision == "refused";
  deps_.log(
      bad ? "error" : "info",
      "run " + std::string(number) + ": " + out.decision +
          (out.analysed ? " (RMS on the analysed rows:" +
                              (out.live_known ? " live " + fmt(out.live_rms_um) + " um," : "") +
                              " new " + fmt(out.new_rms_um) + " um)"
                        : std::string()) +
          ": " + out.reason);
  prune_runs();
  return out;
}

void Service::prune_runs() {
  if (config_.keep_runs <= 0) return;
  std::vector<fs::path> runs;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(fs::path(config_.work_directory) / "runs", ec)) {
    if (e.is_directory()) runs.push_back(fs::absolute(e.path()).lexically_normal());
  }
  const std::size_t keep = static_cast<std::size_t>(config_.keep_runs);
  if (runs.size() <= keep) return;
  // A promoted run's model.toml is the daemon's live model (or the one rollback returns to, or
  // the candidate): its folder stays, or a restart of the daemon could not load it. Without the
  // daemon's word nothing is removed.
  std::vector<std::string> in_use;
  try {
    const auto j = nlohmann::json::parse(deps_.query(client::kStatusJson));
    for (const char* k : {"/model/live/file", "/model/previous/file", "/shadow/other/file"}) {
      in_use.push_back(j.value(nlohmann::json::json_pointer(k), std::string()));
    }
  } catch (const std::exception&) {
    return;
  }
  std::sort(runs.begin(), runs.end());  // numbered: oldest first
  for (std::size_t i = 0; i + keep < runs.size(); ++i) {
    const std::string model = (runs[i] / "model.toml").string();
    if (std::find(in_use.begin(), in_use.end(), model) == in_use.end()) {
      fs::remove_all(runs[i], ec);
    }
  }
}

}  // namespace nccomp::tools::analyzed
