// B of a whole roll is N doubles (160 MB at 2·10⁷ samples): the functions that compute it sample
// by sample hand it on in consecutive chunks instead (envelope.hpp, verify_grid.hpp). This is
// the buffer between the two, and the collector for callers that do want the array.
#pragma once

#include <algorithm>
#include <cstddef>
#include <functional>
#include <span>
#include <vector>

namespace nccomp::core::grind {

/// Receives samples first .. first + b.size() − 1 of B.
using ChunkVisitor = std::function<void(std::size_t first, std::span<const double> b_mm)>;

/// Collects values pushed one at a time and hands them to `visit` 16,384 at a time; finish()
/// hands on the rest. Not real-time (one allocation of the chunk).
class ChunkBuffer {
 public:
  ChunkBuffer(std::size_t total, const ChunkVisitor& visit)
      : visit_(visit), chunk_(std::min(kChunk, total)) {}

  void push(double v) {
    chunk_[fill_++] = v;
    if (fill_ == chunk_.size()) {
      flush();
    }
  }
  void finish() {
    if (fill_ > 0) {
      flush();
    }
  }

 private:
  static constexpr std::size_t kChunk = std::size_t{1} << 14;
  void flush() {
    visit_(first_, std::span<const double>(chunk_.data(), fill_));
    first_ += fill_;
    fill_ = 0;
  }
  const ChunkVisitor& visit_;
  std::vector<double> chunk_;
  std::size_t first_{0};
  std::size_t fill_{0};
};

/// The chunks a producer hands to its visitor, as one array of `total` values.
template <class Produce>
std::vector<double> collect_chunks(std::size_t total, Produce&& produce) {
  std::vector<double> b(total);
  produce([&b](std::size_t first, std::span<const double> chunk) {
    std::copy(chunk.begin(), chunk.end(), b.begin() + static_cast<std::ptrdiff_t>(first));
  });
  return b;
}

}  // namespace nccomp::core::grind
