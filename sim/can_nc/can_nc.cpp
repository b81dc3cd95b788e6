#include "sim/can_nc/can_nc.hpp"

#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <stdexcept>

namespace nccomp::sim::can_nc {

namespace dc = drivers::can;

std::vector<Frame> encode_event(const dc::CanMapping& mapping, const core::Event& event) {
  const auto kind = static_cast<dc::EventKind>(event.index());
  std::vector<Frame> frames;
  std::optional<Frame> last;
  for (const auto& rx : mapping.rx) {
    if (rx.event != kind) {
      continue;
    }
    Frame f;
    f.id = rx.id;
    f.extended = rx.extended;
    f.length_bytes = rx.length_bytes;
    for (const auto& s : rx.signals) {
      const auto v = dc::field_value(event, s.field);
      const auto raw = v ? dc::physical_to_raw(s.layout, *v) : std::nullopt;
      if (!raw) {
        throw std::invalid_argument("encode_event: " + s.name + " does not fit its signal");
      }
      dc::insert_raw(s.layout, *raw, std::span<std::uint8_t>(f.data.data(), f.length_bytes));
    }
    if (rx.emit) {
      last = f;
    } else {
      frames.push_back(f);
    }
  }
  if (!last) {
    throw std::invalid_argument("encode_event: no emitting frame for " +
                                std::string(dc::event_kind_name(kind)));
  }
  frames.push_back(*last);
  return frames;
}

CanNcNode::CanNcNode(const dc::CanMapping& mapping, const std::string& interface)
    : mapping_(mapping) {
  sock_ = ::socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
  if (sock_ < 0) {
    throw std::runtime_error("can_nc: socket: " + std::string(std::strerror(errno)));
  }
  ifreq ifr{};
  std::strncpy(ifr.ifr_name, interface.c_str(), IFNAMSIZ - 1);
  if (::ioctl(sock_, SIOCGIFINDEX, &ifr) < 0) {
    ::close(sock_);
    throw std::runtime_error("can_nc: no interface " + interface);
  }
  if (mapping.fd) {
    const int on = 1;
    (void)::setsockopt(sock_, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof on);
  }
  std::vector<can_filter> filters;
  for (const auto& r : mapping.offsets) {
    can_filter f{};
    f.can_id = r.extended ? (r.id | CAN_EFF_FLAG) : r.id;
    f.can_mask = (r.extended ? CAN_EFF_MASK : CAN_SFF_MASK) | CAN_EFF_FLAG | CAN_RTR_FLAG;
    filters.push_back(f);
  }
  (void)::setsockopt(sock_, SOL_CAN_RAW, CAN_RAW_FILTER, filters.empty() ? nullptr : filters.data(),
                     static_cast<socklen_t>(filters.size() * sizeof(can_filter)));
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = ifr.ifr_ifindex;
  if (::bind(sock_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) < 0) {
    ::close(sock_);
    throw std::runtime_error("can_nc: bind: " + std::string(std::strerror(errno)));
  }
}

CanNcNode::~CanNcNode() {
  if (sock_ >= 0) {
    ::close(sock_);
  }
}

void CanNcNode::send(const Frame& frame) {
  canfd_frame f{};
  f.can_id = frame.extended ? (frame.id | CAN_EFF_FLAG) : frame.id;
  f.len = frame.length_bytes;
  std::memcpy(f.data, frame.data.data(), frame.length_bytes);
  const std::size_t size = frame.length_bytes > CAN_MAX_DLEN ? CANFD_MTU : CAN_MTU;
  for (;;) {
    if (::write(sock_, &f, size) == static_cast<ssize_t>(size)) {
      return;
    }
    if (errno != ENOBUFS && errno != EINTR) {
      throw std::runtime_error("can_nc: write: " + std::string(std::strerror(errno)));
    }
    pollfd p{sock_, POLLOUT, 0};
    (void)::poll(&p, 1, 10);
  }
}

void CanNcNode::send_event(const core::Event& event) {
  for (const auto& f : encode_event(mapping_, event)) {
    send(f);
  }
}

std::optional<ReceivedWrite> CanNcNode::receive_write(int timeout_ms) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::milliseconds(timeout_ms);
  canfd_frame f{};
  for (;;) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
                          end - std::chrono::steady_clock::now())
                          .count();
    if (left <= 0) {
      return std::nullopt;
    }
    pollfd p{sock_, POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(left)) <= 0) {
      continue;
    }
    // An error (ENETDOWN while the interface was down) is consumed by the read; keep waiting.
    if (::read(sock_, &f, sizeof f) >= static_cast<ssize_t>(CAN_MTU)) {
      break;
    }
  }
  const bool ext = (f.can_id & CAN_EFF_FLAG) != 0;
  const std::uint32_t id = f.can_id & (ext ? CAN_EFF_MASK : CAN_SFF_MASK);
  for (const auto& r : mapping_.offsets) {
    if (r.id != id || r.extended != ext || f.len != r.length_bytes) {
      continue;
    }
    ReceivedWrite w;
    w.register_index = r.register_index;
    w.value_um = dc::raw_to_physical(
        r.value, dc::extract_raw(r.value, std::span<const std::uint8_t>(f.data, f.len)));
    w.frame.id = id;
    w.frame.extended = ext;
    w.frame.length_bytes = f.len;
    std::memcpy(w.frame.data.data(), f.data, f.len);
    if (acknowledge && r.ack) {
      Frame a = w.frame;
      a.id = r.ack->id;
      a.extended = r.ack->extended;
      send(a);
    }
    return w;
  }
  return std::nullopt;
}

}  // namespace nccomp::sim::can_nc
