// Test helper of the grind tests: a profile sampled from a function on a uniform grid.
#pragma once

#include <cstddef>
#include <vector>

#include "core/grind/profile.hpp"

namespace nccomp::core::grind::test {

/// u_i = fn(z0 + i·dz), i = 0 … n − 1.
UniformProfile sampled(double z0, double dz, std::size_t n, auto&& fn) {
  UniformProfile p{z0, dz, std::vector<double>(n)};
  for (std::size_t i = 0; i < n; ++i) {
    p.u_mm[i] = fn(p.z_at(static_cast<std::ptrdiff_t>(i)));
  }
  return p;
}

}  // namespace nccomp::core::grind::test
