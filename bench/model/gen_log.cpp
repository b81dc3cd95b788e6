// Writes a generated measurement log (v1 CSV) for the `nccomp analyze` benchmark:
//   bench_model_gen ROWS OUT.csv [effect ...]
// Rows come from the generator of the analysis tests (irregular part times, tool changes,
// random probe positions), 20 checkpoints per part, probe noise 0.5 µm. With the effect
// wear_proportional the log also has a laser measurement of the tool after every part
// (bench_config_wear.toml declares its wear curve).
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>

#include "tests/unit/model/synth.hpp"

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: %s ROWS OUT.csv [effect ...]\n", argv[0]);
    return 2;
  }
  nccomp::test::synth::Options opt;
  opt.points_per_part = 20;
  opt.parts = std::strtoul(argv[1], nullptr, 10) / opt.points_per_part;
  opt.noise_um = 0.5;
  for (int i = 3; i < argc; ++i) opt.effects.emplace_back(argv[i]);
  // The tool-wear effect needs the laser measurements of the tool it is proportional to.
  for (const auto& e : opt.effects)
    opt.tool_wear_rows = opt.tool_wear_rows || e == "wear_proportional";
  const auto data = nccomp::test::synth::generate(opt);
  std::ofstream out(argv[2]);
  nccomp::test::synth::write_csv(out, data);
  std::printf("wrote %zu rows to %s\n", data.rows(), argv[2]);
  return out ? 0 : 1;
}
