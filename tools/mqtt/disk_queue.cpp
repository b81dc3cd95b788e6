#include "tools/mqtt/disk_queue.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <system_error>

namespace nccomp::tools::mqtt {

namespace fs = std::filesystem;

namespace {

constexpr std::int64_t kSaveIntervalNs = 1'000'000'000;
constexpr std::size_t kReadChunk = 64 * 1024;

std::int64_t now_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

std::string read_file_at(const std::string& path, std::uint64_t offset, std::size_t n) {
  std::string s;
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return s;
  s.resize(n);
  std::size_t got = 0;
  while (got < n) {
    const ssize_t k = ::pread(fd, s.data() + got, n - got, static_cast<off_t>(offset + got));
    if (k < 0 && errno == EINTR) continue;
    if (k <= 0) break;
    got += static_cast<std::size_t>(k);
  }
  ::close(fd);
  s.resize(got);
  return s;
}

void write_all(int fd, const std::string& data, const std::string& what) {
  std::size_t done = 0;
  while (done < data.size()) {
    const ssize_t k = ::write(fd, data.data() + done, data.size() - done);
    if (k < 0 && errno == EINTR) continue;
    if (k <= 0) {
      throw std::system_error(errno, std::generic_category(), "cannot write " + what);
    }
    done += static_cast<std::size_t>(k);
  }
}

struct LineHead {
  std::uint64_t id{0};
  std::string kind;
  std::uint64_t seq{0};
  std::string cursor;
  std::string_view payload;
};

/// Splits "id\tkind\tseq\tcursor\tpayload"; false if the line is not one.
bool parse_line(std::string_view line, LineHead& h) {
  std::string_view f[4];
  std::size_t b = 0;
  for (auto& field : f) {
    const std::size_t e = line.find('\t', b);
    if (e == std::string_view::npos) return false;
    field = line.substr(b, e - b);
    b = e + 1;
  }
  h.payload = line.substr(b);
  const auto num = [](std::string_view s, std::uint64_t& v) {
    const auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
    return ec == std::errc() && p == s.data() + s.size();
  };
  if (!num(f[0], h.id) || !num(f[2], h.seq) || f[1].empty()) return false;
  h.kind = std::string(f[1]);
  h.cursor = std::string(f[3]);
  return true;
}

}  // namespace

DiskQueue::DiskQueue(Options options) : options_(std::move(options)) {
  segment_limit_ = std::clamp<std::uint64_t>(options_.max_messages / 16, 1, 100'000);
}

DiskQueue::~DiskQueue() {
  try {
    close();
  } catch (const std::exception&) {
  }
}

std::string DiskQueue::segment_path(std::uint64_t first) const {
  char name[40];
  std::snprintf(name, sizeof name, "seg-%020llu.q", static_cast<unsigned long long>(first));
  return options_.directory + "/" + name;
}

void DiskQueue::open() {
  fs::create_directories(options_.directory);
  const std::string state_path = options_.directory + "/state.json";
  std::uint64_t saved_next = 1;
  if (fs::exists(state_path)) {
    std::ifstream in(state_path);
    nlohmann::json j;
    try {
      in >> j;
      head_ = j.at("head").get<std::uint64_t>();
      saved_next = j.at("next_id").get<std::uint64_t>();
      next_seq_ = j.at("next_seq").get<std::map<std::string, std::uint64_t>>();
      dropped_ = j.at("dropped").get<std::map<std::string, std::uint64_t>>();
      cursor_ = j.at("cursor").get<std::string>();
      app_ = j.at("app");
      acked_total_ = j.value("acknowledged", std::uint64_t{0});
    } catch (const std::exception& e) {
      throw std::runtime_error(
          "queue state '" + state_path + "' is not valid (" + e.what() +
          "): the queue cannot tell which sequence numbers it has used; restore the file, or "
          "remove the queue directory and this machine's log in the collector's directory to "
          "start both anew");
    }
  }
  next_id_ = saved_next;
  segments_.clear();
  for (const auto& e : fs::directory_iterator(options_.directory)) {
    const std::string name = e.path().filename().string();
    if (name.size() != 26 || name.rfind("seg-", 0) != 0 || name.substr(24) != ".q") continue;
    std::uint64_t first = 0;
    const auto [p, ec] = std::from_chars(name.data() + 4, name.data() + 24, first);
    if (ec != std::errc() || p != name.data() + 24) continue;
    segments_.push_back(Segment{first, 0, e.path().string()});
  }
  std::sort(segments_.begin(), segments_.end(),
            [](const Segment& a, const Segment& b) { return a.first < b.first; });
  // Counts from the names; the segments from the one holding saved_next on are read: lines
  // written after the last save roll the state forward, a partial last line is cut.
  for (std::size_t i = 0; i + 1 < segments_.size(); ++i) {
    segments_[i].count = segments_[i + 1].first - segments_[i].first;
  }
  for (std::size_t i = 0; i < segments_.size(); ++i) {
    Segment& s = segments_[i];
    const bool newest = i + 1 == segments_.size();
    if (!newest && segments_[i + 1].first <= saved_next) continue;
    std::string data;
    {
      std::ifstream in(s.path, std::ios::binary);
      std::ostringstream ss;
      ss << in.rdbuf();
      data = ss.str();
    }
    const std::size_t end = data.rfind('\n') == std::string::npos ? 0 : data.rfind('\n') + 1;
    if (end < data.size()) {
      if (::truncate(s.path.c_str(), static_cast<off_t>(end)) != 0) {
        throw std::system_error(errno, std::generic_category(), "cannot repair " + s.path);
      }
      data.resize(end);
    }
    std::uint64_t count = 0;
    std::size_t b = 0;
    while (b < data.size()) {
      const std::size_t e = data.find('\n', b);
      LineHead h;
      if (!parse_line(std::string_view(data).substr(b, e - b), h)) {
        throw std::runtime_error("queue segment '" + s.path + "' has a line that is not a message");
      }
      ++count;
      if (h.id >= next_id_) {
        next_id_ = h.id + 1;
        next_seq_[h.kind] = std::max(next_seq_[h.kind], h.seq + 1);
        cursor_ = h.cursor;
      }
      b = e + 1;
    }
    if (newest) s.count = count;
  }
  if (!segments_.empty()) {
    head_ = std::max(head_, segments_.front().first);
    next_id_ = std::max(next_id_, segments_.back().first + segments_.back().count);
    fd_ = ::open(segments_.back().path.c_str(), O_WRONLY | O_APPEND | O_CLOEXEC);
    if (fd_ < 0) {
      throw std::system_error(errno, std::generic_category(),
                              "cannot open " + segments_.back().path);
    }
  }
  head_ = std::min(head_, next_id_);
  flushed_id_ = next_id_;
  last_sync_ns_ = last_save_ns_ = now_ns();
  rewind();
  dirty_ = true;
  save_state();
}

void DiskQueue::close() {
  if (fd_ >= 0 || !buffer_.empty()) {
    flush(true);
  }
  if (fd_ >= 0) {
    ::close(fd_);
    fd_ = -1;
  }
  if (dirty_) save_state();
}

std::uint64_t DiskQueue::next_seq(const std::string& kind) const {
  const auto it = next_seq_.find(kind);
  return it == next_seq_.end() ? 1 : it->second;
}

void DiskQueue::start_segment() {
  if (fd_ >= 0) {
    if (!buffer_.empty()) {
      write_all(fd_, buffer_, segments_.back().path);
      buffer_.clear();
      unsynced_ = true;
    }
    if (unsynced_) ::fdatasync(fd_);
    unsynced_ = false;
    ::close(fd_);
  }
  segments_.push_back(Segment{next_id_, 0, segment_path(next_id_)});
  fd_ = ::open(segments_.back().path.c_str(), O_WRONLY | O_APPEND | O_CREAT | O_CLOEXEC, 0600);
  if (fd_ < 0) {
    throw std::system_error(errno, std::generic_category(),
                            "cannot create " + segments_.back().path);
  }
}

std::uint64_t DiskQueue::append(const std::string& kind, std::uint64_t seq,
                                const std::string& cursor, std::string_view payload) {
  if (fd_ < 0 || segments_.back().count >= segment_limit_) start_segment();
  const std::uint64_t id = next_id_++;
  buffer_ += std::to_string(id);
  buffer_ += '\t';
  buffer_ += kind;
  buffer_ += '\t';
  buffer_ += std::to_string(seq);
  buffer_ += '\t';
  buffer_ += cursor;
  buffer_ += '\t';
  buffer_ += payload;
  buffer_ += '\n';
  ++segments_.back().count;
  next_seq_[kind] = std::max(next_seq(kind), seq + 1);
  cursor_ = cursor;
  dirty_ = true;
  return id;
}

void DiskQueue::set_cursor(const std::string& cursor) {
  if (cursor != cursor_) {
    cursor_ = cursor;
    dirty_ = true;
  }
}

void DiskQueue::flush(bool force_sync) {
  if (!buffer_.empty()) {
    write_all(fd_, buffer_, segments_.back().path);
    buffer_.clear();
    unsynced_ = true;
  }
  flushed_id_ = next_id_;
  const std::int64_t now = now_ns();
  if (unsynced_ && fd_ >= 0 &&
      (force_sync || static_cast<double>(now - last_sync_ns_) >= options_.fsync_interval_s * 1e9)) {
    ::fdatasync(fd_);
    unsynced_ = false;
    last_sync_ns_ = now;
  }
  if (queued() > options_.max_messages && segments_.size() == 1) start_segment();
  while (queued() > options_.max_messages && segments_.size() > 1) drop_oldest();
  delete_acked_segments();
  if (dirty_ && (force_sync || now - last_save_ns_ >= kSaveIntervalNs)) save_state();
}

void DiskQueue::drop_oldest() {
  const Segment s = segments_.front();
  std::ifstream in(s.path, std::ios::binary);
  for (std::string line; std::getline(in, line);) {
    LineHead h;
    if (parse_line(line, h) && h.id >= head_ && acked_.count(h.id) == 0) ++dropped_[h.kind];
  }
  head_ = segments_[1].first;
  acked_.erase(acked_.begin(), acked_.lower_bound(head_));
  segments_.erase(segments_.begin());
  dirty_ = true;
  save_state();  // the drop counts and the new head before the file goes
  ::unlink(s.path.c_str());
  if (read_segment_ == 0) {
    rewind();
  } else {
    --read_segment_;
  }
}

void DiskQueue::delete_acked_segments() {
  bool saved = false;
  while (segments_.size() > 1 && head_ >= segments_[1].first) {
    if (!saved) {
      save_state();  // the sequence numbers of the deleted lines must not be given again
      saved = true;
    }
    ::unlink(segments_.front().path.c_str());
    segments_.erase(segments_.begin());
    if (read_segment_ > 0) {
      --read_segment_;
    } else {
      // The reader was at the end of the deleted segment: it goes on at the next one's start
      // (its offset was into the deleted file).
      read_offset_ = 0;
      read_buffer_.clear();
    }
  }
}

void DiskQueue::rewind() {
  read_id_ = head_;
  read_segment_ = 0;
  for (std::size_t i = 0; i < segments_.size(); ++i) {
    if (segments_[i].first <= head_) read_segment_ = i;
  }
  read_offset_ = 0;
  read_buffer_.clear();
}

bool DiskQueue::next(QueuedMessage& out) {
  while (read_id_ < flushed_id_) {
    if (read_buffer_.empty()) {
      if (read_segment_ >= segments_.size()) return false;
      std::string data = read_file_at(segments_[read_segment_].path, read_offset_, kReadChunk);
      const std::size_t nl = data.rfind('\n');
      if (nl == std::string::npos) {
        if (read_segment_ + 1 >= segments_.size()) return false;
        ++read_segment_;
        read_offset_ = 0;
        continue;
      }
      data.resize(nl + 1);
      read_buffer_ = std::move(data);
    }
    const std::size_t e = read_buffer_.find('\n');
    const std::string line = read_buffer_.substr(0, e);
    read_buffer_.erase(0, e + 1);
    read_offset_ += e + 1;
    LineHead h;
    if (!parse_line(line, h) || h.id < read_id_) continue;
    read_id_ = h.id + 1;
    if (h.id < head_ || acked_.count(h.id) != 0) continue;
    out.id = h.id;
    out.kind = h.kind;
    out.seq = h.seq;
    out.payload = std::string(h.payload);
    return true;
  }
  return false;
}

void DiskQueue::ack(std::uint64_t id) {
  if (id < head_ || id >= next_id_ || !acked_.insert(id).second) return;
  ++acked_total_;
  while (!acked_.empty() && *acked_.begin() == head_) {
    acked_.erase(acked_.begin());
    ++head_;
  }
  dirty_ = true;
}

std::uint64_t DiskQueue::dropped(const std::string& kind) const {
  const auto it = dropped_.find(kind);
  return it == dropped_.end() ? 0 : it->second;
}

std::uint64_t DiskQueue::dropped_total() const {
  std::uint64_t n = 0;
  for (const auto& [k, v] : dropped_) n += v;
  return n;
}

void DiskQueue::save_state() {
  nlohmann::json j;
  j["version"] = 1;
  j["head"] = head_;
  j["next_id"] = next_id_;
  j["next_seq"] = next_seq_;
  j["dropped"] = dropped_;
  j["acknowledged"] = acked_total_;
  j["cursor"] = cursor_;
  j["app"] = app_;
  const std::string path = options_.directory + "/state.json";
  const std::string tmp = path + ".tmp";
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
  if (fd < 0) throw std::system_error(errno, std::generic_category(), "cannot write " + tmp);
  try {
    write_all(fd, j.dump() + "\n", tmp);
  } catch (...) {
    ::close(fd);
    throw;
  }
  ::fsync(fd);
  ::close(fd);
  if (::rename(tmp.c_str(), path.c_str()) != 0) {
    throw std::system_error(errno, std::generic_category(), "cannot rename " + tmp);
  }
  const int dfd = ::open(options_.directory.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
  last_save_ns_ = now_ns();
  dirty_ = false;
}

}  // namespace nccomp::tools::mqtt
