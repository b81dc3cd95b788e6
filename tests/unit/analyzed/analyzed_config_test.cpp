// nccomp-analyzed's configuration (docs/analyzed.md): GIVEN a file, THEN its keys are read with
// the defaults for the absent ones and paths relative to the file; every error names
// file:line:column and the key path.
#include <gtest/gtest.h>

#include "tests/support/temp_dir.hpp"
#include "tools/analyzed/analyzed_config.hpp"

namespace {

using nccomp::tools::analyzed::load_analyzed_config;

TEST(AnalyzedConfig, ReadsTheKeysAndResolvesPathsFromTheFile) {
  nccomp::test::TempDir d;
  const std::string path = d.write("a.toml",
                                   "[source]\nlog_directory = \"log\"\npoll_interval_s = 2\n"
                                   "[analysis]\nconfig = \"model.toml\"\nmin_new_rows = 50\n"
                                   "max_rows = 500\nmin_improvement_um = 0.25\n"
                                   "[output]\ndirectory = \"/srv/analyzed\"\nkeep_runs = 3\n"
                                   "[daemon]\nstatus_socket = \"s.sock\"\nsubmit = false\n"
                                   "avoid_cpus = [1, 3]\n");
  nccomp::formats::Diagnostics diag;
  const auto c = load_analyzed_config(path, diag);
  ASSERT_TRUE(c) << diag.to_string();
  EXPECT_EQ(c->log_directory, (d.path / "log").string());
  EXPECT_DOUBLE_EQ(c->poll_interval_s, 2.0);
  EXPECT_EQ(c->analysis_config, (d.path / "model.toml").string());
  EXPECT_EQ(c->min_new_rows, 50);
  EXPECT_EQ(c->max_rows, 500);
  EXPECT_DOUBLE_EQ(c->min_improvement_um, 0.25);
  EXPECT_EQ(c->work_directory, "/srv/analyzed");
  EXPECT_EQ(c->keep_runs, 3);
  EXPECT_EQ(c->status_socket, (d.path / "s.sock").string());
  EXPECT_FALSE(c->submit);
  EXPECT_EQ(c->avoid_cpus, (std::vector<int>{1, 3}));
}

TEST(AnalyzedConfig, ErrorsNameFileLineColumnAndKey) {
  nccomp::test::TempDir d;
  const std::string path = d.write("a.toml",
                                   "[analysis]\nconfig = \"m.toml\"\nmin_new_row = 5\n"
                                   "min_new_rows = 100\nmax_rows = 20\n[daemon]\nsubmit = 1\n"
                                   "[extra]\n");
  nccomp::formats::Diagnostics diag;
  EXPECT_FALSE(load_analyzed_config(path, diag));
  const std::string e = diag.to_string();
  EXPECT_NE(e.find(path + ":3:15: analysis.min_new_row: unknown key"), std::string::npos) << e;
  EXPECT_NE(e.find(path + ":5:12: analysis.max_rows: must be at least min_new_rows (100), got 20"),
            std::string::npos)
      << e;
  EXPECT_NE(e.find(path + ":7:10: daemon.submit: must be true or false"), std::string::npos) << e;
  EXPECT_NE(e.find("extra: unknown section"), std::string::npos) << e;
}

TEST(AnalyzedConfig, ATomlSyntaxErrorNamesItsLineAndColumn) {
  nccomp::test::TempDir d;
  const std::string path = d.write("a.toml", "[analysis]\nconfig = \"m.toml\"\n[daemon\n");
  nccomp::formats::Diagnostics diag;
  EXPECT_FALSE(load_analyzed_config(path, diag));
  EXPECT_EQ(diag.to_string().rfind(path + ":3:8: ", 0), 0U) << diag.to_string();
}

TEST(AnalyzedConfig, TheAnalysisSectionAndItsConfigAreRequired) {
  nccomp::test::TempDir d;
  nccomp::formats::Diagnostics diag;
  EXPECT_FALSE(load_analyzed_config(d.write("a.toml", "[source]\n"), diag));
  EXPECT_NE(diag.to_string().find("analysis: required section is missing"), std::string::npos)
      << diag.to_string();
  nccomp::formats::Diagnostics diag2;
  EXPECT_FALSE(load_analyzed_config(d.write("b.toml", "[analysis]\nmin_new_rows = 20\n"), diag2));
  EXPECT_NE(diag2.to_string().find("analysis.config: missing required key"), std::string::npos)
      << diag2.to_string();
}

}  // namespace
