#include "tools/mqtt/mqtt_config.hpp"

#include <sys/stat.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <stdexcept>

#include "formats/measurement_log/measurement_log.hpp"
#include "formats/toml/guard.hpp"
#include "formats/toml/table_reader.hpp"

namespace nccomp::tools::mqtt {

namespace ml = formats::measurement_log;

namespace {

bool has_scheme(const std::string& uri, std::string_view scheme) {
  return uri.rfind(std::string(scheme) + "://", 0) == 0;
}

bool tls_uri(const std::string& uri) { return has_scheme(uri, "ssl") || has_scheme(uri, "mqtts"); }

std::string resolve(const std::string& base, const std::string& p) {
  if (p.empty() || p.front() == '/') return p;
  return (std::filesystem::path(base) / p).lexically_normal().string();
}

}  // namespace

std::string topic(std::string_view site, std::string_view machine, std::string_view what) {
  std::string t = "nccomp/";
  t += site;
  t += '/';
  t += machine;
  t += '/';
  t += what;
  return t;
}

std::string check_broker(const BrokerOptions& b) {
  const std::string& u = b.uri;
  if (!has_scheme(u, "tcp") && !has_scheme(u, "mqtt") && !tls_uri(u)) {
    return "'" + u + "' is not a broker address: tcp://host:port or mqtt://host:port, " +
           "ssl://host:port or mqtts://host:port for TLS";
  }
  if (u.find("://") + 3 >= u.size()) return "'" + u + "' names no host";
  if ((!b.ca_file.empty() || !b.cert_file.empty() || !b.key_file.empty()) && !tls_uri(u)) {
    return "ca_file, cert_file and key_file need a TLS address (ssl:// or mqtts://), not '" + u +
           "'";
  }
  if (b.cert_file.empty() != b.key_file.empty()) {
    return "cert_file and key_file go together (a client certificate and its key)";
  }
  if (!b.password_file.empty() && b.username.empty()) {
    return "password_file needs a username";
  }
  return "";
}

std::string read_password_file(const std::string& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) {
    throw std::runtime_error("password_file '" + path + "': " + std::strerror(errno));
  }
  if (!S_ISREG(st.st_mode)) {
    throw std::runtime_error("password_file '" + path + "': not a regular file");
  }
  if ((st.st_mode & 0007) != 0) {
    char mode[8];
    std::snprintf(mode, sizeof mode, "%04o", static_cast<unsigned>(st.st_mode & 07777));
    throw std::runtime_error("password_file '" + path + "': mode " + mode +
                             " lets other users read or change it; chmod 0600 (or 0640 with "
                             "the publisher's group)");
  }
  std::ifstream in(path);
  std::string line;
  std::getline(in, line);
  if (!line.empty() && line.back() == '\r') line.pop_back();
  if (!in && !in.eof()) throw std::runtime_error("password_file '" + path + "': cannot read it");
  if (line.empty()) throw std::runtime_error("password_file '" + path + "': empty first line");
  return line;
}

std::optional<PublishConfig> load_publish_config(const std::string& path,
                                                 nccomp::formats::Diagnostics& diag) {
  toml::table root;
  try {
    root = formats::parse_toml_file(path);
  } catch (const toml::parse_error& e) {
    nccomp::formats::Where w;
    w.file = path;
    w.line = static_cast<int>(e.source().begin.line);
    w.column = static_cast<int>(e.source().begin.column);
    diag.error(w, std::string(e.description()));
    return std::nullopt;
  }
  const std::string base = std::filesystem::absolute(path).parent_path().string();
  PublishConfig c;
  for (auto&& [k, v] : root) {
    const std::string_view key = k.str();
    if (key != "publish" && key != "source" && key != "broker" && key != "queue") {
      diag.error(&v, std::string(key), "unknown section (known: publish, source, broker, queue)");
    } else if (!v.is_table()) {
      diag.error(&v, std::string(key), "expected a table ([" + std::string(key) + "])");
    }
  }
  const toml::table empty;
  auto section = [&](const char* name) -> const toml::table& {
    const toml::table* t = root.get_as<toml::table>(name);
    return t != nullptr ? *t : empty;
  };
  bool missing = false;
  for (const char* required : {"publish", "broker"}) {
    if (root.get(required) == nullptr) {
      diag.error(nccomp::formats::Where{path, 1, 1, required}, "required section is missing");
      missing = true;
    }
  }
  if (missing) return std::nullopt;
  {
    nccomp::formats::TableReader r(section("publish"), "publish", diag);
    c.site = r.string("site", std::nullopt);
    c.machine = r.string("machine", std::nullopt);
    for (const char* key : {"site", "machine"}) {
      const std::string& v = std::string_view(key) == "site" ? c.site : c.machine;
      if (r.node().get(key) != nullptr && !ml::valid_machine_id(v)) {
        diag.error(r.where(key), "'" + v +
                                     "' is not a topic level: 1 to 64 letters, digits, '.', '_' "
                                     "or '-', starting with a letter or digit");
      }
    }
    c.heartbeat_s = r.number("heartbeat_s", 10.0, 1.0, 3600.0);
    r.finish();
  }
  {
    nccomp::formats::TableReader r(section("source"), "source", diag);
    c.log_directory = resolve(base, r.string("log_directory", c.log_directory));
    c.log_poll_s = r.number("poll_s", 0.2, 0.01, 60.0);
    c.status_socket = resolve(base, r.string("status_socket", c.status_socket));
    c.status_poll_s = r.number("status_poll_s", 1.0, 0.1, 3600.0);
    r.finish();
  }
  {
    nccomp::formats::TableReader r(section("broker"), "broker", diag);
    BrokerOptions& b = c.broker;
    b.uri = r.string("uri", std::nullopt);
    b.client_id = r.string("client_id", "");
    b.username = r.string("username", "");
    b.password_file = resolve(base, r.string("password_file", ""));
    b.ca_file = resolve(base, r.string("ca_file", ""));
    b.cert_file = resolve(base, r.string("cert_file", ""));
    b.key_file = resolve(base, r.string("key_file", ""));
    b.keepalive_s = static_cast<int>(r.integer("keepalive_s", 30, 5, 3600));
    b.session_expiry_s = r.integer("session_expiry_s", 7 * 86400, 60, 0xFFFFFFFE);
    b.max_inflight = static_cast<int>(r.integer("max_inflight", 64, 1, 65535));
    b.reconnect_max_s = r.number("reconnect_max_s", 30.0, 1.0, 3600.0);
    if (b.client_id.size() > 128) {
      diag.error(r.where("client_id"), "longer than 128 bytes");
    }
    if (r.node().get("uri") != nullptr) {
      if (const std::string e = check_broker(b); !e.empty()) diag.error(r.where("uri"), e);
    }
    r.finish();
    if (b.client_id.empty()) b.client_id = "nccomp-publish-" + c.site + "-" + c.machine;
  }
  {
    nccomp::formats::TableReader r(section("queue"), "queue", diag);
    c.queue_directory = resolve(base, r.string("directory", c.queue_directory));
    c.max_messages = r.integer("max_messages", 3'600'000, 16, std::int64_t{1} << 40);
    c.queue_fsync_interval_s = r.number("fsync_interval_s", 1.0, 0.0, 3600.0);
    r.finish();
  }
  if (!diag.ok()) return std::nullopt;
  return c;
}

}  // namespace nccomp::tools::mqtt
