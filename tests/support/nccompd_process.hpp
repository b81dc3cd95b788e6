// nccompd as a child process of a test: started with a config in a test directory, its stdout and
// stderr appended to <dir>/nccompd.log, asked through its status socket (<dir>/status.sock, the
// test configs put it there), signalled, stopped and reaped. One helper for every whole-process
// test of the daemon (tests/hil/daemon, tests/hil/can, tests/hil/modbus, tests/hil/calib).
// The binary's path comes from the test target (NCCOMPD_BIN).
#pragma once

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <exception>
#include <filesystem>
#include <fstream>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "client/status_client.hpp"

extern char** environ;

namespace nccomp::test {

class NccompdProcess {
 public:
  NccompdProcess(std::filesystem::path dir, std::string binary)
      : dir_(std::move(dir)), binary_(std::move(binary)) {}
  NccompdProcess(const NccompdProcess&) = delete;
  NccompdProcess& operator=(const NccompdProcess&) = delete;
  /// A process still running is killed (SIGKILL) and reaped.
  ~NccompdProcess() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
  }

  /// Extra environment for the child ("NAME=value"), besides the test's own.
  std::vector<std::string> env;

  /// Starts `nccompd --config <dir>/<config> extra_args...`. Returns false (and the process is
  /// not running) if it could not be spawned.
  bool start(std::vector<std::string> extra_args = {}, const std::string& config = "nccompd.toml") {
    std::vector<std::string> args{binary_, "--config", (dir_ / config).string()};
    args.insert(args.end(), extra_args.begin(), extra_args.end());
    std::vector<char*> argv;
    for (auto& a : args) {
      argv.push_back(a.data());
    }
    argv.push_back(nullptr);
    std::vector<char*> envp;
    for (char** e = environ; *e != nullptr; ++e) {
      envp.push_back(*e);
    }
    for (auto& e : env) {
      envp.push_back(e.data());
    }
    envp.push_back(nullptr);
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    const std::string log_path = (dir_ / "nccompd.log").string();
    posix_spawn_file_actions_addopen(&fa, 1, log_path.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
    posix_spawn_file_actions_adddup2(&fa, 1, 2);
    const int rc = posix_spawn(&pid_, binary_.c_str(), &fa, nullptr, argv.data(), envp.data());
    posix_spawn_file_actions_destroy(&fa);
    if (rc != 0) {
      pid_ = -1;
      return false;
    }
    exit_status_.reset();
    return true;
  }

  /// Sends `sig`; false if there is no process to send it to.
  bool signal(int sig) const { return pid_ > 0 && ::kill(pid_, sig) == 0; }

  /// Waits for the process to end: its exit status, 128 + the signal if a signal ended it, -1 if
  /// it did not end within `limit` (it keeps running).
  int wait(std::chrono::milliseconds limit = std::chrono::seconds(30)) {
    if (exit_status_) {
      return *exit_status_;
    }
    const auto end = std::chrono::steady_clock::now() + limit;
    while (pid_ > 0) {
      if (reap(WNOHANG)) {
        return *exit_status_;
      }
      if (std::chrono::steady_clock::now() >= end) {
        return -1;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    return exit_status_.value_or(-1);
  }

  /// SIGTERM and the exit status (-1 if it did not end within `limit`).
  int stop(std::chrono::milliseconds limit = std::chrono::seconds(30)) {
    if (exit_status_) {
      return *exit_status_;
    }
    signal(SIGTERM);
    return wait(limit);
  }

  /// SIGKILL, as a crash or the systemd watchdog (no final state write), and reaped.
  void kill() {
    signal(SIGKILL);
    wait();
  }

  /// True while the process has not exited (an exited one is reaped; wait() gives its status).
  bool running() { return pid_ > 0 && !reap(WNOHANG); }

  [[nodiscard]] pid_t pid() const { return pid_; }
  [[nodiscard]] const std::filesystem::path& dir() const { return dir_; }
  [[nodiscard]] std::string socket() const { return (dir_ / "status.sock").string(); }

  /// One request on the status socket ("json", "text", "metrics" or an operator command); nullopt
  /// if the daemon did not answer (not up yet, gone) or answered nothing.
  [[nodiscard]] std::optional<std::string> try_status(const std::string& what = "json") const {
    try {
      auto s = nccomp::client::query(socket(), what);
      if (!s.empty()) {
        return s;
      }
    } catch (const std::exception&) {
    }
    return std::nullopt;
  }
  /// try_status(), "" when there was no answer.
  [[nodiscard]] std::string status(const std::string& what = "json") const {
    return try_status(what).value_or("");
  }

  /// Polls the status until pred(answer) holds or `limit` is up; the last answer either way.
  template <typename P>
  std::string wait_status(P pred, std::chrono::milliseconds limit = std::chrono::seconds(20),
                          const std::string& what = "json") const {
    const auto end = std::chrono::steady_clock::now() + limit;
    std::string last;
    while (std::chrono::steady_clock::now() < end) {
      if (auto s = try_status(what)) {
        last = std::move(*s);
        if (pred(last)) {
          return last;
        }
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return last;
  }

  /// Everything the process wrote so far.
  [[nodiscard]] std::string log() const {
    // Through a stringstream: GCC 12 at -O2 flags istreambuf_iterator (-Wnull-dereference).
    std::ifstream in(dir_ / "nccompd.log");
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
  }

 private:
  /// waitpid(options); true (and the status kept) if the process ended.
  bool reap(int options) {
    int st = 0;
    if (pid_ > 0 && ::waitpid(pid_, &st, options) == pid_) {
      exit_status_ = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
      pid_ = -1;
      return true;
    }
    return false;
  }

  std::filesystem::path dir_;
  std::string binary_;
  pid_t pid_{-1};
  std::optional<int> exit_status_;
};

}  // namespace nccomp::test
