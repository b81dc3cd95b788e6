// Fuzz target: sections split over included files (the loader's merge of tables across files:
// nested tables merged key by key, nested arrays of tables appended, anything else defined twice
// an error) and the located engine build. The input is cut at the first 0x00 byte (or in the
// middle) into a main file, which includes the second part as inc.toml, and that included file.
// Any bytes must end in a config or in diagnostics, never in a crash.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>

#include "daemon/config/builtin_sections.hpp"
#include "daemon/config/config.hpp"

namespace {

// One directory per process (in memory where /dev/shm exists), removed at exit.
std::filesystem::path base() {
  std::error_code ec;
  return std::filesystem::is_directory("/dev/shm", ec) ? std::filesystem::path("/dev/shm")
                                                       : std::filesystem::temp_directory_path();
}

struct Dir {
  Dir() : path(base() / ("nccomp_fuzz_include_" + std::to_string(::getpid()))) {
    std::filesystem::create_directories(path);
  }
  ~Dir() {
    std::error_code ec;
    std::filesystem::remove_all(path, ec);
  }
  std::filesystem::path path;
};

const std::filesystem::path& dir() {
  static const Dir d;
  return d.path;
}

void write(const std::filesystem::path& p, std::string_view text) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out.write(text.data(), static_cast<std::streamsize>(text.size()));
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  namespace cfg = nccomp::daemon::config;
  const std::string_view in(reinterpret_cast<const char*>(data), size);
  std::size_t cut = in.find('\0');
  if (cut == std::string_view::npos) {
    cut = size / 2;
  }
  const std::string_view main_part = in.substr(0, cut);
  const std::string_view inc_part = in.substr(cut < size ? cut + 1 : size);
  write(dir() / "main.toml", "include = [\"inc.toml\"]\n" + std::string(main_part));
  write(dir() / "inc.toml", inc_part);
  auto r = cfg::load_file((dir() / "main.toml").string());
  if (r.config) {
    nccomp::formats::Diagnostics diag;
    auto engine = cfg::build_engine(*r.config, diag);
    if (engine) {
      (void)engine->register_count();
    }
    for (const auto& d : diag.items()) {
      (void)nccomp::formats::format(d);
    }
  } else {
    for (const auto& d : r.diagnostics.items()) {
      (void)nccomp::formats::format(d);
    }
  }
  return 0;
}
