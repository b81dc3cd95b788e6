#include "tools/mqtt/collector.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <filesystem>
#include <fstream>
#include <system_error>

#include "formats/measurement_log/measurement_log.hpp"
#include "tools/mqtt/log_source.hpp"

namespace nccomp::tools::mqtt {

namespace fs = std::filesystem;

namespace {

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::size_t b = 0;
  for (;;) {
    const std::size_t e = s.find(sep, b);
    out.push_back(s.substr(b, e == std::string::npos ? std::string::npos : e - b));
    if (e == std::string::npos) return out;
    b = e + 1;
  }
}

bool column_name(const std::string& k) {
  return !k.empty() && k.size() <= 64 && k.front() >= 'a' && k.front() <= 'z' &&
         k.find_first_not_of("abcdefghijklmnopqrstuvwxyz0123456789_") == std::string::npos;
}

void write_all(int fd, const std::string& data, const std::string& path) {
  std::size_t done = 0;
  while (done < data.size()) {
    const ssize_t k = ::write(fd, data.data() + done, data.size() - done);
    if (k < 0 && errno == EINTR) continue;
    if (k <= 0) throw std::system_error(errno, std::generic_category(), "cannot write " + path);
    done += static_cast<std::size_t>(k);
  }
}

}  // namespace

CollectorStore::~CollectorStore() {
  for (auto& [k, f] : files_) {
    if (f.fd >= 0) {
      ::fdatasync(f.fd);
      ::close(f.fd);
    }
  }
}

std::string CollectorStore::path(const std::string& site, const std::string& machine) const {
  return out_dir_ + "/" + site + "/" + machine + ".csv";
}

CollectorStore::File& CollectorStore::file(const std::string& site, const std::string& machine) {
  const std::string key = site + "/" + machine;
  auto it = files_.find(key);
  if (it != files_.end()) return it->second;
  File& f = files_[key];
  const std::string p = path(site, machine);
  fs::create_directories(fs::path(p).parent_path());
  f.fd = ::open(p.c_str(), O_RDWR | O_APPEND | O_CREAT | O_CLOEXEC, 0644);
  if (f.fd < 0) throw std::system_error(errno, std::generic_category(), "cannot open " + p);
  // Read back the header and the last complete row's seq; cut a partial last row.
  std::ifstream in(p, std::ios::binary);
  std::string header_line;
  std::getline(in, header_line);
  if (!header_line.empty()) f.header = split(header_line, ',');
  struct stat st {};
  ::fstat(f.fd, &st);
  const auto size = static_cast<std::uint64_t>(st.st_size);
  const std::uint64_t tail = std::min<std::uint64_t>(size, 64 * 1024);
  std::string end(static_cast<std::size_t>(tail), '\0');
  in.clear();
  in.seekg(static_cast<std::streamoff>(size - tail));
  in.read(end.data(), static_cast<std::streamsize>(tail));
  const std::size_t nl = end.rfind('\n');
  if (nl != std::string::npos && nl + 1 < end.size()) {
    if (::ftruncate(f.fd, static_cast<off_t>(size - tail + nl + 1)) != 0) {
      throw std::system_error(errno, std::generic_category(), "cannot repair " + p);
    }
    end.resize(nl + 1);
  }
  if (!f.header.empty() && f.header.back() == "seq" && end.size() > 1) {
    const std::size_t b = end.rfind('\n', end.size() - 2);
    const std::string last = end.substr(b == std::string::npos ? 0 : b + 1,
                                        end.size() - 1 - (b == std::string::npos ? 0 : b + 1));
    const auto cells = split(last, ',');
    if (cells.size() == f.header.size() && last != header_line) {
      std::uint64_t seq = 0;
      const std::string& c = cells.back();
      const auto [q, ec] = std::from_chars(c.data(), c.data() + c.size(), seq);
      if (ec == std::errc() && q == c.data() + c.size()) f.last_seq = seq;
    }
  }
  return f;
}

void CollectorStore::start_file(File& f, const std::string& p,
                                const std::vector<std::string>& header) {
  // Other columns than the file's (the machine's context columns changed): the old file is
  // kept as <machine>.csv.<n>, a new one starts.
  if (!f.header.empty()) {
    ::close(f.fd);
    int n = 1;
    while (fs::exists(p + "." + std::to_string(n))) ++n;
    fs::rename(p, p + "." + std::to_string(n));
    f.fd = ::open(p.c_str(), O_RDWR | O_APPEND | O_CREAT | O_CLOEXEC, 0644);
    if (f.fd < 0) throw std::system_error(errno, std::generic_category(), "cannot open " + p);
  }
  std::string h;
  for (const std::string& c : header) h += (h.empty() ? "" : ",") + c;
  write_all(f.fd, h + "\n", p);
  f.header = header;
}

CollectorStore::Result CollectorStore::add(const std::string& topic, const std::string& payload,
                                           std::string& error) {
  std::lock_guard<std::mutex> lock(mu_);
  const auto refuse = [&](std::string why) {
    error = topic + ": " + why;
    ++stats_.refused;
    return Result::kRefused;
  };
  const auto levels = split(topic, '/');
  if (levels.size() != 4 || levels[0] != "nccomp" || levels[3] != "measurements" ||
      !formats::measurement_log::valid_machine_id(levels[1]) ||
      !formats::measurement_log::valid_machine_id(levels[2])) {
    return refuse("not a topic nccomp/<site>/<machine>/measurements");
  }
  const std::string& site = levels[1];
  const std::string& machine = levels[2];
  nlohmann::ordered_json j;
  try {
    j = nlohmann::ordered_json::parse(payload);
  } catch (const std::exception& e) {
    return refuse(std::string("not JSON (") + e.what() + ")");
  }
  if (!j.is_object()) return refuse("not a JSON object");
  const auto seq_it = j.find("seq");
  if (seq_it == j.end() || !seq_it->is_number_unsigned() || seq_it->get<std::uint64_t>() == 0) {
    return refuse("no sequence number (seq, an integer > 0)");
  }
  const auto seq = seq_it->get<std::uint64_t>();
  for (const std::string& c : split(std::string(formats::measurement_log::kV1Header) + "," +
                                        formats::measurement_log::kV2Columns,
                                    ',')) {
    if (!j.contains(c)) return refuse("no column '" + c + "' (not a v2 row)");
  }
  const auto m = j.find("machine");
  if (m == j.end() || !m->is_string() || m->get<std::string>() != machine) {
    return refuse("its machine is not the topic's ('" + machine + "')");
  }
  std::vector<std::string> header;
  for (const auto& [k, v] : j.items()) {
    if (k == "seq") continue;
    if (!column_name(k)) return refuse("'" + k + "' is not a column name");
    if (v.is_string()) {
      const auto& s = v.get_ref<const std::string&>();
      if (!is_text_column(k) || s.find_first_of(",\n\r\"") != std::string::npos) {
        return refuse("column '" + k + "': not a cell of the log");
      }
    } else if (!v.is_null() && !v.is_number()) {
      return refuse("column '" + k + "': not a number");
    }
    header.push_back(k);
  }
  header.push_back("seq");
  File& f = file(site, machine);
  if (seq <= f.last_seq) {
    ++stats_.duplicates;
    return Result::kDuplicate;
  }
  const std::string p = path(site, machine);
  if (f.header != header) start_file(f, p, header);
  if (f.last_seq > 0 && seq > f.last_seq + 1) stats_.missing += seq - f.last_seq - 1;
  write_all(f.fd, json_to_row(header, j) + "\n", p);
  f.last_seq = seq;
  f.unsynced = true;
  ++stats_.written;
  return Result::kWritten;
}

void CollectorStore::sync() {
  std::lock_guard<std::mutex> lock(mu_);
  for (auto& [k, f] : files_) {
    if (f.unsynced) {
      ::fdatasync(f.fd);
      f.unsynced = false;
    }
  }
}

CollectorStore::Stats CollectorStore::stats() const {
  std::lock_guard<std::mutex> lock(mu_);
  return stats_;
}

std::uint64_t CollectorStore::last_seq(const std::string& site, const std::string& machine) {
  std::lock_guard<std::mutex> lock(mu_);
  return file(site, machine).last_seq;
}

}  // namespace nccomp::tools::mqtt
