#include "tools/mqtt/log_source.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <stdexcept>
#include <system_error>

#include "formats/measurement_log/measurement_log.hpp"

namespace nccomp::tools::mqtt {

namespace fs = std::filesystem;
namespace ml = nccomp::formats::measurement_log;
using formats::measurement_log::read_at;

namespace {

constexpr std::size_t kHeadBytes = 1024;
constexpr std::size_t kReadChunk = 1 << 20;

std::vector<std::string> split(const std::string& line) {
  std::vector<std::string> out;
  std::size_t b = 0;
  for (;;) {
    const std::size_t e = line.find(',', b);
    out.push_back(line.substr(b, e == std::string::npos ? std::string::npos : e - b));
    if (e == std::string::npos) break;
    b = e + 1;
  }
  return out;
}

std::uint64_t head_hash(int fd, std::uint64_t offset) {
  const std::string h =
      read_at(fd, 0, static_cast<std::size_t>(std::min<std::uint64_t>(offset, kHeadBytes)));
  return fnv1a(h.data(), h.size());
}

}  // namespace

std::uint64_t fnv1a(const char* data, std::size_t n) noexcept {
  std::uint64_t h = 1469598103934665603ULL;
  for (std::size_t i = 0; i < n; ++i) {
    h ^= static_cast<unsigned char>(data[i]);
    h *= 1099511628211ULL;
  }
  return h;
}

std::string LogCursor::to_string() const {
  return std::to_string(inode) + ":" + std::to_string(offset) + ":" + std::to_string(head_hash);
}

LogCursor LogCursor::parse(const std::string& s) {
  LogCursor c;
  std::uint64_t* parts[] = {&c.inode, &c.offset, &c.head_hash};
  const char* p = s.data();
  const char* end = s.data() + s.size();
  for (std::size_t i = 0; i < 3; ++i) {
    const auto [q, ec] = std::from_chars(p, end, *parts[i]);
    if (ec != std::errc() || (i < 2 && (q == end || *q != ':')) || (i == 2 && q != end)) {
      throw std::invalid_argument("not a log cursor: '" + s + "'");
    }
    p = q + 1;
  }
  return c;
}

bool is_text_column(const std::string& name) {
  return name == "kind" || name == "machine" || name == "utc";
}

bool is_integer_column(const std::string& name) {
  return name == "part" || name == "tool" || name == "point" || name == "session";
}

bool row_to_json(const std::vector<std::string>& header, const std::string& line,
                 nlohmann::ordered_json& out, std::string& error) {
  const std::vector<std::string> cells = split(line);
  if (cells.size() != header.size()) {
    error =
        std::to_string(cells.size()) + " fields, the header has " + std::to_string(header.size());
    return false;
  }
  out = nlohmann::ordered_json::object();
  for (std::size_t i = 0; i < cells.size(); ++i) {
    const std::string& name = header[i];
    const std::string& cell = cells[i];
    if (is_text_column(name)) {
      out[name] = cell;
    } else if (cell.empty()) {
      out[name] = nullptr;
    } else if (is_integer_column(name)) {
      std::int64_t v = 0;
      const auto [p, ec] = std::from_chars(cell.data(), cell.data() + cell.size(), v);
      if (ec != std::errc() || p != cell.data() + cell.size()) {
        error = "column '" + name + "': '" + cell + "' is not an integer";
        return false;
      }
      out[name] = v;
    } else {
      double v = 0.0;
      const auto [p, ec] = std::from_chars(cell.data(), cell.data() + cell.size(), v);
      if (ec != std::errc() || p != cell.data() + cell.size() || !std::isfinite(v)) {
        error = "column '" + name + "': '" + cell + "' is not a finite number";
        return false;
      }
      out[name] = v;
    }
  }
  return true;
}

std::string json_to_row(const std::vector<std::string>& header, const nlohmann::ordered_json& row) {
  std::string s;
  for (std::size_t i = 0; i < header.size(); ++i) {
    if (i > 0) s += ',';
    const auto it = row.find(header[i]);
    if (it == row.end() || it->is_null()) continue;
    if (it->is_string()) {
      s += it->get<std::string>();
    } else {
      s += it->dump();
    }
  }
  return s;
}

std::vector<LogSource::File> LogSource::list() const {
  // Oldest first: measurements.csv.N … measurements.csv.1, measurements.csv.
  std::vector<std::pair<long, File>> found;
  std::error_code ec;
  fs::directory_iterator it(directory_, ec);
  if (ec) {
    throw std::system_error(ec, "cannot read the log directory '" + directory_ + "'");
  }
  for (const auto& e : it) {
    const std::string name = e.path().filename().string();
    std::string log;
    const long rank = ml::rotation_number(name, log);
    if (rank < 0 || log != "measurements.csv") continue;
    struct stat st {};
    if (::stat(e.path().c_str(), &st) != 0 || !S_ISREG(st.st_mode)) continue;
    found.push_back({rank, File{e.path().string(), static_cast<std::uint64_t>(st.st_ino),
                                static_cast<std::uint64_t>(st.st_size)}});
  }
  std::sort(found.begin(), found.end(),
            [](const auto& a, const auto& b) { return a.first > b.first; });
  std::vector<File> files;
  for (auto& [rank, f] : found) files.push_back(std::move(f));
  return files;
}

std::vector<LogRow> LogSource::poll(std::size_t max_rows, std::vector<LogProblem>& problems) {
  std::vector<LogRow> rows;
  std::vector<File> files = list();
  if (files.empty()) return rows;
  for (int guard = 0; guard < 1000 && rows.size() < max_rows; ++guard) {
    // The file the cursor is in.
    std::size_t idx = files.size();
    int fd = -1;
    if (cursor_.inode == 0) {
      idx = files.size() - 1;  // a fresh start: the current file from its beginning
      cursor_ = LogCursor{files[idx].inode, 0, 0};
    }
    for (std::size_t i = 0; i < files.size() && idx == files.size(); ++i) {
      if (files[i].inode == cursor_.inode) idx = i;
    }
    if (idx < files.size()) {
      fd = ::open(files[idx].path.c_str(), O_RDONLY | O_CLOEXEC);
      struct stat st {};
      if (fd < 0 || ::fstat(fd, &st) != 0 ||
          static_cast<std::uint64_t>(st.st_ino) != cursor_.inode) {
        // Rotated between the listing and the open: list again.
        if (fd >= 0) ::close(fd);
        files = list();
        if (files.empty()) return rows;
        continue;
      }
      files[idx].size = static_cast<std::uint64_t>(st.st_size);
      if (files[idx].size < cursor_.offset ||
          (cursor_.offset > 0 && head_hash(fd, cursor_.offset) != cursor_.head_hash)) {
        ::close(fd);
        fd = -1;
        idx = files.size();  // the inode was reused by another file
      }
    }
    if (idx == files.size()) {
      ++files_missed_;
      problems.push_back({directory_, 0,
                          "the log file the publisher was reading was rotated away before all "
                          "its rows were queued; going on with the oldest file there is (rows "
                          "lost)"});
      cursor_ = LogCursor{files.front().inode, 0, 0};
      header_inode_ = 0;
      continue;
    }
    const File& f = files[idx];
    if (header_inode_ != f.inode) {
      const std::string head = read_at(fd, 0, 64 * 1024);
      const std::size_t nl = head.find('\n');
      if (nl == std::string::npos) {
        ::close(fd);
        return rows;  // no complete header yet
      }
      header_ = split(head.substr(0, nl));
      header_v2_ = std::find(header_.begin(), header_.end(), "machine") != header_.end() &&
                   std::find(header_.begin(), header_.end(), "utc") != header_.end() &&
                   std::find(header_.begin(), header_.end(), "session") != header_.end();
      header_inode_ = f.inode;
      if (cursor_.offset == 0) {
        cursor_.offset = nl + 1;
        cursor_.head_hash = head_hash(fd, cursor_.offset);
        if (!header_v2_) {
          problems.push_back({f.path, 1,
                              "not a v2 log (no machine, utc and session columns): its rows "
                              "are not published"});
        }
      }
    }
    // Complete lines after the cursor.
    bool at_end = false;
    while (rows.size() < max_rows) {
      const std::string chunk = read_at(fd, cursor_.offset, kReadChunk);
      const std::size_t last_nl = chunk.rfind('\n');
      if (last_nl == std::string::npos) {
        at_end = true;
        break;
      }
      std::size_t b = 0;
      while (b <= last_nl && rows.size() < max_rows) {
        const std::size_t e = chunk.find('\n', b);
        std::string line = chunk.substr(b, e - b);
        if (!line.empty() && line.back() == '\r') line.pop_back();
        const std::uint64_t before = cursor_.offset;
        cursor_.offset += e - b + 1;
        b = e + 1;
        if (before < kHeadBytes) cursor_.head_hash = head_hash(fd, cursor_.offset);
        if (line.empty() || !header_v2_) continue;
        LogRow row;
        std::string error;
        if (!row_to_json(header_, line, row.columns, error)) {
          problems.push_back({f.path, 0,
                              "the row at byte " + std::to_string(before) +
                                  " is not a measurement row (" + error + "): skipped"});
          continue;
        }
        row.file = f.path;
        row.after = cursor_;
        rows.push_back(std::move(row));
      }
      if (chunk.size() < kReadChunk && b > last_nl) {
        at_end = true;
        break;
      }
    }
    // A rotated file is complete: go on with the next newer one. The current file may grow.
    const bool newest = idx + 1 == files.size();
    if (at_end && !newest) {
      const std::string rest = read_at(fd, cursor_.offset, 1);
      ::close(fd);
      if (!rest.empty()) {
        problems.push_back({f.path, 0, "ends in a partial row: skipped"});
      }
      cursor_ = LogCursor{files[idx + 1].inode, 0, 0};
      continue;
    }
    ::close(fd);
    break;
  }
  return rows;
}

}  // namespace nccomp::tools::mqtt
