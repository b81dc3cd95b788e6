#include "daemon/state_store.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <system_error>

namespace nccomp::daemon {

namespace {

constexpr std::array<char, 8> kMagic{'N', 'C', 'C', 'O', 'M', 'P', 'S', 'T'};
constexpr std::uint32_t kFormatVersion = 1;
// magic 8 + version 4 + crc 4 + size 8 + sequence 8
constexpr std::size_t kHeaderBytes = 32;
constexpr std::size_t kCrcFrom = 16;
constexpr std::uint64_t kMaxPayloadBytes = std::uint64_t{1} << 30;

constexpr std::array<std::uint32_t, 256> make_crc_table() {
  std::array<std::uint32_t, 256> t{};
  for (std::uint32_t i = 0; i < 256; ++i) {
    std::uint32_t c = i;
    for (int k = 0; k < 8; ++k) {
      c = (c & 1U) != 0 ? 0xEDB88320U ^ (c >> 1) : c >> 1;
    }
    t[i] = c;
  }
  return t;
}
constexpr auto kCrcTable = make_crc_table();

[[noreturn]] void fail(const std::string& what, const std::string& path) {
  throw std::system_error(errno, std::generic_category(), what + " '" + path + "'");
}

void write_all(int fd, const std::byte* p, std::size_t n, const std::string& path) {
  while (n > 0) {
    const ssize_t w = ::write(fd, p, n);
    if (w < 0) {
      if (errno == EINTR) {
        continue;
      }
      fail("cannot write", path);
    }
    p += w;
    n -= static_cast<std::size_t>(w);
  }
}

}  // namespace

std::uint32_t crc32(std::span<const std::byte> bytes, std::uint32_t previous) noexcept {
  std::uint32_t c = previous ^ 0xFFFFFFFFU;
  for (std::byte b : bytes) {
    c = kCrcTable[(c ^ static_cast<std::uint32_t>(b)) & 0xFFU] ^ (c >> 8);
  }
  return c ^ 0xFFFFFFFFU;
}

StateFile read_state_file(const std::string& path) {
  StateFile out;
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    return out;
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    out.status = StateFileStatus::kCorrupt;
    out.reason = "cannot open for reading: " + std::string(std::strerror(errno));
    return out;
  }
  std::vector<char> raw((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  out.status = StateFileStatus::kCorrupt;
  if (raw.size() < kHeaderBytes) {
    out.reason = "truncated: " + std::to_string(raw.size()) + " bytes, header needs " +
                 std::to_string(kHeaderBytes);
    return out;
  }
  if (std::memcmp(raw.data(), kMagic.data(), kMagic.size()) != 0) {
    out.reason = "not an nccompd state file (bad magic)";
    return out;
  }
  std::uint32_t version = 0;
  std::uint32_t crc = 0;
  std::uint64_t size = 0;
  std::memcpy(&version, raw.data() + 8, 4);
  std::memcpy(&crc, raw.data() + 12, 4);
  std::memcpy(&size, raw.data() + 16, 8);
  std::memcpy(&out.sequence, raw.data() + 24, 8);
  if (version != kFormatVersion) {
    out.reason = "unsupported format version " + std::to_string(version);
    return out;
  }
  if (size > kMaxPayloadBytes || raw.size() != kHeaderBytes + size) {
    out.reason = "size mismatch: header says " + std::to_string(size) +
                 " payload bytes, file has " + std::to_string(raw.size() - kHeaderBytes) +
                 " (truncated or appended)";
    return out;
  }
  const auto* bytes = reinterpret_cast<const std::byte*>(raw.data());
  const std::uint32_t actual =
      crc32(std::span<const std::byte>(bytes + kCrcFrom, raw.size() - kCrcFrom));
  if (actual != crc) {
    char buf[96];
    std::snprintf(buf, sizeof buf, "checksum mismatch: stored %08x, computed %08x", crc, actual);
    out.reason = buf;
    return out;
  }
  out.payload.assign(bytes + kHeaderBytes, bytes + raw.size());
  out.status = StateFileStatus::kOk;
  return out;
}

void write_state_file(const std::string& path, std::span<const std::byte> payload,
                      std::uint64_t sequence) {
  // Header and payload are written separately: the payload is never copied.
  std::array<std::byte, kHeaderBytes> header{};
  std::memcpy(header.data(), kMagic.data(), kMagic.size());
  std::memcpy(header.data() + 8, &kFormatVersion, 4);
  const std::uint64_t size = payload.size();
  std::memcpy(header.data() + 16, &size, 8);
  std::memcpy(header.data() + 24, &sequence, 8);
  const std::uint32_t crc =
      crc32(payload,
            crc32(std::span<const std::byte>(header.data() + kCrcFrom, kHeaderBytes - kCrcFrom)));
  std::memcpy(header.data() + 12, &crc, 4);

  const std::string tmp = path + ".tmp";
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0640);
  if (fd < 0) {
    fail("cannot create", tmp);
  }
  try {
    write_all(fd, header.data(), header.size(), tmp);
    write_all(fd, payload.data(), payload.size(), tmp);
    if (::fsync(fd) != 0) {
      fail("cannot fsync", tmp);
    }
  } catch (...) {
    ::close(fd);
    throw;
  }
  if (::close(fd) != 0) {
    fail("cannot close", tmp);
  }
  if (::rename(tmp.c_str(), path.c_str()) != 0) {
    fail("cannot rename over", path);
  }
  // The rename is durable only once the directory entry is on disk.
  const std::filesystem::path parent = std::filesystem::path(path).parent_path();
  const std::string dir = parent.empty() ? std::string(".") : parent.string();
  const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd < 0) {
    fail("cannot open directory", dir);
  }
  const int rc = ::fsync(dfd);
  ::close(dfd);
  if (rc != 0) {
    fail("cannot fsync directory", dir);
  }
}

StatePersister::StatePersister(std::string path, std::size_t blob_bytes, std::size_t blobs)
    : path_(std::move(path)), blob_bytes_(blob_bytes), free_(blobs), full_(blobs) {
  for (std::size_t i = 0; i < blobs; ++i) {
    auto b = std::make_unique<Blob>();
    b->data.resize(blob_bytes);
    (void)free_.try_push(b.get());
    pool_.push_back(std::move(b));
  }
}

StatePersister::~StatePersister() { stop(); }

void StatePersister::start(std::uint64_t first_sequence) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    stats_.sequence = first_sequence;
  }
  stop_.store(false);
  thread_ = std::thread([this] { run(); });
}

void StatePersister::stop() {
  stop_.store(true, std::memory_order_release);
  if (thread_.joinable()) {
    thread_.join();
  }
}

StatePersister::Blob* StatePersister::acquire() noexcept {
  Blob* b = nullptr;
  return free_.try_pop(b) ? b : nullptr;
}

void StatePersister::submit(Blob* blob) noexcept { (void)full_.try_push(blob); }

void StatePersister::release(Blob* blob) noexcept {
  // The loop owns both ends only here: free_ is popped by the loop and pushed by the persister;
  // handing an unused blob back goes through full_ with size 0 so the persister recycles it.
  blob->size = 0;
  (void)full_.try_push(blob);
}

void StatePersister::write_one(std::span<const std::byte> payload) {
  std::lock_guard<std::mutex> lock(mu_);
  try {
    write_state_file(path_, payload, stats_.sequence + 1);
    ++stats_.sequence;
    ++stats_.writes;
  } catch (const std::exception& e) {
    ++stats_.failures;
    stats_.last_error = e.what();
  }
}

void StatePersister::write_now(std::span<const std::byte> payload) { write_one(payload); }

StatePersister::Stats StatePersister::stats() const {
  std::lock_guard<std::mutex> lock(mu_);
  return stats_;
}

void StatePersister::run() {
  for (;;) {
    const bool stopping = stop_.load(std::memory_order_acquire);
    // Only the newest queued state matters: older ones are recycled unwritten.
    Blob* latest = nullptr;
    Blob* b = nullptr;
    while (full_.try_pop(b)) {
      if (b->size == 0) {
        (void)free_.try_push(b);
        continue;
      }
      if (latest != nullptr) {
        (void)free_.try_push(latest);
      }
      latest = b;
    }
    if (latest != nullptr) {
      write_one(std::span<const std::byte>(latest->data.data(), latest->size));
      (void)free_.try_push(latest);
    }
    if (stopping) {
      return;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
}

}  // namespace nccomp::daemon
