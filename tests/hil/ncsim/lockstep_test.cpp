// ncsim as the lock-step clock master (contract C2) against a fake daemon peer: a Unix
// SOCK_SEQPACKET client that answers every TICK with DONE, reading the NC's Modbus tables and
// writing offsets with libmodbus in between, like nccompd's sync / flush.
#include <gtest/gtest.h>
#include <modbus/modbus.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <future>
#include <sstream>
#include <thread>

#include "drivers/modbus/encoding.hpp"
#include "sim/ncsim/config.hpp"
#include "sim/ncsim/lockstep.hpp"
#include "sim/ncsim/run.hpp"
#include "sim/ncsim/simulation.hpp"

namespace nccomp::sim::ncsim {
namespace {

namespace mb = drivers::modbus;

const std::string kConfig = std::string(NCCOMP_SOURCE_DIR) + "/config/ncsim.toml";

SimConfig small_face() {
  return load_sim_config(
      kConfig, {"ncsim.modbus_port=0", "ncsim.lockstep_rate_hz=200",
                "program.mould_face.size_x_mm=10", "program.mould_face.size_y_mm=1",
                "program.mould_face.measure_interval_mm=8", "program.mould_face.laser_trip_s=0.2",
                "thermal.enabled=false", "pitch.enabled=false", "hardness.enabled=false",
                "pushoff.enabled=false", "laser_noise.enabled=false", "wear.rate_um_per_m=100"});
}

int connect_seqpacket(const std::string& path) {
  for (int i = 0; i < 500; ++i) {
    const int fd = socket(AF_UNIX, SOCK_SEQPACKET, 0);
    sockaddr_un a{};
    a.sun_family = AF_UNIX;
    std::strncpy(a.sun_path, path.c_str(), sizeof(a.sun_path) - 1);
    if (connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)) == 0) {
      return fd;
    }
    close(fd);
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return -1;
}

struct PeerLog {
  std::vector<LockstepMessage> ticks;
  std::vector<double> wear_um;  // tool measurements seen
  int refused_errno{0};
  bool got_bye{false};
};

/// The fake daemon: write_at_s = when to write Z offset −3 µm (and one out-of-range value);
/// bye_after = cycles after which it leaves (0 = never).
PeerLog fake_daemon(const std::string& sock, std::uint16_t port, double write_at_s,
                    std::uint64_t bye_after) {
  PeerLog log;
  const int fd = connect_seqpacket(sock);
  EXPECT_GE(fd, 0);
  modbus_t* ctx = modbus_new_tcp("127.0.0.1", port);
  EXPECT_EQ(modbus_connect(ctx), 0);
  std::uint16_t last_seq = 0;
  bool wrote = false;
  for (;;) {
    unsigned char buf[64];
    const ssize_t n = recv(fd, buf, sizeof(buf), 0);
    if (n <= 0) {
      break;
    }
    LockstepMessage m{};
    std::string why;
    EXPECT_TRUE(parse_lockstep_message(buf, static_cast<std::size_t>(n), m, why)) << why;
    if (m.type == static_cast<std::uint32_t>(LockstepType::kBye)) {
      log.got_bye = true;
      break;
    }
    log.ticks.push_back(m);
    // sync(): one poll of the tool measurement group (input 100..104).
    std::uint16_t r[5];
    EXPECT_EQ(modbus_read_input_registers(ctx, 100, 5, r), 5);
    if (m.cycle > 0 && r[0] != last_seq) {
      mb::Encoding f32{mb::ValueType::kFloat32};
      log.wear_um.push_back(mb::decode(std::span<const std::uint16_t>(r + 2, 2), f32));
    }
    last_seq = r[0];
    // flush(): the writes of this cycle, answered before DONE.
    if (!wrote && static_cast<double>(m.time_ns) * 1e-9 >= write_at_s) {
      wrote = true;
      std::uint16_t z[2];
      mb::Encoding e{mb::ValueType::kFloat32, mb::WordOrder::kLowFirst};
      EXPECT_EQ(mb::encode(-3.0, e, z), mb::EncodeResult::kOk);
      EXPECT_EQ(modbus_write_registers(ctx, 234, 2, z), 2);
      std::uint16_t big[2];
      mb::Encoding i32{mb::ValueType::kInt32, mb::WordOrder::kHighFirst, mb::ByteOrder::kBigEndian,
                       0.1, 0.0};
      EXPECT_EQ(mb::encode(9000.0, i32, big), mb::EncodeResult::kOk);  // 9 mm: beyond 500 µm
      EXPECT_EQ(modbus_write_registers(ctx, 200, 2, big), -1);
      log.refused_errno = errno;
    }
    if (bye_after > 0 && m.cycle + 1 >= bye_after) {
      LockstepMessage bye{kLockstepMagic, 3, 0, 0};
      EXPECT_EQ(send(fd, &bye, sizeof(bye), 0), static_cast<ssize_t>(sizeof(bye)));
      break;
    }
    LockstepMessage done{kLockstepMagic, 2, m.cycle, m.time_ns};
    EXPECT_EQ(send(fd, &done, sizeof(done), 0), static_cast<ssize_t>(sizeof(done)));
  }
  modbus_close(ctx);
  modbus_free(ctx);
  close(fd);
  return log;
}

std::string slurp(const std::string& path) {
  std::ifstream in(path);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

struct PeerRun {
  RunSummary summary;
  PeerLog peer;
};

PeerRun run_with_peer(const std::string& tag, double write_at_s, std::uint64_t bye_after) {
  const SimConfig c = small_face();
  RunOptions o;
  o.program = ProgramKind::kMouldFace;
  o.out_dir = ::testing::TempDir() + "/ncsim_ls_" + tag;
  o.lockstep_socket = ::testing::TempDir() + "/ncsim_ls_" + tag + ".sock";
  o.connect_timeout_s = 10.0;
  std::promise<std::uint16_t> port;
  o.on_ready = [&](std::uint16_t p) { port.set_value(p); };
  PeerRun r;
  std::thread sim([&] { r.summary = run(c, o); });
  const std::uint16_t p = port.get_future().get();
  r.peer = fake_daemon(o.lockstep_socket, p, write_at_s, bye_after);
  sim.join();
  return r;
}

TEST(NcsimLockstep, FakeDaemonDrivesTheClockAndItsWritesLandInTheCut) {
  const PeerRun r = run_with_peer("a", 0.1, 0);
  ASSERT_TRUE(r.summary.completed);
  EXPECT_TRUE(r.peer.got_bye);
  // TICK k at k · 5 ms, every cycle, in order.
  ASSERT_GT(r.peer.ticks.size(), 100U);
  for (std::size_t k = 0; k < r.peer.ticks.size(); ++k) {
    EXPECT_EQ(r.peer.ticks[k].cycle, k);
    EXPECT_EQ(r.peer.ticks[k].time_ns, static_cast<std::int64_t>(k) * 5000000);
  }
  // 10 mm of cut, then the link and 10 mm more: one laser measurement after 8 mm = 0.8 µm.
  ASSERT_EQ(r.peer.wear_um.size(), 2U);
  EXPECT_NEAR(r.peer.wear_um[0], 0.8, 0.26);  // within one 5 ms cycle of cut (0.25 mm)
  EXPECT_NEAR(r.peer.wear_um[1], 1.6, 0.26);
  EXPECT_EQ(r.peer.refused_errno, EMBXILVAL);
  EXPECT_EQ(r.summary.writes, 1U);
  EXPECT_EQ(r.summary.refused, 1U);
  const std::string dir = ::testing::TempDir() + "/ncsim_ls_a";
  // The write is taken at the tick time it was made in (0.1 s), in force 20 ms later.
  EXPECT_EQ(slurp(dir + "/writes.csv"),
            "t_s,register_index,value_um,effective_t_s\n0.1,8,-3,0.12\n");
  const std::string json = slurp(dir + "/result.json");
  EXPECT_NE(json.find("\"writes_received\":1,\"writes_refused\":1,\"registers\":{\"8\":-3}"),
            std::string::npos)
      << json;
  // Surface: the Z offset of −3 µm is in force from 0.12 s = 6 mm on (first pass at 50 mm/s).
  std::istringstream s(slurp(dir + "/surface.csv"));
  std::string line;
  std::getline(s, line);
  EXPECT_EQ(line, "pass,path_mm,x_mm,y_mm,z_mm,error_um,offset_um");
  const MouldFaceConfig mf = small_face().mould_face;
  int rows = 0;
  while (std::getline(s, line)) {
    int pass = 0;
    double path = 0, x = 0, y = 0, z = 0, err = 0, off = 0;
    ASSERT_EQ(std::sscanf(line.c_str(), "%d,%lf,%lf,%lf,%lf,%lf,%lf", &pass, &path, &x, &y, &z,
                          &err, &off),
              7);
    const double nz = mould_face_normal(mf, x, y)[2];
    if (pass == 0 && path < 5.99) {
      EXPECT_EQ(off, 0.0) << path;
    } else if (pass == 0 && path > 6.01) {
      EXPECT_NEAR(off, 3.0 * nz, 1e-6) << path;
    }
    ++rows;
  }
  EXPECT_EQ(rows, 400);
}

TEST(NcsimLockstep, SameTicksGiveTheSameResultAndAnEarlyByeEndsTheRun) {
  const PeerRun a = run_with_peer("b1", 0.2, 0);
  const PeerRun b = run_with_peer("b2", 0.2, 0);
  const std::string da = ::testing::TempDir() + "/ncsim_ls_b1";
  const std::string db = ::testing::TempDir() + "/ncsim_ls_b2";
  EXPECT_EQ(slurp(da + "/surface.csv"), slurp(db + "/surface.csv"));
  EXPECT_EQ(slurp(da + "/writes.csv"), slurp(db + "/writes.csv"));
  EXPECT_EQ(a.peer.ticks.size(), b.peer.ticks.size());
  // The daemon leaves after 20 cycles: the result is written, the run is not complete.
  const PeerRun c = run_with_peer("c", 10.0, 20);
  EXPECT_FALSE(c.summary.completed);
  EXPECT_EQ(c.summary.cycles, 20U);
  EXPECT_NE(slurp(::testing::TempDir() + "/ncsim_ls_c/result.json").find("\"sim_time_s\":0.095"),
            std::string::npos);
}

// --lockstep-outage (a daemon restart, docs/ncsim.md): GIVEN register 8 as the NC's measure
// request, WHEN the fake daemon raises it at 0.05 s, THEN ncsim stops ticking once it is in
// force (nc.latency_s later); the
// daemon goes away without BYE (killed), ncsim machines 0.5 s alone (100 cycles, publishing: the
// laser measures every 8 mm meanwhile) and takes the daemon back; its next TICK is 100 cycles
// later, the tool measurement counter moved meanwhile, and the run completes.
TEST(NcsimLockstep, AnOutageMachinesOnWithoutTheDaemonAndTakesItBack) {
  const SimConfig c = load_sim_config(
      kConfig,
      {"ncsim.modbus_port=0", "ncsim.lockstep_rate_hz=200", "program.mould_face.size_x_mm=10",
       "program.mould_face.size_y_mm=1", "program.mould_face.measure_interval_mm=8",
       "program.mould_face.laser_trip_s=0.2", "nc.measure_request_register=8"});
  RunOptions o;
  o.program = ProgramKind::kMouldFace;
  o.out_dir = ::testing::TempDir() + "/ncsim_ls_outage";
  o.lockstep_socket = ::testing::TempDir() + "/ncsim_ls_outage.sock";
  o.connect_timeout_s = 10.0;
  o.outage_at_request = 1;
  o.outage_after_s = 0.0;
  o.outage_s = 0.5;
  std::promise<std::uint16_t> port;
  o.on_ready = [&](std::uint16_t p) { port.set_value(p); };
  RunSummary summary;
  std::thread sim([&] { summary = run(c, o); });
  const std::uint16_t p = port.get_future().get();

  modbus_t* ctx = modbus_new_tcp("127.0.0.1", p);
  ASSERT_EQ(modbus_connect(ctx), 0);
  const auto counter = [&] {
    std::uint16_t r = 0;
    EXPECT_EQ(modbus_read_input_registers(ctx, 100, 1, &r), 1);
    return r;
  };
  std::vector<std::uint64_t> cycles;
  std::uint16_t counter_at_pause = 0;
  std::uint16_t counter_back = 0;
  int fd = connect_seqpacket(o.lockstep_socket);
  ASSERT_GE(fd, 0);
  bool reconnected = false;
  for (;;) {
    pollfd pf{fd, POLLIN, 0};
    if (::poll(&pf, 1, 1000) == 0) {
      // No TICK for 1 s: the outage. Go away without BYE, come back.
      ASSERT_FALSE(reconnected);
      counter_at_pause = counter();
      close(fd);
      fd = connect_seqpacket(o.lockstep_socket);
      ASSERT_GE(fd, 0);
      reconnected = true;
      continue;
    }
    unsigned char buf[64];
    const ssize_t n = recv(fd, buf, sizeof(buf), 0);
    ASSERT_GT(n, 0);
    LockstepMessage m{};
    std::string why;
    ASSERT_TRUE(parse_lockstep_message(buf, static_cast<std::size_t>(n), m, why)) << why;
    if (m.type == static_cast<std::uint32_t>(LockstepType::kBye)) {
      break;
    }
    if (reconnected && counter_back == 0) {
      counter_back = counter();
    }
    cycles.push_back(m.cycle);
    if (m.cycle == 10) {  // 0.05 s: the request (1 µm in register 8, float32 at 234)
      std::uint16_t z[2];
      ASSERT_EQ(mb::encode(1.0, mb::Encoding{mb::ValueType::kFloat32, mb::WordOrder::kLowFirst}, z),
                mb::EncodeResult::kOk);
      ASSERT_EQ(modbus_write_registers(ctx, 234, 2, z), 2);
    }
    LockstepMessage done{kLockstepMagic, 2, m.cycle, m.time_ns};
    ASSERT_EQ(send(fd, &done, sizeof(done), 0), static_cast<ssize_t>(sizeof(done)));
  }
  close(fd);
  modbus_close(ctx);
  modbus_free(ctx);
  sim.join();
  EXPECT_TRUE(summary.completed);
  ASSERT_TRUE(reconnected);
  // The request written in cycle 10 is in force nc.latency_s later: ncsim stopped after that
  // cycle, went on alone for 100 cycles and ticked the one after them next.
  const auto in_force = static_cast<std::uint64_t>(10 + std::llround(c.nc.latency_s * 200.0));
  std::size_t gap = 0;
  for (std::size_t i = 1; i < cycles.size(); ++i) {
    if (cycles[i] != cycles[i - 1] + 1) {
      EXPECT_EQ(cycles[i - 1], in_force);
      EXPECT_EQ(cycles[i], in_force + 101U);
      ++gap;
    }
  }
  EXPECT_EQ(gap, 1U);
  EXPECT_EQ(counter_at_pause, 0U);
  EXPECT_GE(counter_back, 1U) << "the laser measured while the daemon was away";
}

}  // namespace
}  // namespace nccomp::sim::ncsim
