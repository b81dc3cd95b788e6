// Lock-step (contract C2). GIVEN the loop driven by a fake ncsim peer over a Unix SOCK_SEQPACKET
// socket and a loopback bus, WHEN the peer sends TICKs, THEN each TICK gets exactly one DONE for
// the same cycle, events carry the tick's time, the same TICK sequence gives byte-identical
// measurement logs and state, BYE and a closed socket end the run cleanly, a malformed message
// ends it with the reason, and a bus that does not answer is counted without a deadlock.
#include "daemon/lockstep.hpp"

#include <gtest/gtest.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

#include "daemon/loop.hpp"
#include "drivers/loopback/loopback_bus.hpp"
#include "drivers/modbus/config.hpp"
#include "drivers/modbus/modbus_bus.hpp"

namespace nccomp::daemon {
namespace {

using drivers::loopback::LoopbackBus;

namespace fs = std::filesystem;
using namespace std::chrono_literals;

TEST(LockstepCodec, LittleEndianLayoutAndValidation) {
  // GIVEN a TICK of cycle 0x0102 at 0x0A0B0C ns WHEN encoded THEN the bytes are the contract's
  const auto b = encode_lockstep({LockstepType::kTick, 0x0102, 0x0A0B0C});
  const std::array<std::uint8_t, 24> want = {0x4D, 0x53, 0x43, 0x4E, 1, 0, 0, 0,
                                             0x02, 0x01, 0,    0,    0, 0, 0, 0,
                                             0x0C, 0x0B, 0x0A, 0,    0, 0, 0, 0};
  EXPECT_EQ(b, want);
  LockstepMessage m;
  ASSERT_EQ(decode_lockstep(b, m), LockstepDecode::kOk);
  EXPECT_EQ(m.type, LockstepType::kTick);
  EXPECT_EQ(m.cycle, 0x0102U);
  EXPECT_EQ(m.time_ns, 0x0A0B0C);
  // Negative times survive the round trip (two's complement).
  ASSERT_EQ(decode_lockstep(encode_lockstep({LockstepType::kBye, 7, -5}), m), LockstepDecode::kOk);
  EXPECT_EQ(m.time_ns, -5);
  auto bad = b;
  bad[0] = 0;
  EXPECT_EQ(decode_lockstep(bad, m), LockstepDecode::kWrongMagic);
  bad = b;
  bad[4] = 4;
  EXPECT_EQ(decode_lockstep(bad, m), LockstepDecode::kUnknownType);
  EXPECT_EQ(decode_lockstep(std::span<const std::uint8_t>(b.data(), 23), m),
            LockstepDecode::kWrongSize);
}

// The ncsim side of the socket, driven by the test thread.
class FakeNcsim {
 public:
  explicit FakeNcsim(const std::string& path) : path_(path) {
    listen_fd_ = ::socket(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0);
    sockaddr_un a{};
    a.sun_family = AF_UNIX;
    std::snprintf(a.sun_path, sizeof a.sun_path, "%s", path.c_str());
    ::unlink(path.c_str());
    EXPECT_EQ(::bind(listen_fd_, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
    EXPECT_EQ(::listen(listen_fd_, 1), 0);
  }
  ~FakeNcsim() {
    close_peer();
    ::close(listen_fd_);
    ::unlink(path_.c_str());
  }
  void accept_daemon() { fd_ = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC); }
  void send_raw(const std::uint8_t* p, std::size_t n) {
    ASSERT_EQ(::send(fd_, p, n, MSG_NOSIGNAL), static_cast<ssize_t>(n));
  }
  void send(LockstepType t, std::uint64_t cycle, core::TimeNs time_ns) {
    const auto b = encode_lockstep({t, cycle, time_ns});
    send_raw(b.data(), b.size());
  }
  // Next message from the daemon (5 s limit); false on timeout / close.
  bool receive(LockstepMessage& m) {
    timeval tv{5, 0};
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    std::array<std::uint8_t, 64> buf{};
    const ssize_t n = ::recv(fd_, buf.data(), buf.size(), 0);
    return n > 0 &&
           decode_lockstep(std::span<const std::uint8_t>(buf.data(), static_cast<std::size_t>(n)),
                           m) == LockstepDecode::kOk;
  }
  // TICK, then the DONE that must answer it.
  void tick(std::uint64_t cycle, core::TimeNs time_ns) {
    send(LockstepType::kTick, cycle, time_ns);
    LockstepMessage m;
    ASSERT_TRUE(receive(m)) << "no DONE for cycle " << cycle;
    EXPECT_EQ(m.type, LockstepType::kDone);
    EXPECT_EQ(m.cycle, cycle);
    EXPECT_EQ(m.time_ns, time_ns);
  }
  void close_peer() {
    if (fd_ >= 0) {
      ::close(fd_);
      fd_ = -1;
    }
  }

 private:
  std::string path_;
  int listen_fd_{-1};
  int fd_{-1};
};

// Each tool measurement becomes a record and the register's target (the measured wear).
class WearModule final : public core::engine::Module {
 public:
  std::string_view name() const noexcept override { return "wear"; }
  void attach(const core::engine::RegisterTable& /*registers*/) override {}
  void step(core::TimeNs now_ns, std::span<const core::Event> events,
            core::StepOutput& out) noexcept override {
    for (const auto& e : events) {
      if (const auto* m = std::get_if<core::ToolMeasurement>(&e)) {
        core::MeasurementRecord r;
        r.time_ns = m->time_ns;  // the event's time: lock-step stamps it with the tick's
        r.tool = m->tool;
        r.kind = core::MeasurementKind::kToolWear;
        r.measured_um = m->wear_um[0];
        out.records.push(r);
        out.writes.push(core::OffsetWrite{now_ns, 0, m->wear_um[0]});
        ++generation_;
      }
    }
  }
  std::size_t state_capacity() const noexcept override { return sizeof(std::uint64_t); }
  std::size_t save_state(std::span<std::byte> buf) const noexcept override {
    std::memcpy(buf.data(), &generation_, sizeof generation_);
    return sizeof generation_;
  }
  bool load_state(std::span<const std::byte> bytes) noexcept override {
    return bytes.size() == sizeof generation_;
  }
  std::uint64_t state_generation() const noexcept override { return generation_; }

 private:
  std::uint64_t generation_{0};
};

std::unique_ptr<Runtime> wear_runtime() {
  auto rt = std::make_unique<Runtime>();
  rt->engine = std::make_unique<core::engine::Engine>();
  std::vector<std::unique_ptr<core::engine::Module>> m;
  m.push_back(std::make_unique<WearModule>());
  rt->engine->configure(
      {{"T1", core::engine::RegisterKind::kToolLengthWear, {1000.0, 1000.0, 1e6}}}, std::move(m));
  rt->register_bus = {0};
  return rt;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

fs::path temp_dir(const std::string& tag) {
  static int counter = 0;
  auto d = fs::temp_directory_path() /
           ("nccomp_ls_" + tag + std::to_string(::getpid()) + "_" + std::to_string(counter++));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

struct RunResult {
  std::string measurements;
  std::vector<std::byte> state;
  double delivered_um{0.0};
  LoopStats stats{};
  LockstepEnd end{LockstepEnd::kRunning};
};

// One lock-step run of `ticks` cycles at 1 kHz of simulated time starting at 5 s; a tool
// measurement of wear 0.5·k µm is published before every 7th TICK.
RunResult run_once(int ticks) {
  const fs::path dir = temp_dir("run");
  RunResult res;
  LoopbackBus bus(256, 256);
  core::rt::ConfigSwap<Runtime> swap(wear_runtime());
  StatePersister persister((dir / "state.bin").string(), 4096);
  MeasurementLogWriter mlog(dir.string(), 1 << 20, 2, 256);
  FakeNcsim ncsim((dir / "ls.sock").string());
  LockstepPeer peer;
  peer.connect((dir / "ls.sock").string(), 2.0);
  ncsim.accept_daemon();
  LoopOptions o;
  o.lockstep = &peer;
  o.state_min_interval_s = 0.002;  // simulated seconds: several exports in the run
  o.state_buffer_bytes = 4096;
  Loop loop(o, swap, {&bus}, &persister, &mlog);
  bus.set_lockstep(true);
  bus.start();
  persister.start(0);
  mlog.start();
  loop.start();
  for (int k = 1; k <= ticks; ++k) {
    if (k % 7 == 0) {
      core::ToolMeasurement m;
      m.time_ns = 123;  // the driver's reception time: must be replaced by the tick's
      m.tool = 3;
      m.wear_um[0] = 0.5 * k;
      m.point_count = 1;
      EXPECT_TRUE(bus.inject(m));
    }
    ncsim.tick(static_cast<std::uint64_t>(k), 5'000'000'000 + k * 1'000'000);
  }
  ncsim.send(LockstepType::kBye, static_cast<std::uint64_t>(ticks), 0);
  const auto limit = std::chrono::steady_clock::now() + 5s;
  while (!loop.finished() && std::chrono::steady_clock::now() < limit) {
    std::this_thread::sleep_for(1ms);
  }
  EXPECT_TRUE(loop.finished());
  res.end = loop.lockstep_end();
  loop.stop();
  res.stats = loop.stats();
  // As the daemon does at exit: the persister drains what the loop queued, then the final state
  // is written synchronously (the other order lets a queued older state overwrite it).
  persister.stop();
  std::vector<std::byte> buf(swap.current().engine->state_capacity());
  const std::size_t n = swap.current().engine->export_state(buf);
  persister.write_now(std::span<const std::byte>(buf.data(), n));
  mlog.stop();
  const auto limit2 = std::chrono::steady_clock::now() + 2s;
  while (!bus.delivered(0) && std::chrono::steady_clock::now() < limit2) {
    std::this_thread::sleep_for(1ms);
  }
  res.delivered_um = bus.delivered(0).value_or(-1.0);
  bus.stop();
  res.measurements = slurp(dir / "measurements.csv");
  res.state = read_state_file((dir / "state.bin").string()).payload;
  fs::remove_all(dir);
  return res;
}

TEST(Lockstep, SameTicksGiveIdenticalLogAndStateAndTickTimes) {
  const RunResult a = run_once(60);
  const RunResult b = run_once(60);
  EXPECT_EQ(a.end, LockstepEnd::kBye);
  EXPECT_EQ(a.stats.cycles, 60U);
  EXPECT_EQ(a.stats.lockstep_cycle, 60U);
  EXPECT_EQ(a.stats.lockstep_time_ns, 5'060'000'000);
  EXPECT_EQ(a.stats.sync_timeouts + a.stats.flush_timeouts, 0U);
  EXPECT_EQ(a.stats.records, 8U);  // k = 7, 14, ..., 56
  // The last measurement (k = 56: 28 µm) is the register's value on the bus.
  EXPECT_DOUBLE_EQ(a.delivered_um, 28.0);
  // Records carry the tick's simulated time, as the time since the machine's warm start
  // (core/engine/context.hpp; the axes never move here, so since the first tick at 5.001 s):
  // k = 7 → 5.007 s − 5.001 s.
  EXPECT_NE(a.measurements.find("\n0.006000,"), std::string::npos) << a.measurements;
  EXPECT_EQ(a.measurements.find("0.000000123"), std::string::npos);
  ASSERT_FALSE(a.state.empty());
  EXPECT_EQ(a.measurements, b.measurements);
  EXPECT_EQ(a.state, b.state);
}

// Runs the loop against a peer that the test script drives; returns how the run ended.
LockstepEnd end_after(const std::function<void(FakeNcsim&)>& script) {
  const fs::path dir = temp_dir("end");
  LoopbackBus bus(16, 16);
  core::rt::ConfigSwap<Runtime> swap(wear_runtime());
  FakeNcsim ncsim((dir / "ls.sock").string());
  LockstepPeer peer;
  peer.connect((dir / "ls.sock").string(), 2.0);
  ncsim.accept_daemon();
  LoopOptions o;
  o.lockstep = &peer;
  Loop loop(o, swap, {&bus}, nullptr, nullptr);
  bus.start();
  loop.start();
  script(ncsim);
  const auto limit = std::chrono::steady_clock::now() + 5s;
  while (!loop.finished() && std::chrono::steady_clock::now() < limit) {
    std::this_thread::sleep_for(1ms);
  }
  const bool finished = loop.finished();
  loop.stop();
  bus.stop();
  fs::remove_all(dir);
  return finished ? loop.lockstep_end() : LockstepEnd::kRunning;
}

TEST(Lockstep, RunEndsOnByeCloseBadMessageAndBadSequence) {
  EXPECT_EQ(end_after([](FakeNcsim& n) {
              n.tick(1, 1'000'000);
              n.close_peer();
            }),
            LockstepEnd::kClosed);
  EXPECT_EQ(end_after([](FakeNcsim& n) {
              const std::uint8_t junk[5] = {1, 2, 3, 4, 5};
              n.send_raw(junk, sizeof junk);
            }),
            LockstepEnd::kBadMessage);
  EXPECT_EQ(end_after([](FakeNcsim& n) {
              n.tick(5, 5'000'000);
              n.send(LockstepType::kTick, 5, 6'000'000);  // the same cycle again
            }),
            LockstepEnd::kBadSequence);
  EXPECT_EQ(end_after([](FakeNcsim& n) {
              n.tick(1, 1'000'000);
              n.send(LockstepType::kBye, 1, 0);
            }),
            LockstepEnd::kBye);
}

TEST(Lockstep, ConnectGivesUpWithTheReason) {
  LockstepPeer peer;
  try {
    peer.connect("/nonexistent-dir/ls.sock", 0.1);
    FAIL() << "connect to a missing socket must throw";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent-dir/ls.sock"), std::string::npos);
  }
}

// A Modbus NC that is not there: sync() and flush() time out, are counted, and every TICK still
// gets its DONE (no deadlock between the daemon and the peer).
TEST(Lockstep, BusTimeoutsAreCountedAndTheCycleCompletes) {
  drivers::modbus::ModbusConfig mc = drivers::modbus::parse_modbus_config(R"([modbus]
transport = "tcp"
host = "127.0.0.1"
port = 9
response_timeout_s = 0.05
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int32", scale = 0.0001 }
[[modbus.offset]]
register_index = 0
address = 200
type = "int32"
scale = 0.1
)",
                                                                          "t.toml");
  drivers::modbus::ModbusBus bus(mc);
  const fs::path dir = temp_dir("timeout");
  core::rt::ConfigSwap<Runtime> swap(wear_runtime());
  FakeNcsim ncsim((dir / "ls.sock").string());
  LockstepPeer peer;
  peer.connect((dir / "ls.sock").string(), 2.0);
  ncsim.accept_daemon();
  LoopOptions o;
  o.lockstep = &peer;
  o.lockstep_bus_timeout_ns = 30'000'000;
  Loop loop(o, swap, {&bus}, nullptr, nullptr);
  bus.set_lockstep(true);
  bus.start();
  loop.start();
  for (std::uint64_t k = 1; k <= 3; ++k) {
    ncsim.tick(k, static_cast<core::TimeNs>(k) * 1'000'000);
  }
  ncsim.send(LockstepType::kBye, 3, 0);
  const auto limit = std::chrono::steady_clock::now() + 5s;
  while (!loop.finished() && std::chrono::steady_clock::now() < limit) {
    std::this_thread::sleep_for(1ms);
  }
  loop.stop();
  bus.stop();
  const LoopStats s = loop.stats();
  EXPECT_EQ(s.cycles, 3U);
  EXPECT_EQ(s.sync_timeouts, 3U);
  EXPECT_EQ(s.flush_timeouts, 3U);
  EXPECT_EQ(s.last_timeout_bus, 0);
  EXPECT_EQ(s.last_timeout_cycle, 3U);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace nccomp::daemon
