// nccompd over SocketCAN, run inside the CAN HIL VM on vcan0 (tests/hil/can/run_hil.sh). The test
// plays the NC with a raw CAN socket:
// - real time: a commissioning ramp's target, 12.3 µm, goes out as frame 0x300 with int32 123
//   (0.1 µm per count, little-endian), the NC's echo on 0x380 acknowledges it, the bus shows
//   up in `nccomp status`; SIGTERM exits 0;
// - lock-step (contract C2): per cycle the NC sends its axis frame and SYNC (0x7F0, the cycle),
//   the fake ncsim sends TICK; after DONE the frames up to SYNC-ACK (0x7F1, the cycle) hold the
//   cycle's ramp value, every axis frame is one event in the engine, BYE exits 0.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <optional>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "daemon/lockstep.hpp"
#include "daemon/status.hpp"

extern char** environ;

namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using nccomp::daemon::LockstepMessage;
using nccomp::daemon::LockstepType;

std::string config_text(double rate_hz) {
  std::ostringstream s;
  s << "[daemon]\nrate_hz = " << rate_hz << "\n"
    << "[state]\ndirectory = \"state\"\n"
    << "[measurement_log]\ndirectory = \"log\"\n"
    << "[status]\nsocket_path = \"status.sock\"\n"
    << "[can]\ninterface = \"vcan0\"\nack_timeout_s = 0.5\n"
    << "[[can.rx]]\nid = 0x100\nlength_bytes = 4\nevent = \"axis_sample\"\n"
    << "[[can.rx.signal]]\nname = \"x_mm\"\nstart_bit = 0\nlength_bits = 32\ntype = \"signed\"\n"
    << "scale = 0.0001\n"
    << "[[can.offset]]\nregister = 0\nid = 0x300\nlength_bytes = 4\nack_id = 0x380\n"
    << "[can.offset.value]\nstart_bit = 0\nlength_bits = 32\ntype = \"signed\"\nscale = 0.1\n"
    << "[[registers]]\nname = \"T1_length_wear\"\nkind = \"tool_length_wear\"\nbus = \"can\"\n"
    << "max_abs_um = 200\nmax_step_um = 5\nmax_rate_um_per_s = 1000\n"
    << "[[ramp]]\nname = \"commissioning\"\nregister = \"T1_length_wear\"\ntarget_um = 12.3\n"
    << "rate_um_per_s = 100\n";
  return s.str();
}

struct TempDir {
  TempDir() {
    path = fs::temp_directory_path() /
           ("nccompd_can_" + std::to_string(::getpid()) + "_" + std::to_string(n++));
    fs::remove_all(path);
    fs::create_directories(path);
  }
  ~TempDir() { fs::remove_all(path); }
  void write(const std::string& name, const std::string& text) const {
    std::ofstream(path / name) << text;
  }
  static inline int n = 0;
  fs::path path;
};

class Daemon {
 public:
  explicit Daemon(fs::path dir) : dir_(std::move(dir)) {}
  ~Daemon() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
  }
  void start(std::vector<std::string> extra_args = {}) {
    std::vector<std::string> args{NCCOMPD_BIN, "--config", (dir_ / "nccompd.toml").string()};
    args.insert(args.end(), extra_args.begin(), extra_args.end());
    std::vector<char*> argv;
    for (auto& a : args) {
      argv.push_back(a.data());
    }
    argv.push_back(nullptr);
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    const std::string log = (dir_ / "nccompd.log").string();
    posix_spawn_file_actions_addopen(&fa, 1, log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
    posix_spawn_file_actions_adddup2(&fa, 1, 2);
    ASSERT_EQ(posix_spawn(&pid_, NCCOMPD_BIN, &fa, nullptr, argv.data(), environ), 0);
    posix_spawn_file_actions_destroy(&fa);
  }
  void signal(int sig) const { ASSERT_EQ(::kill(pid_, sig), 0); }
  int wait(std::chrono::milliseconds limit = 20000ms) {
    const auto end = std::chrono::steady_clock::now() + limit;
    while (std::chrono::steady_clock::now() < end) {
      int st = 0;
      if (::waitpid(pid_, &st, WNOHANG) == pid_) {
        pid_ = -1;
        return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
      }
      std::this_thread::sleep_for(10ms);
    }
    return -1;
  }
  std::optional<std::string> status(const std::string& what = "json") const {
    try {
      auto s = nccomp::daemon::query_status((dir_ / "status.sock").string(), what);
      if (!s.empty()) {
        return s;
      }
    } catch (const std::exception&) {
    }
    return std::nullopt;
  }
  std::string log() const {
    // Through a stringstream: GCC 12 at -O2 flags istreambuf_iterator (-Wnull-dereference).
    std::ifstream in(dir_ / "nccompd.log");
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
  }

 private:
  fs::path dir_;
  pid_t pid_{-1};
};

double number(const std::string& json, const std::string& key) {
  const std::regex re("\"" + key + "\":(-?[0-9.eE+-]+)");
  std::smatch m;
  return std::regex_search(json, m, re) ? std::stod(m[1]) : -1e300;
}

// The NC's end of vcan0.
class Nc {
 public:
  Nc() {
    fd_ = ::socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
    EXPECT_GE(fd_, 0) << "no AF_CAN: run inside the HIL VM (tests/hil/can)";
    ifreq ifr{};
    std::strncpy(ifr.ifr_name, "vcan0", IFNAMSIZ - 1);
    EXPECT_EQ(::ioctl(fd_, SIOCGIFINDEX, &ifr), 0);
    sockaddr_can a{};
    a.can_family = AF_CAN;
    a.can_ifindex = ifr.ifr_ifindex;
    EXPECT_EQ(::bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
  }
  ~Nc() { ::close(fd_); }
  void send(std::uint32_t id, std::uint64_t value, std::uint8_t len) {
    can_frame f{};
    f.can_id = id;
    f.len = len;
    for (int i = 0; i < len; ++i) {
      f.data[i] = static_cast<std::uint8_t>(value >> (8 * i));
    }
    ASSERT_EQ(::write(fd_, &f, sizeof f), static_cast<ssize_t>(sizeof f));
  }
  /// Next frame within limit; nullopt on timeout.
  std::optional<can_frame> receive(std::chrono::milliseconds limit) {
    pollfd p{fd_, POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(limit.count())) != 1) {
      return std::nullopt;
    }
    can_frame f{};
    if (::read(fd_, &f, sizeof f) != static_cast<ssize_t>(sizeof f)) {
      return std::nullopt;
    }
    return f;
  }
  /// An offset write frame: echo it on the acknowledge ID as the NC does; its value [counts].
  std::int32_t take_write(const can_frame& f) {
    std::uint32_t raw = 0;
    for (int i = 3; i >= 0; --i) {
      raw = (raw << 8) | f.data[i];
    }
    send(0x380, raw, 4);
    return static_cast<std::int32_t>(raw);
  }

 private:
  int fd_{-1};
};

TEST(NccompdCan, RealTimeOffsetFrameCarriesTheScaledValue) {
  TempDir d;
  d.write("nccompd.toml", config_text(200.0));
  Nc nc;
  Daemon daemon(d.path);
  daemon.start();
  std::int32_t last = -1;
  const auto end = std::chrono::steady_clock::now() + 15s;
  while (last != 123 && std::chrono::steady_clock::now() < end) {
    if (auto f = nc.receive(100ms); f && (f->can_id & CAN_SFF_MASK) == 0x300) {
      last = nc.take_write(*f);
    }
  }
  ASSERT_EQ(last, 123) << daemon.log();
  std::string st;
  const auto end2 = std::chrono::steady_clock::now() + 5s;
  while (std::chrono::steady_clock::now() < end2) {
    st = daemon.status().value_or("");
    if (st.find("{\"name\":\"can\",\"state\":\"up\"") != std::string::npos &&
        number(st, "offsets_written") >= 1) {
      break;
    }
    std::this_thread::sleep_for(20ms);
  }
  EXPECT_NE(st.find("{\"name\":\"can\",\"state\":\"up\",\"alarm\":false"), std::string::npos) << st;
  EXPECT_GE(number(st, "offsets_written"), 1) << st;
  daemon.signal(SIGTERM);
  EXPECT_EQ(daemon.wait(), 0) << daemon.log();
}

class Peer {
 public:
  explicit Peer(const std::string& path) : path_(path) {
    listen_fd_ = ::socket(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0);
    sockaddr_un a{};
    a.sun_family = AF_UNIX;
    std::snprintf(a.sun_path, sizeof a.sun_path, "%s", path.c_str());
    EXPECT_EQ(::bind(listen_fd_, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
    EXPECT_EQ(::listen(listen_fd_, 1), 0);
  }
  ~Peer() {
    if (fd_ >= 0) {
      ::close(fd_);
    }
    ::close(listen_fd_);
    ::unlink(path_.c_str());
  }
  bool accept_daemon(std::chrono::milliseconds limit) {
    pollfd p{listen_fd_, POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(limit.count())) != 1) {
      return false;
    }
    fd_ = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC);
    return fd_ >= 0;
  }
  void send(LockstepType t, std::uint64_t cycle, std::int64_t time_ns) {
    const auto b = nccomp::daemon::encode_lockstep({t, cycle, time_ns});
    ASSERT_EQ(::send(fd_, b.data(), b.size(), MSG_NOSIGNAL), 24);
  }
  bool receive(LockstepMessage& m) {
    pollfd p{fd_, POLLIN, 0};
    if (::poll(&p, 1, 10000) != 1) {
      return false;
    }
    std::array<std::uint8_t, 64> buf{};
    const ssize_t n = ::recv(fd_, buf.data(), buf.size(), 0);
    return n > 0 && nccomp::daemon::decode_lockstep(
                        std::span<const std::uint8_t>(buf.data(), static_cast<std::size_t>(n)),
                        m) == nccomp::daemon::LockstepDecode::kOk;
  }

 private:
  std::string path_;
  int listen_fd_{-1};
  int fd_{-1};
};

TEST(NccompdCan, LockstepWritesPrecedeSyncAckOfTheirCycle) {
  TempDir d;
  d.write("nccompd.toml", config_text(1000.0));
  const std::string sock = (d.path / "ls.sock").string();
  Peer peer(sock);
  Nc nc;
  Daemon daemon(d.path);
  daemon.start({"--lockstep", sock});
  ASSERT_TRUE(peer.accept_daemon(20s)) << daemon.log();
  constexpr int kTicks = 150;
  std::int32_t value = -1;
  for (int k = 1; k <= kTicks; ++k) {
    nc.send(0x100, static_cast<std::uint64_t>(10 * k), 4);  // X = k µm
    nc.send(0x7F0, static_cast<std::uint64_t>(k), 8);       // SYNC of cycle k
    peer.send(LockstepType::kTick, static_cast<std::uint64_t>(k), std::int64_t{k} * 1'000'000);
    LockstepMessage m;
    ASSERT_TRUE(peer.receive(m)) << "no DONE for cycle " << k << "\n" << daemon.log();
    ASSERT_EQ(m.cycle, static_cast<std::uint64_t>(k));
    // Everything the daemon sent for cycle k is on the bus before its SYNC-ACK.
    bool acked = false;
    while (!acked) {
      auto f = nc.receive(5000ms);
      ASSERT_TRUE(f.has_value()) << "no SYNC-ACK for cycle " << k << "\n" << daemon.log();
      const std::uint32_t id = f->can_id & CAN_SFF_MASK;
      if (id == 0x300) {
        value = nc.take_write(*f);
      } else if (id == 0x7F1) {
        std::uint64_t c = 0;
        for (int i = 7; i >= 0; --i) {
          c = (c << 8) | f->data[i];
        }
        acked = c == static_cast<std::uint64_t>(k);
      }
    }
    ASSERT_EQ(value, std::min(k - 1, 123)) << "cycle " << k;
  }
  const std::string st = daemon.status().value_or("");
  EXPECT_EQ(number(st, "events_in"), kTicks) << st;
  peer.send(LockstepType::kBye, kTicks, 0);
  EXPECT_EQ(daemon.wait(), 0) << daemon.log();
}

}  // namespace
