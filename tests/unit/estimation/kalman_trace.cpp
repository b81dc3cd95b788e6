// Runs the level + rate Kalman filter of core/estimation on inputs read from stdin and prints
// every step, for kalman_vs_numpy.py (an independent implementation compares them).
//
// stdin: "q_level q_rate r gate x0 x1 p00 p01 p11", then one "d z" line per step (predict over
//        d, then update with z).
// stdout: per step "accepted normalized x0 x1 p00 p01 p11" (%.17g).
#include <cstdio>

#include "core/estimation/kalman.hpp"

int main() {
  using nccomp::core::estimation::KalmanFilter;
  double ql = 0, qr = 0, r = 0, gate = 0, x0 = 0, x1 = 0, p00 = 0, p01 = 0, p11 = 0;
  if (std::scanf("%lf %lf %lf %lf %lf %lf %lf %lf %lf", &ql, &qr, &r, &gate, &x0, &x1, &p00, &p01,
                 &p11) != 9) {
    std::fprintf(stderr, "kalman_trace: bad header\n");
    return 2;
  }
  KalmanFilter<2> kf;
  Eigen::Matrix2d p;
  p << p00, p01, p01, p11;
  kf.reset(Eigen::Vector2d(x0, x1), p);
  const Eigen::RowVector2d h(1.0, 0.0);
  double d = 0, z = 0;
  while (std::scanf("%lf %lf", &d, &z) == 2) {
    kf.predict(nccomp::core::estimation::cv_transition(d),
               nccomp::core::estimation::cv_process_noise(d, ql, qr));
    const auto res = kf.update(h, z, r, gate);
    const auto& x = kf.state();
    const auto& c = kf.covariance();
    std::printf("%d %.17g %.17g %.17g %.17g %.17g %.17g\n", res.accepted ? 1 : 0, res.normalized,
                x(0), x(1), c(0, 0), c(0, 1), c(1, 1));
  }
  return 0;
}
