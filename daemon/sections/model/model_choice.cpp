#include "daemon/sections/model/model_choice.hpp"

#include <array>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <ctime>
#include <fstream>
#include <map>
#include <mutex>
#include <stdexcept>

namespace nccomp::daemon::sections {

namespace {

std::mutex g_mu;
std::optional<ModelChoice> g_choice;  // under g_mu

constexpr std::string_view kHeader = "nccomp_model_choice 1";

}  // namespace

std::optional<ModelChoice> model_choice() {
  std::lock_guard<std::mutex> lock(g_mu);
  return g_choice;
}

void set_model_choice(std::optional<ModelChoice> choice) {
  std::lock_guard<std::mutex> lock(g_mu);
  g_choice = std::move(choice);
}

std::string model_file_hash(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot read " + path);
  std::uint64_t h = 0xcbf29ce484222325ULL;
  // Chunks, not istreambuf_iterator: GCC 12 at -O2 warns of a null dereference in <streambuf>.
  std::array<char, 4096> buf{};
  while (in.read(buf.data(), static_cast<std::streamsize>(buf.size())) || in.gcount() > 0) {
    const auto n = static_cast<std::size_t>(in.gcount());
    for (std::size_t i = 0; i < n; ++i) {
      h = (h ^ static_cast<unsigned char>(buf[i])) * 0x100000001b3ULL;
    }
  }
  std::array<char, 17> hex{};
  std::snprintf(hex.data(), hex.size(), "%016llx", static_cast<unsigned long long>(h));
  return hex.data();
}

std::string utc_now() {
  const std::time_t t = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm tm{};
  ::gmtime_r(&t, &tm);
  std::array<char, 32> buf{};
  std::strftime(buf.data(), buf.size(), "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf.data();
}

std::string to_text(const ModelChoice& c) {
  std::string s(kHeader);
  s += '\n';
  const auto line = [&s](std::string_view key, const std::string& value) {
    s += key;
    s += ' ';
    s += value;
    s += '\n';
  };
  line("configured", c.configured);
  line("live_file", c.live.file);
  line("live_hash", c.live.hash);
  line("live_since", c.live.since_utc);
  line("previous_file", c.previous.file);
  line("previous_hash", c.previous.hash);
  line("previous_since", c.previous.since_utc);
  return s;
}

ModelChoice model_choice_from_text(std::string_view text) {
  std::map<std::string, std::string, std::less<>> values;
  std::size_t n = 0;
  while (!text.empty()) {
    const std::size_t nl = text.find('\n');
    const std::string_view line = text.substr(0, nl);
    text = nl == std::string_view::npos ? std::string_view{} : text.substr(nl + 1);
    ++n;
    if (n == 1) {
      if (line != kHeader) {
        throw std::invalid_argument("line 1: expected '" + std::string(kHeader) + "'");
      }
      continue;
    }
    if (line.empty()) continue;
    const std::size_t sp = line.find(' ');
    const std::string key(line.substr(0, sp));
    const std::string value(sp == std::string_view::npos ? std::string_view{}
                                                         : line.substr(sp + 1));
    if (!values.emplace(key, value).second) {
      throw std::invalid_argument("line " + std::to_string(n) + ": key '" + key + "' twice");
    }
  }
  if (n == 0) throw std::invalid_argument("line 1: empty");
  ModelChoice c;
  const auto take = [&values](const char* key, std::string& out) {
    const auto it = values.find(key);
    if (it == values.end()) throw std::invalid_argument(std::string("key '") + key + "' missing");
    out = it->second;
    values.erase(it);
  };
  take("configured", c.configured);
  take("live_file", c.live.file);
  take("live_hash", c.live.hash);
  take("live_since", c.live.since_utc);
  take("previous_file", c.previous.file);
  take("previous_hash", c.previous.hash);
  take("previous_since", c.previous.since_utc);
  if (!values.empty()) {
    throw std::invalid_argument("unknown key '" + values.begin()->first + "'");
  }
  return c;
}

}  // namespace nccomp::daemon::sections
