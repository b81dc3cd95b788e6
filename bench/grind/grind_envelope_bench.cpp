// Whole-process benchmark of the exact envelope U_T(Z) = max_{|s|≤W/2} [P(Z+s) − g(s)] at the
// seed's sampling (0.0001 mm): a 2,000 mm roll is 2·10⁷ samples, the 150 mm wheel spans 1.5·10⁶.
// Peer in the same run: memcpy of the same bytes (the input array) into a pre-faulted buffer,
// the physical limit of any one-pass algorithm. Peak memory: getrusage max RSS, read right after
// the envelope (before the peer's buffer exists) and at the end.
//
//   bench_grind_envelope [length_mm=2000] [spacing_mm=0.0001] [width_mm=150] [height_mm=0.5]
//                        [repeats=3] [spot_checks=40] [profile=crown|sine|noise]
#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "core/grind/envelope.hpp"
#include "core/grind/local_rule.hpp"
#include "core/grind/profile.hpp"
#include "core/grind/wheel.hpp"

namespace {

namespace g = nccomp::core::grind;

double now_s() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

long max_rss_kib() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_maxrss;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  const double length_mm = argc > 1 ? std::atof(argv[1]) : 2000.0;
  const double spacing_mm = argc > 2 ? std::atof(argv[2]) : 0.0001;
  const double width_mm = argc > 3 ? std::atof(argv[3]) : 150.0;
  const double height_mm = argc > 4 ? std::atof(argv[4]) : 0.5;
  const int repeats = argc > 5 ? std::atoi(argv[5]) : 3;
  const int spot_checks = argc > 6 ? std::atoi(argv[6]) : 40;
  const std::string shape = argc > 7 ? argv[7] : "crown";

  g::FamilySpec spec;
  spec.z_from_mm = -0.5 * length_mm;
  spec.z_to_mm = 0.5 * length_mm;
  spec.spacing_mm = spacing_mm;
  if (shape == "sine") {
    spec.family = g::Family::kSine;
    spec.amplitude_mm = 0.05;
    spec.wavelength_mm = 40.0;
  } else {
    spec.family = g::Family::kConvexCrown;
    spec.height_mm = 0.6;
  }
  g::UniformProfile p = g::generate_profile(spec);
  if (shape == "noise") {  // crown plus 1 µm white noise: many small caps compete
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> noise(-0.5e-3, 0.5e-3);
    for (double& u : p.u_mm) {
      u += noise(rng);
    }
  }
  const auto wheel = g::Wheel::from_arc_height(width_mm, height_mm);
  const std::ptrdiff_t m = g::half_window_samples(wheel, spacing_mm);
  const std::size_t n = p.size();
  const std::size_t n_out = n + 2 * static_cast<std::size_t>(m);
  std::printf(
      "profile %s: %zu samples (%.1f MB), spacing %g mm; wheel W %g mm h %g mm "
      "(R %.2f mm), window %td samples each side\n",
      shape.c_str(), n, static_cast<double>(n * sizeof(double)) / 1e6, spacing_mm, width_mm,
      height_mm, wheel.radius_mm(), m);
  const long rss_input_kib = max_rss_kib();

  std::vector<double> out(n_out, 0.0);  // pre-faulted: the algorithm is timed, not the kernel
  g::EnvelopeScratch scratch;
  std::vector<double> t_env;
  for (int r = 0; r < repeats; ++r) {
    const double t0 = now_s();
    g::max_plus_arc(p.u_mm, spacing_mm, wheel, -m, out, scratch);
    t_env.push_back(now_s() - t0);
  }
  const long rss_envelope_kib = max_rss_kib();

  // Spot checks against brute force (O(M) each).
  std::mt19937_64 rng(1);
  std::uniform_int_distribution<std::size_t> pick(0, n_out - 1);
  double worst = 0.0;
  std::vector<double> one(1);
  for (int c = 0; c < spot_checks; ++c) {
    const std::size_t q = pick(rng);
    g::max_plus_arc_brute(p.u_mm, spacing_mm, wheel, -m + static_cast<std::ptrdiff_t>(q), one);
    worst = std::max(worst, std::abs(one[0] - out[q]));
  }

  std::vector<double> peer(n, 0.0);
  std::vector<double> t_copy;
  for (int r = 0; r < repeats; ++r) {
    const double t0 = now_s();
    std::memcpy(peer.data(), p.u_mm.data(), n * sizeof(double));
    t_copy.push_back(now_s() - t0);
  }
  if (std::memcmp(peer.data(), p.u_mm.data(), n * sizeof(double)) != 0) {  // copy is observable
    return 2;
  }

  const double te = median(t_env);
  const double tc = median(t_copy);
  std::printf(
      "exact envelope (O(N) deque): median %.3f s of %d (min %.3f), %.1f M samples/s, "
      "%.2f ns/sample\n",
      te, repeats, *std::min_element(t_env.begin(), t_env.end()), static_cast<double>(n) / te / 1e6,
      te / static_cast<double>(n) * 1e9);
  std::printf("memcpy peer (%.1f MB):      median %.4f s, %.1f M samples/s, %.2f GB/s\n",
              static_cast<double>(n * sizeof(double)) / 1e6, tc, static_cast<double>(n) / tc / 1e6,
              static_cast<double>(n * sizeof(double)) / tc / 1e9);
  std::printf("ratio envelope / memcpy: %.1f\n", te / tc);
  std::printf("spot checks against brute force: %d points, max |fast - brute| = %.3g mm\n",
              spot_checks, worst);
  std::printf(
      "peak RSS: %.1f MiB after the input, %.1f MiB after the envelope (input + output + "
      "deque scratch %.1f MiB), %.1f MiB at the end (with the peer's buffer)\n",
      static_cast<double>(rss_input_kib) / 1024.0, static_cast<double>(rss_envelope_kib) / 1024.0,
      static_cast<double>(scratch.index.size() * 2 * sizeof(std::ptrdiff_t)) / 1048576.0,
      static_cast<double>(max_rss_kib()) / 1024.0);
  return 0;
}
