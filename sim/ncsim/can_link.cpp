#include "sim/ncsim/can_link.hpp"

#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <stdexcept>

#include "sim/can_nc/can_nc.hpp"

namespace nccomp::sim::ncsim {

namespace dc = drivers::can;

CanLink::CanLink(dc::CanConfig config, std::string interface, double limit_um)
    : config_(std::move(config)), interface_(std::move(interface)), limit_um_(limit_um) {}

CanLink::~CanLink() { stop(); }

void CanLink::start() {
  sock_ = ::socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
  if (sock_ < 0) {
    throw std::runtime_error(std::string("ncsim: CAN socket: ") + std::strerror(errno));
  }
  ifreq ifr{};
  std::strncpy(ifr.ifr_name, interface_.c_str(), IFNAMSIZ - 1);
  if (::ioctl(sock_, SIOCGIFINDEX, &ifr) < 0) {
    const std::string why = std::strerror(errno);
    stop();
    throw std::runtime_error("ncsim: CAN interface " + interface_ + ": " + why);
  }
  if (config_.mapping.fd) {
    const int on = 1;
    (void)::setsockopt(sock_, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof on);
  }
  std::vector<can_filter> filters;
  for (const auto& r : config_.mapping.offsets) {
    can_filter f{};
    f.can_id = r.extended ? (r.id | CAN_EFF_FLAG) : r.id;
    f.can_mask = (r.extended ? CAN_EFF_MASK : CAN_SFF_MASK) | CAN_EFF_FLAG | CAN_RTR_FLAG;
    filters.push_back(f);
  }
  filters.push_back({kCanSyncAckId, CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG});
  (void)::setsockopt(sock_, SOL_CAN_RAW, CAN_RAW_FILTER, filters.data(),
                     static_cast<socklen_t>(filters.size() * sizeof(can_filter)));
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = ifr.ifr_ifindex;
  if (::bind(sock_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) < 0) {
    const std::string why = std::strerror(errno);
    stop();
    throw std::runtime_error("ncsim: CAN bind " + interface_ + ": " + why);
  }
}

void CanLink::stop() {
  if (sock_ >= 0) {
    ::close(sock_);
    sock_ = -1;
  }
}

namespace {

void send_frame(int sock, const can_nc::Frame& fr, bool fd) {
  canfd_frame f{};
  f.can_id = fr.extended ? (fr.id | CAN_EFF_FLAG) : fr.id;
  f.len = fr.length_bytes;
  std::memcpy(f.data, fr.data.data(), fr.length_bytes);
  const std::size_t size = (fd && fr.length_bytes > 8) ? CANFD_MTU : CAN_MTU;
  // A full transmit queue (ENOBUFS) is waited out briefly: a real NC's frames are not lost.
  for (int tries = 0; tries < 1000; ++tries) {
    if (::write(sock, &f, size) == static_cast<ssize_t>(size)) {
      return;
    }
    if (errno != ENOBUFS && errno != EAGAIN) {
      throw std::runtime_error(std::string("ncsim: CAN write: ") + std::strerror(errno));
    }
    pollfd p{sock, POLLOUT, 0};
    (void)::poll(&p, 1, 1);
  }
  throw std::runtime_error("ncsim: CAN transmit queue stays full");
}

}  // namespace

void CanLink::publish(const core::AxisSample& axis, const std::array<double, 2>& temperatures_c,
                      const std::vector<core::Event>& events, double /*hold_s*/) {
  auto send_event = [&](const core::Event& e) {
    std::vector<can_nc::Frame> frames;
    try {
      frames = can_nc::encode_event(config_.mapping, e);
    } catch (const std::invalid_argument&) {
      ++unmapped_;  // this NC profile does not carry that event, or a value does not fit
      return;
    }
    for (const auto& f : frames) {
      send_frame(sock_, f, config_.mapping.fd);
    }
  };
  for (const core::Event& e : events) {
    send_event(e);
  }
  send_event(axis);
  // Temperatures go out when they changed by 0.01 °C (the NC's resolution in the reference map).
  for (std::uint8_t s = 0; s < 2; ++s) {
    if (std::fabs(temperatures_c[s] - last_temperature_c_[s]) >= 0.01) {
      last_temperature_c_[s] = temperatures_c[s];
      send_event(core::TemperatureSample{axis.time_ns, s, temperatures_c[s]});
    }
  }
}

void CanLink::before_tick(std::uint64_t cycle) {
  can_nc::Frame f{};
  f.id = kCanSyncId;
  f.length_bytes = 8;
  for (std::size_t i = 0; i < 8; ++i) {
    f.data[i] = static_cast<std::uint8_t>(cycle >> (8U * i));
  }
  send_frame(sock_, f, false);
}

long long CanLink::read_one(int timeout_ms) {
  pollfd p{sock_, POLLIN, 0};
  if (::poll(&p, 1, timeout_ms) <= 0) {
    return -2;
  }
  canfd_frame f{};
  const ssize_t n = ::read(sock_, &f, sizeof f);
  if (n < static_cast<ssize_t>(CAN_MTU)) {
    return -1;
  }
  const bool ext = (f.can_id & CAN_EFF_FLAG) != 0;
  const std::uint32_t id = f.can_id & (ext ? CAN_EFF_MASK : CAN_SFF_MASK);
  if (!ext && id == kCanSyncAckId) {
    if (f.len != 8) {
      return -1;
    }
    std::uint64_t c = 0;
    for (std::size_t i = 0; i < 8; ++i) {
      c |= static_cast<std::uint64_t>(f.data[i]) << (8U * i);
    }
    return static_cast<long long>(c);
  }
  for (const auto& r : config_.mapping.offsets) {
    if (r.id != id || r.extended != ext) {
      continue;
    }
    if (f.len != r.length_bytes) {
      ++refused_;  // a malformed write: not taken, not acknowledged
      return -1;
    }
    const double v = dc::raw_to_physical(
        r.value, dc::extract_raw(r.value, std::span<const std::uint8_t>(f.data, f.len)));
    if (!std::isfinite(v) || std::fabs(v) > limit_um_) {
      ++refused_;
      return -1;
    }
    writes_.push_back({r.register_index, v});
    if (r.ack) {
      can_nc::Frame a{};
      a.id = r.ack->id;
      a.extended = r.ack->extended;
      a.length_bytes = f.len;
      std::memcpy(a.data.data(), f.data, f.len);
      send_frame(sock_, a, config_.mapping.fd);
    }
    return -1;
  }
  return -1;
}

bool CanLink::after_done(std::uint64_t cycle, double timeout_s) {
  const int ms = static_cast<int>(timeout_s * 1000.0);
  for (;;) {
    const long long r = read_one(ms);
    if (r == -2) {
      return false;
    }
    if (r == static_cast<long long>(cycle)) {
      return true;
    }
  }
}

std::vector<ReceivedOffset> CanLink::take_writes() {
  while (read_one(0) != -2) {
  }
  std::vector<ReceivedOffset> out;
  out.swap(writes_);
  return out;
}

}  // namespace nccomp::sim::ncsim
