// Fuzz target: the model.toml a [model] section loads (written to a temporary file, then the
// section is parsed with a fixed [[model.apply]]), and the ModelModule stepping on it. Any bytes
// must end in diagnostics or in a module that attaches and steps, never in a crash.
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <memory>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include <toml++/toml.h>

#include "core/engine/engine.hpp"
#include "daemon/sections/model/model_section.hpp"
#include "formats/toml/guard.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  namespace cfg = nccomp::daemon::config;
  namespace core = nccomp::core;
  static const std::string dir = "/tmp/nccomp_fuzz_model_" + std::to_string(::getpid());
  static const bool made = [] { return ::mkdir(dir.c_str(), 0700) == 0 || errno == EEXIST; }();
  // Removed when the fuzz driver exits (no directory left behind in /tmp per run).
  struct Cleanup {
    ~Cleanup() { std::filesystem::remove_all(dir); }
  };
  static const Cleanup cleanup;
  if (!made) return 0;
  {
    std::ofstream f(dir + "/model.toml", std::ios::binary | std::ios::trunc);
    f.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  }
  const std::string daemon_text =
      "[model]\nfile = \"model.toml\"\nupdate = \"cycle\"\n"
      "[[model.apply]]\nterm = \"part_trend\"\nregister = \"r0\"\npoint = 0\n";
  toml::table root;
  try {
    root = nccomp::formats::parse_toml(daemon_text, std::string_view(dir + "/nccompd.toml"));
  } catch (const toml::parse_error&) {
    return 0;
  }
  nccomp::formats::Diagnostics diag;
  auto section = nccomp::daemon::sections::parse_model_section(*root.get("model"), diag);
  for (const auto& d : diag.items()) (void)nccomp::formats::format(d);
  if (!diag.ok()) return 0;
  const core::LimiterConfig lim{100.0, 10.0, 1000.0};
  std::vector<core::engine::RegisterSpec> regs{
      {"r0", core::engine::RegisterKind::kCheckpoint, lim}};
  std::vector<std::unique_ptr<core::engine::Module>> mods;
  try {
    mods.push_back(nccomp::daemon::sections::make_model_module(*section, regs));
  } catch (const std::invalid_argument&) {
    return 0;
  }
  core::engine::Engine e;
  e.configure(regs, std::move(mods));
  core::StepOutput out;
  for (std::int32_t part = 1; part <= 4; ++part) {
    const std::vector<core::Event> ev = {
        core::ProgramEvent{part * 1'000'000'000LL, core::ProgramEventKind::kPartStart, part},
        core::TemperatureSample{part * 1'000'000'000LL, 0, 20.0 + part}};
    e.step(part * 1'000'000'000LL, ev, out);
  }
  return 0;
}
