// `nccomp plan` run as the operator runs it: the real binary, its exit status, its standard
// output and error, the files it writes. The console examples of docs/checkpoints.md are checked
// against what the binary prints (the docs must not show an output the command does not give).
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;

const std::string kSource = NCCOMP_SOURCE_DIR;
const std::string kBin = NCCOMP_BIN;

struct RunResult {
  int status{-1};
  std::string out;  // standard output and error, interleaved as written
};

std::string read_file(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

struct TempDir {
  TempDir() {
    path = fs::temp_directory_path() /
           ("nccomp_plan_cli_" + std::to_string(::getpid()) + "_" + std::to_string(n++));
    fs::remove_all(path);
    fs::create_directories(path);
  }
  ~TempDir() { fs::remove_all(path); }
  static inline int n = 0;
  fs::path path;
};

/// Runs `nccomp plan <args>` in directory cwd; stdout and stderr go to one file.
RunResult run_plan(const std::vector<std::string>& args, const fs::path& cwd, const fs::path& tmp) {
  const fs::path log = tmp / "output.txt";
  const pid_t pid = ::fork();
  if (pid == 0) {
    const int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (fd < 0 || ::dup2(fd, 1) < 0 || ::dup2(fd, 2) < 0 || ::chdir(cwd.c_str()) != 0) {
      ::_exit(127);
    }
    std::vector<std::string> a{kBin, "plan"};
    a.insert(a.end(), args.begin(), args.end());
    std::vector<char*> argv;
    for (auto& s : a) argv.push_back(s.data());
    argv.push_back(nullptr);
    ::execv(kBin.c_str(), argv.data());
    ::_exit(127);
  }
  RunResult r;
  int st = 0;
  if (pid > 0 && ::waitpid(pid, &st, 0) == pid && WIFEXITED(st)) {
    r.status = WEXITSTATUS(st);
  }
  r.out = read_file(log);
  return r;
}

std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> lines;
  std::istringstream in(text);
  for (std::string l; std::getline(in, l);) lines.push_back(l);
  return lines;
}

/// The lines docs/checkpoints.md shows after `$ <command>` in a console block, up to the next
/// `$ ` line or the end of the block (a block indented in a list: its indentation removed).
std::vector<std::string> doc_output(const std::string& command) {
  const auto doc = lines_of(read_file(fs::path(kSource) / "docs/checkpoints.md"));
  std::vector<std::string> out;
  for (std::size_t i = 0; i < doc.size(); ++i) {
    const std::size_t indent = doc[i].find_first_not_of(' ');
    if (indent == std::string::npos || doc[i].substr(indent) != "$ " + command) continue;
    for (std::size_t k = i + 1; k < doc.size(); ++k) {
      const std::string line = doc[k].size() >= indent ? doc[k].substr(indent) : std::string();
      if (line.rfind("$ ", 0) == 0 || line.rfind("```", 0) == 0) break;
      out.push_back(line);
    }
    return out;
  }
  ADD_FAILURE() << "docs/checkpoints.md shows no `$ " << command << "`";
  return out;
}

std::vector<std::string> head(const std::vector<std::string>& v, std::size_t n) {
  return {v.begin(), v.begin() + static_cast<std::ptrdiff_t>(std::min(n, v.size()))};
}

TEST(PlanCli, TheDocumentedExampleIsWhatTheCommandPrintsAndWrites) {
  TempDir d;
  const RunResult r =
      run_plan({"tests/unit/checkpoint/data/boss.toml", "--out-csv", (d.path / "plan.csv").string(),
                "--out-gcode", (d.path / "O9100.nc").string()},
               kSource, d.path);
  ASSERT_EQ(r.status, 0) << r.out;
  // With both outputs in files, only the summary is printed.
  EXPECT_EQ(lines_of(r.out), doc_output("nccomp plan tests/unit/checkpoint/data/boss.toml "
                                        "--out-csv plan.csv --out-gcode O9100.nc"));
  const auto csv = lines_of(read_file(d.path / "plan.csv"));
  EXPECT_EQ(csv.size(), 1U + 56U);
  EXPECT_EQ(head(csv, 5), doc_output("head -5 plan.csv"));
  const auto gcode = lines_of(read_file(d.path / "O9100.nc"));
  EXPECT_EQ(head(gcode, 13), doc_output("head -13 O9100.nc"));
  // 56 probing blocks of 4 lines, 5 lines of header, M30 and %.
  EXPECT_EQ(gcode.size(), 5U + 56U * 4U + 2U);
  EXPECT_EQ(gcode[gcode.size() - 2], "M30");
  EXPECT_EQ(gcode.back(), "%");
}

TEST(PlanCli, FormatChoosesWhatGoesToStandardOutput) {
  TempDir d;
  const std::string cfg = kSource + "/tests/unit/checkpoint/data/boss.toml";
  const RunResult csv = run_plan({cfg, "--format", "csv"}, d.path, d.path);
  ASSERT_EQ(csv.status, 0) << csv.out;
  auto lines = lines_of(csv.out);
  ASSERT_EQ(lines.size(), 4U + 1U + 56U);  // summary, header, one row per checkpoint
  EXPECT_EQ(lines[4].rfind("id,level,source,register,", 0), 0U);
  EXPECT_EQ(lines.back().rfind("55,3,corner,75,", 0), 0U) << lines.back();
  EXPECT_EQ(csv.out.find("G65"), std::string::npos);

  const RunResult gcode = run_plan({cfg, "--format", "gcode"}, d.path, d.path);
  ASSERT_EQ(gcode.status, 0) << gcode.out;
  lines = lines_of(gcode.out);
  ASSERT_EQ(lines.size(), 4U + 5U + 56U * 4U + 2U);
  EXPECT_EQ(lines[4], "%");
  EXPECT_EQ(lines[5], "O9100 (NCCOMP S1 CHECKPOINT PROBING, 56 POINTS, 4 LEVELS)");
  EXPECT_EQ(gcode.out.find("id,level"), std::string::npos);

  // Default (both): the CSV, an empty line, the program.
  const RunResult both = run_plan({cfg}, d.path, d.path);
  ASSERT_EQ(both.status, 0) << both.out;
  lines = lines_of(both.out);
  ASSERT_EQ(lines.size(), 4U + 57U + 1U + 5U + 56U * 4U + 2U);
  EXPECT_EQ(lines[4 + 57], "");
  EXPECT_EQ(lines[4 + 57 + 1], "%");

  // An output file takes its part away from standard output; the other part stays.
  const RunResult split =
      run_plan({cfg, "--out-gcode", (d.path / "p.nc").string()}, d.path, d.path);
  ASSERT_EQ(split.status, 0) << split.out;
  EXPECT_EQ(lines_of(split.out).size(), 4U + 57U);
  EXPECT_EQ(lines_of(read_file(d.path / "p.nc")).size(), 5U + 56U * 4U + 2U);

  const RunResult bad = run_plan({cfg, "--format", "xml"}, d.path, d.path);
  EXPECT_NE(bad.status, 0);
  EXPECT_NE(bad.out.find("--format"), std::string::npos) << bad.out;
}

TEST(PlanCli, ContourOptionReplacesTheContourWithPerPointAlphaAndMarkedCorners) {
  const RunResult r =
      run_plan({"tests/unit/checkpoint/data/boss.toml", "--contour",
                "tests/unit/checkpoint/data/rounded_contour.csv", "--format", "csv"},
               kSource, fs::temp_directory_path());
  ASSERT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(lines_of(read_file(kSource + "/tests/unit/checkpoint/data/rounded_contour.csv")),
            doc_output("cat tests/unit/checkpoint/data/rounded_contour.csv"));
  EXPECT_EQ(head(lines_of(r.out), 9),
            doc_output("nccomp plan tests/unit/checkpoint/data/boss.toml --contour "
                       "tests/unit/checkpoint/data/rounded_contour.csv --format csv | head -9"));
}

TEST(PlanCli, ABadConfigExitsWithStatus3AndEveryProblemWithItsPlace) {
  TempDir d;
  // The documented bad.toml, written as the docs show it.
  const auto text = doc_output("cat bad.toml");
  ASSERT_FALSE(text.empty());
  {
    std::ofstream f(d.path / "bad.toml");
    for (const auto& l : text) f << l << "\n";
  }
  const RunResult r = run_plan({"bad.toml"}, d.path, d.path);
  EXPECT_EQ(r.status, 3) << r.out;
  EXPECT_EQ(lines_of(r.out), doc_output("nccomp plan bad.toml"));

  // The config trap: creep without a live register, refused with the key's place (the docs'
  // table-only.toml).
  {
    std::ofstream f(d.path / "table-only.toml");
    for (const auto& l : doc_output("cat table-only.toml")) f << l << "\n";
  }
  const RunResult trap = run_plan({"table-only.toml"}, d.path, d.path);
  EXPECT_EQ(trap.status, 3);
  EXPECT_EQ(lines_of(trap.out), doc_output("nccomp plan table-only.toml"));
  ASSERT_EQ(lines_of(trap.out).size(), 2U) << trap.out;
  EXPECT_EQ(lines_of(trap.out)[1].rfind("table-only.toml:4:9: checkpoints.apply: \"creep\" "
                                        "drives the live radius wear register, but "
                                        "active_register = -1",
                                        0),
            0U)
      << trap.out;

  // A missing file, a contour file with a bad row, an output that cannot be written.
  const RunResult missing = run_plan({"nope.toml"}, d.path, d.path);
  EXPECT_EQ(missing.status, 3);
  EXPECT_NE(missing.out.find("nope.toml"), std::string::npos) << missing.out;
  {
    std::ofstream f(d.path / "wall.csv");
    f << "x_mm,y_mm,alpha_deg\n0,0,\n100,0,95\n100,60,\n";
  }
  const RunResult csv = run_plan(
      {kSource + "/tests/unit/checkpoint/data/boss.toml", "--contour", "wall.csv"}, d.path, d.path);
  EXPECT_EQ(csv.status, 3);
  EXPECT_NE(csv.out.find("wall.csv:3: column alpha_deg: 95 is not below 89 degrees"),
            std::string::npos)
      << csv.out;
  const RunResult unwritable =
      run_plan({kSource + "/tests/unit/checkpoint/data/boss.toml", "--out-csv",
                (d.path / "no" / "such" / "dir.csv").string()},
               d.path, d.path);
  EXPECT_EQ(unwritable.status, 1);
  EXPECT_NE(unwritable.out.find("cannot write the plan CSV"), std::string::npos) << unwritable.out;
}

}  // namespace
