// ncsim over CAN in lock-step (contract C2), against a fake daemon on vcan0: per TICK the peer
// reads the bus up to SYNC(cycle), writes an offset once, sends SYNC-ACK(cycle), then DONE. Needs
// a working vcan0: run inside tests/hil/vm/run_in_vm.sh (tests/hil/can runs it in its one VM).
#include <gtest/gtest.h>
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <fstream>
#include <future>
#include <sstream>
#include <thread>

#include "drivers/can/can_config.hpp"
#include "sim/ncsim/can_link.hpp"
#include "sim/ncsim/config.hpp"
#include "sim/ncsim/lockstep.hpp"
#include "sim/ncsim/run.hpp"

namespace nccomp::sim::ncsim {
namespace {

const std::string kConfig = std::string(NCCOMP_SOURCE_DIR) + "/config/ncsim.toml";

int open_can(const char* ifname) {
  const int s = socket(PF_CAN, SOCK_RAW, CAN_RAW);
  ifreq ifr{};
  std::strncpy(ifr.ifr_name, ifname, IFNAMSIZ - 1);
  if (s < 0 || ioctl(s, SIOCGIFINDEX, &ifr) < 0) {
    return -1;
  }
  sockaddr_can a{};
  a.can_family = AF_CAN;
  a.can_ifindex = ifr.ifr_ifindex;
  if (bind(s, reinterpret_cast<sockaddr*>(&a), sizeof a) < 0) {
    return -1;
  }
  return s;
}

void send_can(int s, std::uint32_t id, const std::uint8_t* data, std::uint8_t len) {
  can_frame f{};
  f.can_id = id;
  f.len = len;
  std::memcpy(f.data, data, len);
  ASSERT_EQ(write(s, &f, sizeof f), static_cast<ssize_t>(sizeof f));
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

std::string slurp(const std::string& path) {
  std::ifstream in(path);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

TEST(NcsimCan, LockstepOverVcanSyncAckAndAcknowledgedWrites) {
  const int probe = open_can("vcan0");
  if (probe < 0) {
    GTEST_SKIP() << "no vcan0 here: run inside tests/hil/vm/run_in_vm.sh";
  }
  close(probe);
  const SimConfig c = load_sim_config(
      kConfig, {"ncsim.lockstep_rate_hz=200", "program.mould_face.size_x_mm=10",
                "program.mould_face.size_y_mm=1", "program.mould_face.measure_interval_mm=0",
                "thermal.enabled=false", "pitch.enabled=false", "hardness.enabled=false",
                "pushoff.enabled=false", "wear.rate_um_per_m=0", "wear.initial_um=5"});
  const drivers::can::CanConfig can =
      drivers::can::parse_can_config(c.can_bus_map_text, c.can_bus_map_file);
  // The tool length wear register (logical 0, acknowledged on its ack ID) takes the writes.
  const drivers::can::TxRegister* z = nullptr;
  for (const auto& r : can.mapping.offsets) {
    if (r.register_index == static_cast<std::uint16_t>(c.nc.tool_length_register)) {
      z = &r;
    }
  }
  ASSERT_NE(z, nullptr) << "the CAN map has no register " << c.nc.tool_length_register;
  ASSERT_TRUE(z->ack.has_value());
  RunOptions o;
  o.bus = BusKind::kCan;
  o.out_dir = ::testing::TempDir() + "/ncsim_can";
  o.lockstep_socket = ::testing::TempDir() + "/ncsim_can.sock";
  RunSummary summary;
  std::thread sim([&] { summary = run(c, o); });
  const int ls = connect_seqpacket(o.lockstep_socket);
  ASSERT_GE(ls, 0);
  const int bus = open_can("vcan0");
  ASSERT_GE(bus, 0);
  std::uint64_t ticks = 0;
  int acks = 0;
  int axis_frames = 0;
  bool wrote = false;
  for (;;) {
    LockstepMessage m{};
    if (recv(ls, &m, sizeof m, 0) != static_cast<ssize_t>(sizeof m) || m.type != 1) {
      break;
    }
    EXPECT_EQ(m.cycle, ticks);
    // sync(): the bus up to SYNC(cycle) (the NC sent it before TICK).
    for (;;) {
      can_frame f{};
      ASSERT_EQ(read(bus, &f, sizeof f), static_cast<ssize_t>(sizeof f));
      if (f.can_id == kCanSyncId) {
        std::uint64_t cyc = 0;
        std::memcpy(&cyc, f.data, 8);
        EXPECT_EQ(cyc, m.cycle);
        break;
      }
      if (f.can_id == 0x100) {
        ++axis_frames;
      }
      if (z->ack && f.can_id == z->ack->id) {
        ++acks;
      }
    }
    if (!wrote && m.time_ns >= 100000000) {
      wrote = true;
      std::array<std::uint8_t, drivers::can::kMaxPayloadBytes> p{};
      ASSERT_TRUE(drivers::can::encode_offset(*z, -4.0, p));
      send_can(bus, z->id, p.data(), z->length_bytes);
      ASSERT_TRUE(drivers::can::encode_offset(*z, 9000.0, p));  // beyond the NC's 500 µm
      send_can(bus, z->id, p.data(), z->length_bytes);
    }
    const std::uint8_t ack[8] = {
        static_cast<std::uint8_t>(m.cycle),        static_cast<std::uint8_t>(m.cycle >> 8U),
        static_cast<std::uint8_t>(m.cycle >> 16U), static_cast<std::uint8_t>(m.cycle >> 24U),
        static_cast<std::uint8_t>(m.cycle >> 32U), static_cast<std::uint8_t>(m.cycle >> 40U),
        static_cast<std::uint8_t>(m.cycle >> 48U), static_cast<std::uint8_t>(m.cycle >> 56U)};
    send_can(bus, kCanSyncAckId, ack, 8);
    LockstepMessage done{kLockstepMagic, 2, m.cycle, m.time_ns};
    ASSERT_EQ(send(ls, &done, sizeof done, 0), static_cast<ssize_t>(sizeof done));
    ++ticks;
  }
  sim.join();
  close(bus);
  close(ls);
  EXPECT_TRUE(summary.completed);
  EXPECT_GT(ticks, 80U);
  EXPECT_GE(axis_frames, static_cast<int>(ticks) - 1);
  EXPECT_EQ(acks, 1);  // the accepted write, not the refused one
  EXPECT_EQ(summary.writes, 1U);
  EXPECT_EQ(summary.refused, 1U);
  EXPECT_EQ(slurp(o.out_dir + "/writes.csv"), "t_s,register_index,value_um,effective_t_s\n0.1," +
                                                  std::to_string(c.nc.tool_length_register) +
                                                  ",-4,0.12\n");
  EXPECT_NE(slurp(o.out_dir + "/result.json").find("\"bus\":\"can\""), std::string::npos);
}

}  // namespace
}  // namespace nccomp::sim::ncsim
