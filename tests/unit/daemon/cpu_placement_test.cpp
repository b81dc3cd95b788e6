// GIVEN the CPUs a process may use and the loop's configured cpu_affinity, WHEN nccompd places
// its threads, THEN the loop gets CPU(s) of its own and every other thread the rest; on one CPU,
// or with the loop configured onto every CPU, it warns that they share. A thread restricted to
// the others' CPUs passes that on to the threads it starts (the bus I/O threads).
#include "daemon/cpu_placement.hpp"

#include <gtest/gtest.h>
#include <pthread.h>
#include <sched.h>

#include <thread>
#include <vector>

namespace nccomp::daemon {
namespace {

using Cpus = std::vector<int>;

TEST(CpuPlacement, TwoOrMoreCpusSeparateTheLoopOnTheHighest) {
  const CpuPlacement two = choose_cpu_placement(Cpus{0, 1}, Cpus{});
  EXPECT_EQ(two.loop_cpus, Cpus{1});
  EXPECT_EQ(two.other_cpus, Cpus{0});
  EXPECT_TRUE(two.separated);
  EXPECT_FALSE(two.warning);
  EXPECT_EQ(two.message,
            "CPU placement: loop thread on CPU 1 (the highest allowed), the other threads (bus "
            "I/O, log, state, status) on CPU 0 (this process may use CPU 0,1)");

  const CpuPlacement sparse = choose_cpu_placement(Cpus{2, 5, 7}, Cpus{});
  EXPECT_EQ(sparse.loop_cpus, Cpus{7});
  EXPECT_EQ(sparse.other_cpus, (Cpus{2, 5}));
  EXPECT_TRUE(sparse.separated);
}

TEST(CpuPlacement, TheConfiguredLoopCpusWinAndTheOthersGetTheRest) {
  const CpuPlacement p = choose_cpu_placement(Cpus{0, 1, 2, 3}, Cpus{0, 2});
  EXPECT_EQ(p.loop_cpus, (Cpus{0, 2}));
  EXPECT_EQ(p.other_cpus, (Cpus{1, 3}));
  EXPECT_TRUE(p.separated);
  EXPECT_NE(p.message.find("loop thread on CPU 0,2 ([daemon.realtime] cpu_affinity)"),
            std::string::npos)
      << p.message;
  // A configured CPU the process may not use stays (the loop reports the refusal); the others
  // keep every allowed CPU.
  const CpuPlacement outside = choose_cpu_placement(Cpus{0, 1}, Cpus{6});
  EXPECT_EQ(outside.loop_cpus, Cpus{6});
  EXPECT_EQ(outside.other_cpus, (Cpus{0, 1}));
}

TEST(CpuPlacement, OneCpuSaysTheTargetCannotBeHeld) {
  const CpuPlacement p = choose_cpu_placement(Cpus{3}, Cpus{});
  EXPECT_TRUE(p.loop_cpus.empty());
  EXPECT_EQ(p.other_cpus, Cpus{3});
  EXPECT_FALSE(p.separated);
  EXPECT_TRUE(p.warning);
  EXPECT_NE(p.message.find("may use one CPU (3)"), std::string::npos) << p.message;
  EXPECT_NE(p.message.find("latency target cannot be held"), std::string::npos) << p.message;
}

TEST(CpuPlacement, TheLoopConfiguredOnEveryCpuSharesWithAWarning) {
  const CpuPlacement p = choose_cpu_placement(Cpus{0, 1}, Cpus{0, 1});
  EXPECT_EQ(p.loop_cpus, (Cpus{0, 1}));
  EXPECT_TRUE(p.other_cpus.empty());
  EXPECT_FALSE(p.separated);
  EXPECT_TRUE(p.warning);
  EXPECT_NE(p.message.find("leaves no CPU of 0,1 to the other threads"), std::string::npos)
      << p.message;
}

Cpus affinity_of_this_thread() {
  cpu_set_t set;
  CPU_ZERO(&set);
  Cpus cpus;
  if (pthread_getaffinity_np(pthread_self(), sizeof set, &set) != 0) return cpus;
  for (int c = 0; c < CPU_SETSIZE; ++c) {
    if (CPU_ISSET(static_cast<std::size_t>(c), &set)) cpus.push_back(c);
  }
  return cpus;
}

// On this machine: a thread that applied the placement for the others, and a thread it starts
// afterwards, run only on the others' CPUs.
TEST(CpuPlacement, ThreadsStartedAfterTheRestrictionInheritIt) {
  const Cpus allowed = allowed_cpus();
  if (allowed.size() < 2) {
    GTEST_SKIP() << "needs 2 or more CPUs, this process may use " << allowed.size();
  }
  const CpuPlacement p = choose_cpu_placement(allowed, Cpus{});
  ASSERT_TRUE(p.separated);
  Cpus own;
  Cpus child;
  int err = -1;
  std::thread main_like([&] {
    err = restrict_calling_thread(p.other_cpus);
    own = affinity_of_this_thread();
    std::thread io_like([&] { child = affinity_of_this_thread(); });
    io_like.join();
  });
  main_like.join();
  EXPECT_EQ(err, 0);
  EXPECT_EQ(own, p.other_cpus);
  EXPECT_EQ(child, p.other_cpus);
  // The test's own thread is untouched.
  EXPECT_EQ(affinity_of_this_thread(), allowed);
}

}  // namespace
}  // namespace nccomp::daemon
