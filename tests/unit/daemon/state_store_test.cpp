// GIVEN the state file format, WHEN a file is truncated, extended or has any bit flipped, THEN
// it is reported corrupt (never silently accepted); writes are atomic and leave no temp file.
#include "daemon/state_store.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <thread>
#include <vector>

namespace nccomp::daemon {
namespace {

namespace fs = std::filesystem;

struct Dir {
  Dir() {
    path = fs::temp_directory_path() /
           ("nccomp_state_" + std::to_string(::getpid()) + "_" + std::to_string(n++));
    fs::create_directories(path);
  }
  ~Dir() { fs::remove_all(path); }
  static inline int n = 0;
  fs::path path;
};

std::vector<std::byte> bytes_of(const std::string& s) {
  std::vector<std::byte> b(s.size());
  std::memcpy(b.data(), s.data(), s.size());
  return b;
}

std::vector<char> read_all(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void write_raw(const fs::path& p, const std::vector<char>& raw) {
  std::ofstream(p, std::ios::binary | std::ios::trunc)
      .write(raw.data(), static_cast<std::streamsize>(raw.size()));
}

TEST(Crc32, MatchesTheStandardCheckValue) {
  EXPECT_EQ(crc32(bytes_of("123456789")), 0xCBF43926U);
  EXPECT_EQ(crc32({}), 0U);
  EXPECT_EQ(crc32(bytes_of("56789"), crc32(bytes_of("1234"))), 0xCBF43926U);
}

TEST(StateFile, RoundTripAndAbsent) {
  Dir d;
  const auto p = (d.path / "state.bin").string();
  EXPECT_EQ(read_state_file(p).status, StateFileStatus::kAbsent);
  write_state_file(p, bytes_of("engine state"), 42);
  const auto f = read_state_file(p);
  ASSERT_EQ(f.status, StateFileStatus::kOk) << f.reason;
  EXPECT_EQ(f.sequence, 42U);
  EXPECT_EQ(f.payload, bytes_of("engine state"));
  EXPECT_FALSE(fs::exists(p + ".tmp"));
  // Overwriting replaces the content.
  write_state_file(p, bytes_of("newer"), 43);
  EXPECT_EQ(read_state_file(p).payload, bytes_of("newer"));
}

TEST(StateFile, EveryTruncationIsCorrupt) {
  Dir d;
  const auto p = d.path / "state.bin";
  write_state_file(p.string(), bytes_of("some engine state bytes"), 7);
  const auto raw = read_all(p);
  for (std::size_t len = 0; len < raw.size(); ++len) {
    write_raw(p, std::vector<char>(raw.begin(), raw.begin() + static_cast<long>(len)));
    const auto f = read_state_file(p.string());
    EXPECT_EQ(f.status, StateFileStatus::kCorrupt) << len;
    EXPECT_FALSE(f.reason.empty());
  }
  auto longer = raw;
  longer.push_back('x');
  write_raw(p, longer);
  EXPECT_EQ(read_state_file(p.string()).status, StateFileStatus::kCorrupt);
}

TEST(StateFile, EveryBitFlipIsCorrupt) {
  Dir d;
  const auto p = d.path / "state.bin";
  write_state_file(p.string(), bytes_of("abc"), 1);
  const auto raw = read_all(p);
  for (std::size_t i = 0; i < raw.size(); ++i) {
    for (int bit = 0; bit < 8; ++bit) {
      auto bad = raw;
      bad[i] = static_cast<char>(bad[i] ^ (1 << bit));
      write_raw(p, bad);
      ASSERT_EQ(read_state_file(p.string()).status, StateFileStatus::kCorrupt)
          << "byte " << i << " bit " << bit;
    }
  }
}

TEST(StateFile, ReasonsNameTheProblem) {
  Dir d;
  const auto p = d.path / "state.bin";
  write_raw(p, {'h', 'e', 'l', 'l', 'o'});
  EXPECT_NE(read_state_file(p.string()).reason.find("truncated"), std::string::npos);
  write_state_file(p.string(), bytes_of("abcdef"), 1);
  auto raw = read_all(p);
  raw.back() = 'X';
  write_raw(p, raw);
  EXPECT_NE(read_state_file(p.string()).reason.find("checksum mismatch"), std::string::npos);
}

// A file whose checksum covers bytes beyond the payload size its header states (a writer that
// appended after the header was made, two files run together): the checksum alone cannot tell,
// the size field does. Refused, whatever the extra bytes are.
TEST(StateFile, ExtraBytesUnderAValidChecksumAreRefusedBySize) {
  Dir d;
  const auto p = d.path / "state.bin";
  write_state_file(p.string(), bytes_of("engine state plus more"), 5);
  auto raw = read_all(p);
  ASSERT_EQ(raw.size(), 32U + 22U);
  // The header now says 12 payload bytes ("engine state"); the checksum is made right again over
  // everything from the size field on (the file's checksum range, bytes 16..end).
  const std::uint64_t size = 12;
  std::memcpy(raw.data() + 16, &size, 8);
  const std::uint32_t crc = crc32(std::span<const std::byte>(
      reinterpret_cast<const std::byte*>(raw.data()) + 16, raw.size() - 16));
  std::memcpy(raw.data() + 12, &crc, 4);
  write_raw(p, raw);
  const auto f = read_state_file(p.string());
  EXPECT_EQ(f.status, StateFileStatus::kCorrupt);
  EXPECT_TRUE(f.payload.empty());
  EXPECT_NE(f.reason.find("size mismatch"), std::string::npos) << f.reason;
}

TEST(StateFile, WriteIntoMissingDirectoryThrowsNamingThePath) {
  try {
    write_state_file("/nonexistent-nccomp/state.bin", bytes_of("x"), 1);
    FAIL();
  } catch (const std::system_error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent-nccomp/state.bin.tmp"), std::string::npos);
  }
}

TEST(StatePersister, WritesTheNewestQueuedBlob) {
  Dir d;
  const auto p = (d.path / "state.bin").string();
  StatePersister ps(p, 64, 4);
  ps.start(10);
  for (int k = 0; k < 3; ++k) {
    auto* b = ps.acquire();
    ASSERT_NE(b, nullptr);
    const std::string s = "state " + std::to_string(k);
    std::memcpy(b->data.data(), s.data(), s.size());
    b->size = s.size();
    ps.submit(b);
  }
  ps.stop();
  const auto f = read_state_file(p);
  ASSERT_EQ(f.status, StateFileStatus::kOk);
  EXPECT_EQ(f.payload, bytes_of("state 2"));
  EXPECT_GT(f.sequence, 10U);
  EXPECT_GE(ps.stats().writes, 1U);
  EXPECT_EQ(ps.stats().failures, 0U);
}

}  // namespace
}  // namespace nccomp::daemon
