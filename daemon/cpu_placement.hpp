// Where nccompd's threads run: the loop thread on CPU(s) of its own, every other thread (bus
// I/O, logger, state persister, status server) on the rest of the CPUs the process may use, so
// that a busy bus or a status client never delays a cycle. By default the loop takes the highest
// allowed CPU; [daemon.realtime] cpu_affinity chooses its CPUs instead, and [modbus]
// io_cpu_affinity those of the Modbus I/O thread. On one CPU nothing can be separated: the
// daemon says so (the loop's latency target cannot be held there).
#pragma once

#include <span>
#include <string>
#include <vector>

namespace nccomp::daemon {

struct CpuPlacement {
  std::vector<int> loop_cpus;   ///< the loop thread's affinity; empty = not pinned
  std::vector<int> other_cpus;  ///< every other thread's; empty = not restricted
  bool separated{false};        ///< the two sets are disjoint and both non-empty
  bool warning{false};          ///< `message` is a warning (the loop shares its CPU(s))
  std::string message;          ///< what was chosen and why, for the log
};

/// Pure: the placement for the CPUs the process may use (`allowed`, ascending) and the loop's
/// configured cpu_affinity (empty = choose).
[[nodiscard]] CpuPlacement choose_cpu_placement(std::span<const int> allowed,
                                                std::span<const int> configured_loop);

/// The CPUs this process may run on now (sched_getaffinity), ascending.
[[nodiscard]] std::vector<int> allowed_cpus();

/// Restricts the calling thread, and so every thread it starts afterwards, to `cpus` (nothing if
/// empty). Returns 0 or the errno.
int restrict_calling_thread(std::span<const int> cpus);

/// run_daemon's call, before it starts any thread: chooses from allowed_cpus(), restricts the
/// calling thread to the other CPUs, logs what was chosen; returns the loop thread's CPUs
/// (LoopOptions::cpu_affinity). Not real-time.
[[nodiscard]] std::vector<int> place_threads(std::span<const int> configured_loop);

}  // namespace nccomp::daemon
