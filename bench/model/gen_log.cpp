// Writes a generated measurement log (v1 CSV) for the `nccomp analyze` benchmark:
//   bench_model_gen ROWS OUT.csv [effect ...]
// Rows come from the generator of the analysis tests (irregular part times, tool changes,
// random probe positions), 20 checkpoints per part, probe noise 0.5 µm.
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
  const auto data = nccomp::test::synth::generate(opt);
  std::ofstream out(argv[2]);
  nccomp::test::synth::write_csv(out, data);
  std::printf("wrote %zu rows to %s\n", data.rows(), argv[2]);
  return out ? 0 : 1;
}
