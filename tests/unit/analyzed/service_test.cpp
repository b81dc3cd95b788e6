// nccomp-analyzed's service (tools/analyzed/service.hpp) on a log directory written here as nccompd
// writes it (v2 header, rows appended, measurements.csv rotated to .1) and a fake status socket
// that records the requests and answers as nccompd does: GIVEN rows coming in, THEN the analysis
// runs once per min_new_rows new rows, on every row exactly once across rotation, restarts and
// torn lines, bad rows are skipped and counted, and the candidate is submitted only when it
// predicts the rows better than the live model by min_improvement_um.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "client/protocol.hpp"
#include "formats/measurement_log/measurement_log.hpp"
#include "tests/support/temp_dir.hpp"
#include "tools/analyzed/service.hpp"

namespace {

namespace fs = std::filesystem;
using nccomp::tools::analyzed::AnalyzedConfig;
using nccomp::tools::analyzed::Service;
using nccomp::tools::analyzed::ServiceDeps;

// Tool measurements of T1: 3 µm of wear and ±0.2 µm of uniform noise (a fixed LCG).
double measured_um(int i) {
  std::uint32_t x = 12345U + static_cast<std::uint32_t>(i) * 2654435761U;
  x ^= x >> 13;
  x *= 1103515245U;
  x ^= x >> 16;
  return 3.0 + 0.4 * (static_cast<double>(x % 10001U) / 10000.0 - 0.5);
}

std::string row(int i) {
  std::ostringstream s;
  s.precision(17);
  s << i << ",0,1,tool_wear,0,,,,"
    << "," << 10 * i << ",," << measured_um(i) << ",0,m1,2026-01-01T00:00:00.000Z,1";
  return s.str();
}

std::string rows(int from, int to) {
  std::string s;
  for (int i = from; i <= to; ++i) s += row(i) + "\n";
  return s;
}

struct FakeDaemon {
  std::vector<std::string> requests;
  std::string live_file;
  std::string phase{"none"};
  bool away{false};
  std::string candidate_answer{"ok model candidate: scored in shadow\n"};

  std::string query(std::string_view request) {
    requests.emplace_back(request);
    if (away) throw std::runtime_error("status.sock: cannot connect: No such file or directory");
    if (request == nccomp::client::kStatusJson) {
      return "{\"model\":{\"live\":{\"file\":\"" + live_file +
             "\",\"hash\":\"\"}},\"shadow\":{"
             "\"phase\":\"" +
             phase + "\"}}";
    }
    return candidate_answer;
  }
};

class AnalyzedService : public ::testing::Test {
 protected:
  void SetUp() override {
    fs::create_directories(d.path / "log");
    config.log_directory = (d.path / "log").string();
    config.work_directory = (d.path / "work").string();
    config.analysis_config = d.write("analysis.toml",
                                     "[model]\n[[model.term]]\nname = \"offset\"\n"
                                     "form = \"constant\"\nkinds = [\"tool_wear\"]\n");
    config.min_new_rows = 20;
    config.min_improvement_um = 0.5;
    append(std::string(nccomp::formats::measurement_log::csv_header({})) + "\n");
  }
  void append(const std::string& text, const char* name = "measurements.csv") {
    std::ofstream(d.path / "log" / name, std::ios::app) << text;
  }
  ServiceDeps deps() {
    ServiceDeps x;
    x.query = [this](std::string_view r) { return daemon.query(r); };
    x.log = [this](std::string_view level, const std::string& line) {
      journal += std::string(level) + " " + line + "\n";
    };
    return x;
  }
  // The data rows of the work directory's rows.csv.
  std::vector<std::string> taken(const Service& s) {
    std::ifstream in(s.rows_path());
    std::vector<std::string> out;
    std::string l;
    std::getline(in, l);
    while (std::getline(in, l)) out.push_back(l);
    return out;
  }
  nccomp::test::TempDir d;
  AnalyzedConfig config;
  FakeDaemon daemon;
  std::string journal;
};

// The first cell (time_s) of every row: which rows were taken, in which order.
std::vector<int> times(const std::vector<std::string>& lines) {
  std::vector<int> t;
  for (const auto& l : lines) t.push_back(std::stoi(l.substr(0, l.find(','))));
  return t;
}

std::vector<int> range(int from, int to) {
  std::vector<int> v;
  for (int i = from; i <= to; ++i) v.push_back(i);
  return v;
}

TEST_F(AnalyzedService, RunsOncePerMinNewRowsAndSubmitsABetterModel) {
  Service s(config, deps());
  append(rows(1, 19));
  s.poll();
  EXPECT_EQ(s.state().rows_total, 19U);
  EXPECT_EQ(s.state().runs, 0U) << journal;
  append(rows(20, 20));
  s.poll();
  ASSERT_EQ(s.state().runs, 1U) << journal;
  ASSERT_EQ(s.outcomes().size(), 1U);
  const auto& o = s.outcomes()[0];
  EXPECT_TRUE(o.analysed) << o.reason << "\n" << journal;
  EXPECT_EQ(o.rows, 20U);
  // No live model: its error is the rows themselves; the fitted constant leaves their spread.
  double sum = 0.0;
  double sum2 = 0.0;
  for (int i = 1; i <= 20; ++i) {
    sum += measured_um(i);
    sum2 += measured_um(i) * measured_um(i);
  }
  const double mean = sum / 20.0;
  EXPECT_TRUE(o.live_known);
  EXPECT_NEAR(o.live_rms_um, std::sqrt(sum2 / 20.0), 1e-9);
  EXPECT_NEAR(o.new_rms_um, std::sqrt(sum2 / 20.0 - mean * mean), 1e-9);
  EXPECT_EQ(o.effects_added, 0U);
  EXPECT_EQ(o.decision, "submitted") << o.reason;
  const fs::path model = fs::path(o.directory) / "model.toml";
  ASSERT_EQ(daemon.requests.size(), 2U);
  EXPECT_EQ(daemon.requests[1], "model candidate " + model.string());
  for (const char* f :
       {"model.toml", "summary.json", "report.md", "measurements.csv", "decision.json"}) {
    EXPECT_TRUE(fs::exists(fs::path(o.directory) / f)) << f;
  }
  EXPECT_EQ(s.state().submitted, 1U);
  EXPECT_NE(journal.find("run 000001: submitted"), std::string::npos) << journal;

  // 19 more rows are not enough; the 20th starts run 2.
  append(rows(21, 39));
  s.poll();
  EXPECT_EQ(s.state().runs, 1U);
  append(rows(40, 40));
  s.poll();
  EXPECT_EQ(s.state().runs, 2U);
  EXPECT_EQ(s.outcomes().back().rows, 40U);
}

TEST_F(AnalyzedService, FollowsRotationAndTakesEveryRowOnceInOrder) {
  Service s(config, deps());
  append(rows(1, 10));
  s.poll();
  // The daemon writes five more rows, rotates, and goes on in a new file.
  append(rows(11, 15));
  fs::rename(d.path / "log" / "measurements.csv", d.path / "log" / "measurements.csv.1");
  append(std::string(nccomp::formats::measurement_log::csv_header({})) + "\n" + rows(16, 25));
  s.poll();
  EXPECT_EQ(times(taken(s)), range(1, 25));
  EXPECT_EQ(s.state().rows_total, 25U);
  EXPECT_EQ(s.state().rows_skipped, 0U) << journal;
  EXPECT_EQ(s.state().runs, 1U);
}

TEST_F(AnalyzedService, AFirstStartBeginsWithTheOldestRotatedFile) {
  append(rows(1, 5));
  fs::rename(d.path / "log" / "measurements.csv", d.path / "log" / "measurements.csv.1");
  append(std::string(nccomp::formats::measurement_log::csv_header({})) + "\n" + rows(6, 8));
  Service s(config, deps());
  s.poll();
  s.poll();
  EXPECT_EQ(times(taken(s)), range(1, 8));
}

TEST_F(AnalyzedService, ARestartNeitherReadsAgainNorSkips) {
  {
    Service s(config, deps());
    append(rows(1, 12));
    s.poll();
    EXPECT_EQ(s.state().rows_total, 12U);
  }
  append(rows(13, 20));
  {
    Service s(config, deps());
    EXPECT_EQ(s.state().rows_total, 12U);
    s.poll();
    EXPECT_EQ(times(taken(s)), range(1, 20));
    ASSERT_EQ(s.state().runs, 1U);
    EXPECT_EQ(s.outcomes()[0].rows, 20U);
  }
  {
    // A restart after the run: the 20 rows are not analysed again.
    Service s(config, deps());
    s.poll();
    EXPECT_EQ(s.state().runs, 1U);
    EXPECT_EQ(s.state().rows_at_last_run, 20U);
  }
}

TEST_F(AnalyzedService, RowsAppendedAfterTheLastStateAreTakenOnceAfterACrash) {
  {
    Service s(config, deps());
    append(rows(1, 6));
    s.poll();
  }
  // A crash between appending rows 7–9 to rows.csv and writing the state: the state still says 6.
  append(rows(7, 9));
  std::ofstream((d.path / "work" / "rows.csv"), std::ios::app) << rows(7, 9);
  Service s(config, deps());
  s.poll();
  EXPECT_EQ(times(taken(s)), range(1, 9));
  EXPECT_EQ(s.state().rows_total, 9U);
}

TEST_F(AnalyzedService, ATornLastLineIsTakenOnlyWhenComplete) {
  Service s(config, deps());
  const std::string sixth = row(6);
  // Torn within its measured_um cell.
  const std::size_t cut = sixth.rfind(",0,m1,") - 4;
  append(rows(1, 5) + sixth.substr(0, cut));
  s.poll();
  EXPECT_EQ(s.state().rows_total, 5U);
  append(sixth.substr(cut) + "\n");
  s.poll();
  const auto lines = taken(s);
  ASSERT_EQ(lines.size(), 6U);
  // The row whole: its measured_um is the value written, not the torn cell's.
  EXPECT_EQ(times(lines), range(1, 6));
  std::istringstream cells(lines[5]);
  std::vector<std::string> c;
  for (std::string x; std::getline(cells, x, ',');) c.push_back(x);
  ASSERT_EQ(c.size(), 16U);
  EXPECT_DOUBLE_EQ(std::stod(c[11]), measured_um(6));
  EXPECT_EQ(s.state().rows_skipped, 0U);
}

TEST_F(AnalyzedService, BadRowsAreSkippedCountedAndLogged) {
  Service s(config, deps());
  append(rows(1, 3) + "4,0,1,tool_wear,0\n" + "5,0,1,tool_wear,0,,,,,50,,abc,0,m1,x,1\n" +
         rows(6, 8));
  s.poll();
  EXPECT_EQ(times(taken(s)), (std::vector<int>{1, 2, 3, 6, 7, 8}));
  EXPECT_EQ(s.state().rows_skipped, 2U);
  EXPECT_NE(journal.find("5 fields, the header has 16"), std::string::npos) << journal;
  EXPECT_NE(journal.find("column 'measured_um': 'abc' is not a finite number"), std::string::npos)
      << journal;
}

TEST_F(AnalyzedService, AModelNoBetterThanTheLiveOneIsWrittenNotSubmitted) {
  // The live model already predicts the mean: the refit is better by far less than 0.5 µm.
  double sum = 0.0;
  for (int i = 1; i <= 20; ++i) sum += measured_um(i);
  std::ostringstream live;
  live.precision(17);
  live << "[model]\n[[model.term]]\nname = \"offset\"\nform = \"constant\"\n"
       << "kinds = [\"tool_wear\"]\ngroups = [[0.0, 0.0]]\ncoef_um = [" << sum / 20.0 << "]\n";
  daemon.live_file = d.write("live.toml", live.str());
  Service s(config, deps());
  append(rows(1, 20));
  s.poll();
  ASSERT_EQ(s.outcomes().size(), 1U);
  const auto& o = s.outcomes()[0];
  EXPECT_EQ(o.decision, "written") << o.reason;
  EXPECT_NEAR(o.live_rms_um, o.new_rms_um, 1e-9);
  EXPECT_NE(o.reason.find("not better than the live model " + daemon.live_file), std::string::npos)
      << o.reason;
  EXPECT_EQ(daemon.requests.size(), 1U);  // the status only
  EXPECT_EQ(s.state().submitted, 0U);
}

TEST_F(AnalyzedService, ACandidateInShadowIsNotReplaced) {
  daemon.phase = "candidate";
  Service s(config, deps());
  append(rows(1, 20));
  s.poll();
  ASSERT_EQ(s.outcomes().size(), 1U);
  EXPECT_EQ(s.outcomes()[0].decision, "written");
  EXPECT_NE(s.outcomes()[0].reason.find("still deciding"), std::string::npos);
  EXPECT_EQ(daemon.requests.size(), 1U);
}

TEST_F(AnalyzedService, TheDaemonAwayOrRefusingIsCountedAndTheServiceGoesOn) {
  daemon.away = true;
  Service s(config, deps());
  append(rows(1, 20));
  s.poll();
  ASSERT_EQ(s.outcomes().size(), 1U);
  EXPECT_EQ(s.outcomes()[0].decision, "failed");
  EXPECT_NE(s.outcomes()[0].reason.find("the daemon is away: status.sock: cannot connect"),
            std::string::npos)
      << s.outcomes()[0].reason;
  EXPECT_TRUE(fs::exists(fs::path(s.outcomes()[0].directory) / "model.toml"));
  EXPECT_FALSE(s.outcomes()[0].live_known);
  EXPECT_EQ(s.submit_errors(), 1U);
  daemon.away = false;
  daemon.candidate_answer = "error: permission denied: 'model' changes the machine\n";
  append(rows(21, 40));
  s.poll();
  ASSERT_EQ(s.outcomes().size(), 2U);
  EXPECT_EQ(s.outcomes()[1].decision, "refused");
  EXPECT_EQ(s.outcomes()[1].reason, "permission denied: 'model' changes the machine");
  EXPECT_EQ(s.submit_errors(), 2U);
  EXPECT_EQ(s.state().submitted, 0U);
}

TEST_F(AnalyzedService, AnAnalysisThatFailsIsCountedAndTheRowsAreKept) {
  config.analysis_config = d.write("bad.toml",
                                   "[model]\n[[model.term]]\nname = \"x\"\n"
                                   "form = \"cubic\"\n");
  Service s(config, deps());
  append(rows(1, 20));
  s.poll();
  ASSERT_EQ(s.outcomes().size(), 1U);
  EXPECT_EQ(s.outcomes()[0].decision, "failed");
  EXPECT_NE(s.outcomes()[0].reason.find("unknown form 'cubic'"), std::string::npos)
      << s.outcomes()[0].reason;
  EXPECT_EQ(s.failed_runs(), 1U);
  EXPECT_EQ(s.state().rows_total, 20U);
  EXPECT_TRUE(daemon.requests.empty());
}

// keep_runs = 1: old run folders go, but never the one whose model the daemon runs (a restart
// of the daemon loads it again) nor any while the daemon cannot say which that is.
TEST_F(AnalyzedService, OldRunsAreRemovedButNotTheLiveModels) {
  config.keep_runs = 1;
  config.submit = false;
  Service s(config, deps());
  append(rows(1, 20));
  s.poll();
  ASSERT_EQ(s.outcomes().size(), 1U);
  const fs::path first = s.outcomes()[0].directory;
  daemon.live_file = (first / "model.toml").string();
  append(rows(21, 40));
  s.poll();
  append(rows(41, 60));
  s.poll();
  ASSERT_EQ(s.outcomes().size(), 3U);
  EXPECT_TRUE(fs::exists(first / "model.toml"));
  EXPECT_FALSE(fs::exists(s.outcomes()[1].directory));
  EXPECT_TRUE(fs::exists(s.outcomes()[2].directory));
  daemon.away = true;
  append(rows(61, 80));
  s.poll();
  ASSERT_EQ(s.outcomes().size(), 4U);
  EXPECT_TRUE(fs::exists(s.outcomes()[2].directory));
  EXPECT_TRUE(fs::exists(s.outcomes()[3].directory));
}

TEST(AnalyzedState, RoundTripsAndRefusesADamagedFile) {
  nccomp::tools::analyzed::ServiceState s;
  s.cursor = {12, 345, 678};
  s.rows_bytes = 1000;
  s.rows_total = 9;
  s.rows_at_last_run = 4;
  s.runs = 2;
  s.submitted = 1;
  s.rows_skipped = 3;
  s.last_submitted_hash = 42;
  const std::string text = s.to_text();
  const auto back = nccomp::tools::analyzed::ServiceState::parse(text);
  EXPECT_EQ(back.to_text(), text);
  std::string damaged = text;
  damaged[text.find("rows_total 9") + 11] = '8';
  EXPECT_THROW((void)nccomp::tools::analyzed::ServiceState::parse(damaged), std::invalid_argument);
}

}  // namespace
