// Polls a condition until it holds or a time limit passes: for tests that watch another process
// or thread (status counters, files, registers) change. Not for timing: a test asserts what
// happened, never how fast.
#pragma once

#include <chrono>
#include <thread>

namespace nccomp::test {

/// True as soon as `pred()` is; else, after `limit`, what a last `pred()` says.
template <typename Pred>
bool wait_until(Pred&& pred, std::chrono::milliseconds limit = std::chrono::seconds(10),
                std::chrono::milliseconds poll = std::chrono::milliseconds(5)) {
  const auto end = std::chrono::steady_clock::now() + limit;
  while (std::chrono::steady_clock::now() < end) {
    if (pred()) return true;
    std::this_thread::sleep_for(poll);
  }
  return pred();
}

}  // namespace nccomp::test
