#include "daemon/cpu_placement.hpp"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <pthread.h>
#include <sched.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstring>

namespace nccomp::daemon {

CpuPlacement choose_cpu_placement(std::span<const int> allowed,
                                  std::span<const int> configured_loop) {
  CpuPlacement p;
  if (!configured_loop.empty()) {
    p.loop_cpus.assign(configured_loop.begin(), configured_loop.end());
  } else if (allowed.size() >= 2) {
    p.loop_cpus = {allowed.back()};
  }
  for (int c : allowed) {
    if (std::find(p.loop_cpus.begin(), p.loop_cpus.end(), c) == p.loop_cpus.end()) {
      p.other_cpus.push_back(c);
    }
  }
  p.separated = !p.loop_cpus.empty() && !p.other_cpus.empty();
  const std::string loop = fmt::format("{}", fmt::join(p.loop_cpus, ","));
  const std::string others = fmt::format("{}", fmt::join(p.other_cpus, ","));
  const std::string all = fmt::format("{}", fmt::join(allowed, ","));
  if (p.separated) {
    p.message = fmt::format(
        "CPU placement: loop thread on CPU {} ({}), the other threads (bus I/O, log, state, "
        "status) on CPU {} (this process may use CPU {})",
        loop, configured_loop.empty() ? "the highest allowed" : "[daemon.realtime] cpu_affinity",
        others, all);
  } else if (allowed.size() <= 1) {
    p.warning = true;
    p.message = fmt::format(
        "CPU placement: this process may use one CPU ({}): the loop thread shares it with the bus "
        "I/O threads, and its latency target cannot be held; give nccompd two or more CPUs "
        "(systemd CPUAffinity=, the cpuset)",
        allowed.empty() ? std::string("none known") : all);
  } else {
    p.warning = true;
    p.message = fmt::format(
        "CPU placement: [daemon.realtime] cpu_affinity = [{}] leaves no CPU of {} to the other "
        "threads: the bus I/O threads share the loop's CPU(s)",
        loop, all);
  }
  return p;
}

std::vector<int> allowed_cpus() {
  cpu_set_t set;
  CPU_ZERO(&set);
  std::vector<int> cpus;
  if (sched_getaffinity(0, sizeof set, &set) != 0) {
    return cpus;
  }
  for (int c = 0; c < CPU_SETSIZE; ++c) {
    if (CPU_ISSET(static_cast<std::size_t>(c), &set)) {
      cpus.push_back(c);
    }
  }
  return cpus;
}

int restrict_calling_thread(std::span<const int> cpus) {
  if (cpus.empty()) {
    return 0;
  }
  cpu_set_t set;
  CPU_ZERO(&set);
  for (int c : cpus) {
    if (c >= 0 && c < CPU_SETSIZE) {
      CPU_SET(static_cast<std::size_t>(c), &set);
    }
  }
  return pthread_setaffinity_np(pthread_self(), sizeof set, &set);
}

std::vector<int> place_threads(std::span<const int> configured_loop) {
  const std::vector<int> allowed = allowed_cpus();
  const CpuPlacement p = choose_cpu_placement(allowed, configured_loop);
  spdlog::log(p.warning ? spdlog::level::warn : spdlog::level::info, "{}", p.message);
  if (p.separated) {
    if (const int err = restrict_calling_thread(p.other_cpus); err != 0) {
      spdlog::warn("CPU placement: the other threads could not be restricted to CPU {}: {}",
                   fmt::join(p.other_cpus, ","), std::strerror(err));
    }
  }
  return p.loop_cpus;
}

}  // namespace nccomp::daemon
