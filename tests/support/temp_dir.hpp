// A fresh directory for one test under the system's temporary directory, removed with
// everything in it when the test ends. Its name carries the process id and a counter, so tests
// running in parallel (ctest -j) and several directories of one test never meet.
#pragma once

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <utility>

namespace nccomp::test {

struct TempDir {
  explicit TempDir(const std::string& prefix = "nccomp_test") {
    path = std::filesystem::temp_directory_path() /
           (prefix + "_" + std::to_string(::getpid()) + "_" + std::to_string(counter()++));
    std::filesystem::remove_all(path);
    std::filesystem::create_directories(path);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  ~TempDir() {
    std::error_code ignored;
    std::filesystem::remove_all(path, ignored);
  }
  /// Writes `text` to the file `name` in the directory; returns its path.
  std::string write(const std::string& name, const std::string& text) const {
    std::ofstream(path / name) << text;
    return (path / name).string();
  }
  std::filesystem::path path;

 private:
  static int& counter() {
    static int n = 0;
    return n;
  }
};

}  // namespace nccomp::test
