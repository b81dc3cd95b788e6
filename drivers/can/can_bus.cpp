#include "drivers/can/can_bus.hpp"

#include <linux/can.h>
#include <linux/can/error.h>
#include <linux/can/netlink.h>
#include <linux/can/raw.h>
#include <linux/capability.h>
#include <linux/if_link.h>
#include <linux/netlink.h>
#include <linux/rtnetlink.h>
#include <net/if.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <stdexcept>
#include <string>
#include <string_view>
#include <variant>

namespace nccomp::drivers::can {
namespace {

constexpr std::int64_t kIdlePollNs = 1'000'000;  // bounds tx latency when nobody calls wake()
constexpr int kMaxRxBatch = 512;                 // frames per wake-up before tx gets a turn

std::int64_t mono_ns() noexcept {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

std::int64_t to_ns(double s) noexcept { return static_cast<std::int64_t>(s * 1e9); }

std::string errno_text(int e) { return std::string(std::strerror(e)); }

}  // namespace

CanBus::CanBus(CanConfig config)
    : config_(std::move(config)),
      decoder_(config_.mapping),
      rx_ring_(config_.rx_ring_events),
      tx_ring_(config_.tx_ring_writes),
      input_watch_(to_ns(config_.degraded_alarm_after_s),
                   std::any_of(config_.mapping.rx.begin(), config_.mapping.rx.end(),
                               [](const RxFrame& f) { return f.event == EventKind::kAxisSample; })),
      receipts_(config_.mapping.offsets.size()),
      rebind_backoff_(to_ns(config_.link_check_s),
                      to_ns(std::max(config_.link_check_s, config_.reconnect_max_s)),
                      to_ns(config_.reconnect_reset_after_s)),
      restart_backoff_(to_ns(config_.restart_delay_s),
                       to_ns(std::max(config_.restart_delay_s, config_.reconnect_max_s)),
                       to_ns(config_.reconnect_reset_after_s)) {
  for (const auto& r : config_.mapping.offsets) {
    Slot s;
    s.reg = &r;
    slots_.push_back(s);
  }
  std::sort(slots_.begin(), slots_.end(), [](const Slot& a, const Slot& b) {
    return a.reg->register_index < b.reg->register_index;
  });
  for (const Slot& s : slots_) {
    slot_registers_.push_back(s.reg->register_index);
  }
  for (std::size_t i = 0; i < slots_.size(); ++i) {
    if (slots_[i].reg->ack) {
      ack_index_.emplace_back(id_key(slots_[i].reg->ack->id, slots_[i].reg->ack->extended), i);
    }
  }
  std::sort(ack_index_.begin(), ack_index_.end());
}

CanBus::~CanBus() { stop(); }

void CanBus::open_socket() {
  const std::string& ifname = config_.interface;
  const int s = ::socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC | SOCK_NONBLOCK, CAN_RAW);
  if (s < 0) {
    throw std::runtime_error("can: socket(PF_CAN, CAN_RAW) failed: " + errno_text(errno) +
                             " (kernel without CAN? modprobe can-raw)");
  }
  const auto fail = [&](const std::string& what) {
    const int e = errno;
    ::close(s);
    throw std::runtime_error("can: " + ifname + ": " + what + ": " + errno_text(e));
  };
  ifreq ifr{};
  std::strncpy(ifr.ifr_name, ifname.c_str(), IFNAMSIZ - 1);
  if (::ioctl(s, SIOCGIFINDEX, &ifr) < 0) {
    fail("no such interface");
  }
  const int index = ifr.ifr_ifindex;
  if (config_.mapping.fd) {
    // FD frames only make sense where the interface carries them: its MTU says so.
    if (::ioctl(s, SIOCGIFMTU, &ifr) < 0) {
      fail("SIOCGIFMTU");
    }
    if (ifr.ifr_mtu != static_cast<int>(CANFD_MTU)) {
      ::close(s);
      throw std::runtime_error("can: " + ifname + ": can.fd = true but the interface MTU is " +
                               std::to_string(ifr.ifr_mtu) +
                               " (not CAN FD: " + std::to_string(CANFD_MTU) + ")");
    }
    const int on = 1;
    if (::setsockopt(s, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof on) < 0) {
      fail("CAN_RAW_FD_FRAMES");
    }
  }
  // Kernel filters: only mapped IDs and acknowledges reach user space.
  std::vector<can_filter> filters;
  const auto add = [&](std::uint32_t id, bool ext) {
    can_filter f{};
    f.can_id = ext ? (id | CAN_EFF_FLAG) : id;
    f.can_mask = (ext ? CAN_EFF_MASK : CAN_SFF_MASK) | CAN_EFF_FLAG | CAN_RTR_FLAG;
    filters.push_back(f);
  };
  for (const auto& f : config_.mapping.rx) {
    add(f.id, f.extended);
  }
  for (const auto& r : config_.mapping.offsets) {
    if (r.ack) {
      add(r.ack->id, r.ack->extended);
    }
  }
  if (lockstep_) {
    add(kLockstepSyncId, false);
  }
  if (::setsockopt(s, SOL_CAN_RAW, CAN_RAW_FILTER, filters.empty() ? nullptr : filters.data(),
                   static_cast<socklen_t>(filters.size() * sizeof(can_filter))) < 0) {
    fail("CAN_RAW_FILTER");
  }
  const can_err_mask_t err_mask = CAN_ERR_MASK;
  if (::setsockopt(s, SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &err_mask, sizeof err_mask) < 0) {
    fail("CAN_RAW_ERR_FILTER");
  }
  const int on = 1;
  if (::setsockopt(s, SOL_SOCKET, SO_RXQ_OVFL, &on, sizeof on) < 0) {
    fail("SO_RXQ_OVFL");
  }
  if (config_.socket_rcvbuf_bytes > 0) {
    const int bytes = static_cast<int>(config_.socket_rcvbuf_bytes);
    // SO_RCVBUFFORCE needs CAP_NET_ADMIN; fall back to the capped SO_RCVBUF.
    if (::setsockopt(s, SOL_SOCKET, SO_RCVBUFFORCE, &bytes, sizeof bytes) < 0) {
      (void)::setsockopt(s, SOL_SOCKET, SO_RCVBUF, &bytes, sizeof bytes);
    }
  }
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = index;
  if (::bind(s, reinterpret_cast<sockaddr*>(&addr), sizeof addr) < 0) {
    fail("bind");
  }
  sock_ = s;
  ifindex_ = index;
  fd_frames_ = config_.mapping.fd;
  ovfl_base_ += ovfl_last_;
  ovfl_last_ = 0;
}

void CanBus::close_socket() noexcept {
  if (sock_ >= 0) {
    ::close(sock_);
    sock_ = -1;
  }
}

void CanBus::start() {
  if (running_.load()) {
    return;
  }
  if (lockstep_) {
    // The lock-step frames share the bus with the NC's own: an overlap would be misread.
    const auto clash = [](std::uint32_t id, bool ext) {
      return !ext && (id == kLockstepSyncId || id == kLockstepSyncAckId);
    };
    for (const auto& f : config_.mapping.rx) {
      if (clash(f.id, f.extended)) {
        throw std::runtime_error("can: " + f.origin.key_path +
                                 ": ID 0x7F0/0x7F1 is reserved for lock-step SYNC / SYNC-ACK");
      }
    }
    for (const auto& r : config_.mapping.offsets) {
      if (clash(r.id, r.extended) || (r.ack && clash(r.ack->id, r.ack->extended))) {
        throw std::runtime_error("can: " + r.origin.key_path +
                                 ": ID 0x7F0/0x7F1 is reserved for lock-step SYNC / SYNC-ACK");
      }
    }
  }
  if (config_.restart == RestartMode::kDaemon) {
    // Refused here rather than found out at the first bus-off, which would then never end.
    const std::string missing = restart_permission_problem();
    if (!missing.empty()) {
      throw std::runtime_error(
          "can: " + config_.interface +
          ": can.restart = \"daemon\" needs CAP_NET_ADMIN and an AF_NETLINK socket to request "
          "bus-off restarts, and this process has " +
          missing +
          ". Under systemd install the drop-in nccompd-can-restart.conf as "
          "/etc/systemd/system/nccompd.service.d/can-restart.conf (docs/can.md), or use "
          "restart = \"kernel\" with the interface's restart-ms");
    }
  }
  open_socket();
  event_fd_ = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
  if (event_fd_ < 0) {
    close_socket();
    throw std::runtime_error("can: eventfd: " + errno_text(errno));
  }
  st_.bus.state = LinkState::kUp;
  input_watch_.start(mono_ns());
  publish(mono_ns());
  running_.store(true);
  thread_ = std::thread([this] { run(); });
}

void CanBus::stop() {
  if (!running_.exchange(false)) {
    return;
  }
  wake();
  if (thread_.joinable()) {
    thread_.join();
  }
  close_socket();
  if (event_fd_ >= 0) {
    ::close(event_fd_);
    event_fd_ = -1;
  }
  st_.bus.state = LinkState::kStopped;
  publish(mono_ns());
}

void CanBus::wake() noexcept {
  if (event_fd_ >= 0) {
    const std::uint64_t one = 1;
    (void)!::write(event_fd_, &one, sizeof one);
  }
}

void CanBus::publish(std::int64_t now_ns) noexcept {
  auto& b = st_.bus;
  auto& c = st_.can;
  b.counters.malformed = c.rejected_unknown_id + c.rejected_wrong_length + c.rejected_out_of_range +
                         c.rejected_not_finite;
  b.counters.faults = c.error_passive + c.bus_off + c.interface_down + c.controller_overflow;
  c.rx_overflow = ovfl_base_ + ovfl_last_;
  // Down or bus-off beyond the tolerance: the NC gets no offsets, the operator must know.
  const bool down_long =
      down_since_ns_ != 0 && now_ns - down_since_ns_ > to_ns(config_.alarm_after_s);
  if (down_long && !link_alarm_) {
    ++c.link_alarms;
  }
  link_alarm_ = down_long;
  b.alarm = link_alarm_ || std::any_of(slots_.begin(), slots_.end(), [](const Slot& s) {
              return s.state == WriteState::kFailed || s.given_up;
            });
  if (b.state != LinkState::kStopped) {
    if (if_down_ || bus_off_) {
      b.state = LinkState::kDown;
    }
  }
  if (b.state == LinkState::kUp) {
    input_watch_.link_ok(now_ns);
  }
  if (!lockstep_) {
    b.input_stale = b.state != LinkState::kStopped && input_watch_.stale(now_ns);
  }
  status_.store(st_);
}

static_assert(std::string_view(kCanCounterNames.back()) == "reconnect_backoff_ms");

std::size_t CanBus::extra_counters(std::span<BusCounterValue> out) const {
  const CanCounters c = status_.load().can;
  const std::array<std::uint64_t, kCanCounterNames.size()> values{
      c.error_frames,          c.error_warning,
      c.error_passive,         c.bus_off,
      c.bus_recoveries,        c.restart_requests,
      c.restart_failures,      c.interface_down,
      c.link_alarms,           c.controller_overflow,
      c.rx_overflow,           c.enobufs,
      c.enobufs_retries,       c.ack_timeouts,
      c.ack_retries,           c.resent_after_recovery,
      c.rejected_wrong_length, c.rejected_out_of_range,
      c.rejected_not_finite,   c.rejected_unknown_id,
      c.tx_unencodable,        c.tx_unmapped,
      c.lockstep_syncs,        c.lockstep_sync_acks,
      c.reconnect_backoffs,    c.reconnect_backoff_ms};
  const std::size_t n = std::min(out.size(), values.size());
  for (std::size_t i = 0; i < n; ++i) {
    // The last one, reconnect_backoff_ms, is the back-off now: a gauge.
    out[i] = BusCounterValue{kCanCounterNames[i], values[i], i + 1 == values.size()};
  }
  return n;
}

core::WriteReceipt CanBus::write_receipt(std::uint16_t register_index) const noexcept {
  const auto it = std::lower_bound(slot_registers_.begin(), slot_registers_.end(), register_index);
  if (it == slot_registers_.end() || *it != register_index) {
    return kUnmappedReceipt;
  }
  return receipts_.load(static_cast<std::size_t>(it - slot_registers_.begin()));
}

CanBus::Slot* CanBus::slot_for(std::uint16_t register_index) noexcept {
  const auto it =
      std::lower_bound(slots_.begin(), slots_.end(), register_index,
                       [](const Slot& s, std::uint16_t r) { return s.reg->register_index < r; });
  return (it != slots_.end() && it->reg->register_index == register_index) ? &*it : nullptr;
}

void CanBus::run() noexcept {
  std::int64_t now = mono_ns();
  while (running_.load(std::memory_order_acquire)) {
    // Sleep until the next thing to do: a frame, a wake(), an ack deadline, a link check.
    std::int64_t wait_ns = kIdlePollNs;
    for (const auto& s : slots_) {
      if (s.state == WriteState::kAwaitAck) {
        wait_ns = std::min(wait_ns, s.deadline_ns - now);
      }
    }
    if (backoff_until_ns_ > now) {
      wait_ns = std::min(wait_ns, backoff_until_ns_ - now);
    }
    if (if_down_) {
      wait_ns = std::min(wait_ns, next_link_check_ns_ - now);
    }
    if (bus_off_ && config_.restart == RestartMode::kDaemon) {
      wait_ns = std::min(wait_ns, next_restart_ns_ - now);
    }
    wait_ns = std::max<std::int64_t>(wait_ns, 0);
    pollfd fds[2]{};
    fds[0].fd = event_fd_;
    fds[0].events = POLLIN;
    fds[1].fd = sock_;
    fds[1].events = POLLIN;
    const timespec ts{static_cast<time_t>(wait_ns / 1'000'000'000),
                      static_cast<long>(wait_ns % 1'000'000'000)};
    const int n = ::ppoll(fds, sock_ >= 0 ? 2 : 1, &ts, nullptr);
    now = mono_ns();
    if (n > 0 && (fds[0].revents & POLLIN) != 0) {
      std::uint64_t v = 0;
      (void)!::read(event_fd_, &v, sizeof v);
    }
    if (n > 0 && sock_ >= 0 && (fds[1].revents & (POLLIN | POLLERR)) != 0) {
      receive_all(now);
    }
    if (if_down_ && now >= next_link_check_ns_) {
      check_link(now);
    }
    if (bus_off_ && config_.restart == RestartMode::kDaemon && now >= next_restart_ns_) {
      ++st_.can.restart_requests;
      if (request_can_restart(ifindex_) != 0) {
        ++st_.can.restart_failures;
        next_restart_ns_ = restart_backoff_.lost(now);
      } else {
        // Granted: the restarted frame ends bus-off; without it, ask again after as long.
        next_restart_ns_ = now + restart_backoff_.delay_ns();
      }
    }
    take_writes();
    check_acks(now);
    send_pending(now);
    serve_flush();
    rebind_backoff_.healthy(now, !if_down_);
    restart_backoff_.healthy(now, !if_down_ && !bus_off_);
    st_.can.reconnect_backoffs = rebind_backoff_.waits() + restart_backoff_.waits();
    st_.can.reconnect_backoff_ms = static_cast<std::uint64_t>(
        std::max(rebind_backoff_.raised_delay_ns(), restart_backoff_.raised_delay_ns()) /
        1'000'000);
    publish(now);
  }
}

bool CanBus::sync(std::uint64_t cycle, core::TimeNs timeout_ns) {
  std::unique_lock<std::mutex> lock(ls_mu_);
  return ls_cv_.wait_for(lock, std::chrono::nanoseconds(timeout_ns),
                         [&] { return synced_plus1_ > cycle; });
}

bool CanBus::flush(std::uint64_t cycle, core::TimeNs timeout_ns) {
  std::uint64_t want = 0;
  {
    std::lock_guard<std::mutex> lock(ls_mu_);
    want = ++flush_req_;
    flush_cycle_ = cycle;
  }
  wake();
  std::unique_lock<std::mutex> lock(ls_mu_);
  return ls_cv_.wait_for(lock, std::chrono::nanoseconds(timeout_ns),
                         [&] { return flush_done_ >= want; });
}

void CanBus::handle_sync(const std::uint8_t* data, std::size_t len) noexcept {
  if (len != 8) {
    ++st_.can.rejected_wrong_length;
    return;
  }
  std::uint64_t cycle = 0;
  for (int i = 7; i >= 0; --i) {
    cycle = (cycle << 8) | data[i];
  }
  ++st_.can.lockstep_syncs;
  // The peer is the clock: judged at its SYNCs only, so that a paused peer is not stale input.
  st_.bus.input_stale = input_watch_.stale(mono_ns());
  {
    std::lock_guard<std::mutex> lock(ls_mu_);
    synced_plus1_ = std::max(synced_plus1_, cycle + 1);
  }
  ls_cv_.notify_all();
}

void CanBus::serve_flush() noexcept {
  if (!lockstep_) {
    return;
  }
  if (serving_flush_ == 0) {
    std::lock_guard<std::mutex> lock(ls_mu_);
    if (flush_req_ > flush_done_) {
      serving_flush_ = flush_req_;
      serving_cycle_ = flush_cycle_;
    }
  }
  if (serving_flush_ == 0) {
    return;
  }
  // Read after the request was taken: every write the loop queued before flush() is in the ring.
  const std::int64_t now = mono_ns();
  take_writes();
  send_pending(now);
  for (const auto& slot : slots_) {
    if (slot.state == WriteState::kPending) {
      return;  // not on the wire yet (queue full, link down): the next round tries again
    }
  }
  if (sock_ < 0 || if_down_ || bus_off_ || now < backoff_until_ns_) {
    return;
  }
  can_frame f{};
  f.can_id = kLockstepSyncAckId;
  f.len = 8;
  for (int i = 0; i < 8; ++i) {
    f.data[i] = static_cast<std::uint8_t>(serving_cycle_ >> (8 * i));
  }
  if (::send(sock_, &f, sizeof f, MSG_DONTWAIT) != static_cast<ssize_t>(sizeof f)) {
    if (errno == ENOBUFS || errno == EAGAIN) {
      queue_full(now);
    }
    return;
  }
  ++st_.bus.counters.frames_tx;
  ++st_.can.lockstep_sync_acks;
  {
    std::lock_guard<std::mutex> lock(ls_mu_);
    flush_done_ = serving_flush_;
  }
  serving_flush_ = 0;
  ls_cv_.notify_all();
}

void CanBus::receive_all(std::int64_t now_ns) noexcept {
  for (int i = 0; i < kMaxRxBatch && sock_ >= 0; ++i) {
    canfd_frame frame{};
    iovec iov{&frame, sizeof frame};
    alignas(cmsghdr) char ctrl[CMSG_SPACE(sizeof(std::uint32_t))];
    msghdr msg{};
    msg.msg_iov = &iov;
    msg.msg_iovlen = 1;
    msg.msg_control = ctrl;
    msg.msg_controllen = sizeof ctrl;
    const ssize_t got = ::recvmsg(sock_, &msg, MSG_DONTWAIT);
    if (got < 0) {
      if (errno == EAGAIN || errno == EINTR) {
        return;
      }
      // The socket reports the interface going down (ENETDOWN) or away (ENODEV) as an error.
      link_down(now_ns);
      return;
    }
    for (cmsghdr* c = CMSG_FIRSTHDR(&msg); c != nullptr; c = CMSG_NXTHDR(&msg, c)) {
      if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SO_RXQ_OVFL) {
        std::memcpy(&ovfl_last_, CMSG_DATA(c), sizeof ovfl_last_);
      }
    }
    if (got != static_cast<ssize_t>(CAN_MTU) && got != static_cast<ssize_t>(CANFD_MTU)) {
      continue;  // not a CAN frame; cannot happen on CAN_RAW
    }
    ++st_.bus.counters.frames_rx;
    st_.bus.last_rx_ns = now_ns;
    const std::uint32_t can_id = frame.can_id;
    if ((can_id & CAN_ERR_FLAG) != 0) {
      handle_error_frame(can_id, frame.data, now_ns);
      continue;
    }
    if (bus_off_) {
      // Traffic again: the controller was restarted (restart-ms or our request).
      bus_off_ = false;
      ++st_.can.bus_recoveries;
      recovered();
    }
    const bool ext = (can_id & CAN_EFF_FLAG) != 0;
    const std::uint32_t id = can_id & (ext ? CAN_EFF_MASK : CAN_SFF_MASK);
    const std::size_t len = std::min<std::size_t>(frame.len, kMaxPayloadBytes);
    const std::uint32_t key = id_key(id, ext);
    if (lockstep_ && !ext && id == kLockstepSyncId) {
      handle_sync(frame.data, len);
      continue;
    }
    if (!ack_index_.empty()) {
      const auto it = std::lower_bound(ack_index_.begin(), ack_index_.end(),
                                       std::make_pair(key, std::size_t{0}));
      if (it != ack_index_.end() && it->first == key) {
        handle_ack(key, frame.data, len);
        continue;
      }
    }
    core::Event ev;
    const auto r =
        decoder_.decode(id, ext, std::span<const std::uint8_t>(frame.data, len), now_ns, ev);
    switch (r.reject) {
      case RejectReason::kNone:
        break;
      case RejectReason::kUnknownId:
        ++st_.can.rejected_unknown_id;
        break;
      case RejectReason::kWrongLength:
        ++st_.can.rejected_wrong_length;
        break;
      case RejectReason::kOutOfRange:
        ++st_.can.rejected_out_of_range;
        break;
      case RejectReason::kNotFinite:
        ++st_.can.rejected_not_finite;
        break;
    }
    if (r.emitted) {
      if (std::holds_alternative<core::AxisSample>(ev)) {
        input_watch_.axis_ok(now_ns);
      }
      if (rx_ring_.try_push(ev)) {
        ++st_.bus.counters.events_decoded;
      } else {
        ++st_.bus.counters.events_dropped;
      }
    }
  }
}

void CanBus::handle_error_frame(std::uint32_t can_id, const std::uint8_t* data,
                                std::int64_t now_ns) noexcept {
  ++st_.can.error_frames;
  if ((can_id & CAN_ERR_CRTL) != 0) {
    const std::uint8_t c = data[1];
    if ((c & (CAN_ERR_CRTL_RX_OVERFLOW | CAN_ERR_CRTL_TX_OVERFLOW)) != 0) {
      ++st_.can.controller_overflow;
    }
    if ((c & (CAN_ERR_CRTL_RX_WARNING | CAN_ERR_CRTL_TX_WARNING)) != 0) {
      ++st_.can.error_warning;
    }
    if ((c & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE)) != 0) {
      ++st_.can.error_passive;
      if (st_.bus.state == LinkState::kUp) {
        st_.bus.state = LinkState::kDegraded;
      }
    }
    if ((c & CAN_ERR_CRTL_ACTIVE) != 0 && st_.bus.state == LinkState::kDegraded) {
      st_.bus.state = LinkState::kUp;
    }
  }
  if ((can_id & CAN_ERR_BUSOFF) != 0 && !bus_off_) {
    bus_off_ = true;
    ++st_.can.bus_off;
    st_.bus.state = LinkState::kDown;
    went_down(now_ns);
    if (config_.restart == RestartMode::kDaemon) {
      next_restart_ns_ = restart_backoff_.lost(now_ns);
    }
  }
  if ((can_id & CAN_ERR_RESTARTED) != 0 && bus_off_) {
    bus_off_ = false;
    ++st_.can.bus_recoveries;
    recovered();
  }
}

void CanBus::handle_ack(std::uint32_t key, const std::uint8_t* data, std::size_t len) noexcept {
  for (auto it = std::lower_bound(ack_index_.begin(), ack_index_.end(),
                                  std::make_pair(key, std::size_t{0}));
       it != ack_index_.end() && it->first == key; ++it) {
    Slot& s = slots_[it->second];
    // The NC echoes the written payload: an ack of an older value does not confirm a newer one.
    if (s.state == WriteState::kAwaitAck && len == s.reg->length_bytes &&
        std::memcmp(data, s.payload.data(), len) == 0) {
      s.state = WriteState::kIdle;
      s.given_up = false;
      ++st_.bus.counters.offsets_written;
      receipts_.publish(it->second, s.sequence, core::WriteOutcome::kReached);
    }
  }
}

void CanBus::take_writes() noexcept {
  core::OffsetWrite w;
  while (tx_ring_.try_pop(w)) {
    Slot* s = slot_for(w.register_index);
    if (s == nullptr) {
      ++st_.can.tx_unmapped;
      ++st_.bus.counters.offsets_failed;
      continue;
    }
    // Absolute values: a newer write replaces whatever was pending for the register, a
    // recovery re-send included (the new value is a first send, not a re-send).
    s->resend = false;
    s->sequence = w.sequence;
    if (!encode_offset(*s->reg, w.value_um, s->payload)) {
      // The payload is cleared: nothing to re-send after a recovery until a value fits again
      // (the NC keeps its last value, the alarm says why).
      ++st_.can.tx_unencodable;
      ++st_.bus.counters.offsets_failed;
      s->state = WriteState::kFailed;
      s->has_value = false;
      receipts_.publish(static_cast<std::size_t>(s - slots_.data()), w.sequence,
                        core::WriteOutcome::kRefused);
      continue;
    }
    s->value_um = w.value_um;
    s->has_value = true;
    s->state = WriteState::kPending;
    s->attempts = 0;
  }
}

void CanBus::send_pending(std::int64_t now_ns) noexcept {
  if (sock_ < 0 || if_down_ || bus_off_ || now_ns < backoff_until_ns_) {
    return;
  }
  bool after_backoff = backoff_ns_ != 0;  // the last round ended in ENOBUFS
  for (auto& s : slots_) {
    if (s.state != WriteState::kPending) {
      continue;
    }
    if (after_backoff) {
      ++st_.can.enobufs_retries;
      after_backoff = false;
    }
    canfd_frame f{};
    f.can_id = s.reg->extended ? (s.reg->id | CAN_EFF_FLAG) : s.reg->id;
    f.len = s.reg->length_bytes;
    std::memcpy(f.data, s.payload.data(), s.reg->length_bytes);
    const bool fd = s.reg->length_bytes > CAN_MAX_DLEN;
    const std::size_t size = fd ? CANFD_MTU : CAN_MTU;
    const ssize_t put = ::send(sock_, &f, size, MSG_DONTWAIT);
    if (put < 0) {
      const int e = errno;
      if (e == ENOBUFS || e == EAGAIN) {
        queue_full(now_ns);  // the write stays pending
        return;
      }
      if (e == ENETDOWN || e == ENODEV || e == ENXIO) {
        link_down(now_ns);
        return;
      }
      ++st_.bus.counters.offsets_failed;
      s.state = WriteState::kFailed;
      receipts_.publish(static_cast<std::size_t>(&s - slots_.data()), s.sequence,
                        core::WriteOutcome::kRefused);
      continue;
    }
    ++st_.bus.counters.frames_tx;
    ++s.attempts;
    if (s.resend) {
      // Counted once it is on the wire: once per register and recovery.
      s.resend = false;
      ++st_.can.resent_after_recovery;
      ++st_.bus.counters.offsets_retried;
    }
    if (s.reg->ack) {
      s.state = WriteState::kAwaitAck;
      s.deadline_ns = now_ns + to_ns(config_.ack_timeout_s);
    } else {
      s.state = WriteState::kIdle;
      ++st_.bus.counters.offsets_written;
      receipts_.publish(static_cast<std::size_t>(&s - slots_.data()), s.sequence,
                        core::WriteOutcome::kReached);
    }
  }
  // Everything pending went out: only now is the queue known to have room again (one frame that
  // fitted is not enough).
  backoff_ns_ = 0;
}

void CanBus::queue_full(std::int64_t now_ns) noexcept {
  // Transmit queue full: back off exponentially, from enobufs_backoff_s up to 64 times that.
  ++st_.can.enobufs;
  const std::int64_t base = to_ns(config_.enobufs_backoff_s);
  backoff_ns_ = backoff_ns_ == 0 ? base : std::min(backoff_ns_ * 2, 64 * base);
  backoff_until_ns_ = now_ns + backoff_ns_;
}

void CanBus::check_acks(std::int64_t now_ns) noexcept {
  for (auto& s : slots_) {
    if (s.state != WriteState::kAwaitAck || now_ns < s.deadline_ns) {
      continue;
    }
    ++st_.can.ack_timeouts;
    if (s.attempts <= config_.ack_retries) {
      ++st_.bus.counters.offsets_retried;
      ++st_.can.ack_retries;
      s.state = WriteState::kPending;
    } else {
      ++st_.bus.counters.offsets_failed;
      s.state = WriteState::kFailed;
      s.given_up = true;
      receipts_.publish(static_cast<std::size_t>(&s - slots_.data()), s.sequence,
                        core::WriteOutcome::kUnknown);
    }
  }
}

void CanBus::link_down(std::int64_t now_ns) noexcept {
  if (!if_down_) {
    if_down_ = true;
    ++st_.can.interface_down;
    st_.bus.state = LinkState::kDown;
    went_down(now_ns);
    next_rebind_ns_ = rebind_backoff_.lost(now_ns);
  }
  next_link_check_ns_ = now_ns + to_ns(config_.link_check_s);
  // Consume the pending socket error so poll() does not spin on POLLERR.
  int err = 0;
  socklen_t len = sizeof err;
  if (sock_ >= 0) {
    (void)::getsockopt(sock_, SOL_SOCKET, SO_ERROR, &err, &len);
  }
  if (err == ENODEV) {
    close_socket();  // the interface is gone; a new one needs a new bind
  }
}

void CanBus::check_link(std::int64_t now_ns) noexcept {
  if (now_ns < next_rebind_ns_) {
    next_link_check_ns_ = next_rebind_ns_;  // back-off: no rebind before then
    return;
  }
  next_link_check_ns_ = now_ns + to_ns(config_.link_check_s);
  const int probe = sock_ >= 0 ? sock_ : ::socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
  if (probe < 0) {
    return;
  }
  ifreq ifr{};
  std::strncpy(ifr.ifr_name, config_.interface.c_str(), IFNAMSIZ - 1);
  const bool up = ::ioctl(probe, SIOCGIFFLAGS, &ifr) == 0 && (ifr.ifr_flags & IFF_UP) != 0 &&
                  (ifr.ifr_flags & IFF_RUNNING) != 0;
  if (probe != sock_) {
    ::close(probe);
  }
  if (!up) {
    return;
  }
  // Rebind on a fresh socket: if the interface was deleted and re-created (a USB adapter
  // plugged back in), the old socket is bound to an index that no longer exists.
  close_socket();
  try {
    open_socket();
  } catch (...) {
    next_rebind_ns_ = rebind_backoff_.lost(now_ns);
    return;
  }
  if_down_ = false;
  recovered();
}

void CanBus::went_down(std::int64_t now_ns) noexcept {
  if (down_since_ns_ == 0) {
    down_since_ns_ = std::max<std::int64_t>(now_ns, 1);
  }
}

void CanBus::recovered() noexcept {
  if (if_down_ || bus_off_) {
    return;
  }
  down_since_ns_ = 0;  // the next publish() clears the link alarm
  ++st_.bus.counters.reconnects;
  st_.bus.state = LinkState::kUp;
  // Every register that holds a value is sent again, whether or not its frame is acknowledged:
  // a frame sent just before the fault may never have reached the NC, and one without an ack
  // would otherwise be lost unnoticed. Absolute values, so a repeat is harmless (the Modbus
  // driver re-writes every offset after a reconnect the same way). A re-send gets a fresh
  // retry budget. Writes still pending were never sent: they go out as first sends.
  for (auto& s : slots_) {
    if (s.has_value && s.state != WriteState::kPending) {
      s.state = WriteState::kPending;
      s.attempts = 0;
      s.resend = true;
    }
  }
  backoff_until_ns_ = 0;
  backoff_ns_ = 0;
}

std::string restart_permission_problem() {
  std::string missing;
  __user_cap_header_struct header{};
  header.version = _LINUX_CAPABILITY_VERSION_3;
  std::array<__user_cap_data_struct, _LINUX_CAPABILITY_U32S_3> caps{};
  if (::syscall(SYS_capget, &header, caps.data()) != 0 ||
      (caps[CAP_TO_INDEX(CAP_NET_ADMIN)].effective & CAP_TO_MASK(CAP_NET_ADMIN)) == 0) {
    missing = "no CAP_NET_ADMIN in its effective capabilities";
  }
  // RestrictAddressFamilies= (seccomp) makes socket() fail with EAFNOSUPPORT.
  const int nl = ::socket(AF_NETLINK, SOCK_RAW | SOCK_CLOEXEC, NETLINK_ROUTE);
  if (nl < 0) {
    const int e = errno;
    missing += missing.empty() ? "" : "; ";
    missing += "AF_NETLINK sockets refused: ";
    missing += errno_text(e);
  } else {
    ::close(nl);
  }
  return missing;
}

int request_can_restart(int ifindex) noexcept {
  const int nl = ::socket(AF_NETLINK, SOCK_RAW | SOCK_CLOEXEC, NETLINK_ROUTE);
  if (nl < 0) {
    return errno;
  }
  struct {
    nlmsghdr nh;
    ifinfomsg ifi;
    char attrs[128];
  } req{};
  req.nh.nlmsg_len = NLMSG_LENGTH(sizeof(ifinfomsg));
  req.nh.nlmsg_type = RTM_NEWLINK;
  req.nh.nlmsg_flags = NLM_F_REQUEST | NLM_F_ACK;
  req.nh.nlmsg_seq = 1;
  req.ifi.ifi_family = AF_UNSPEC;
  req.ifi.ifi_index = ifindex;
  const auto put = [&req](std::uint16_t type, const void* data, std::size_t len) {
    auto* rta =
        reinterpret_cast<rtattr*>(reinterpret_cast<char*>(&req) + NLMSG_ALIGN(req.nh.nlmsg_len));
    rta->rta_type = type;
    rta->rta_len = static_cast<std::uint16_t>(RTA_LENGTH(len));
    if (len > 0) {
      std::memcpy(reinterpret_cast<char*>(rta) + RTA_LENGTH(0), data, len);
    }
    req.nh.nlmsg_len = NLMSG_ALIGN(req.nh.nlmsg_len) + RTA_ALIGN(rta->rta_len);
    return rta;
  };
  rtattr* linkinfo = put(IFLA_LINKINFO, nullptr, 0);
  put(IFLA_INFO_KIND, "can", 3);
  rtattr* data = put(IFLA_INFO_DATA, nullptr, 0);
  const std::uint32_t one = 1;
  put(IFLA_CAN_RESTART, &one, sizeof one);
  const auto end = reinterpret_cast<char*>(&req) + req.nh.nlmsg_len;
  data->rta_len = static_cast<std::uint16_t>(end - reinterpret_cast<char*>(data));
  linkinfo->rta_len = static_cast<std::uint16_t>(end - reinterpret_cast<char*>(linkinfo));
  sockaddr_nl sa{};
  sa.nl_family = AF_NETLINK;
  int rc = 0;
  if (::sendto(nl, &req, req.nh.nlmsg_len, 0, reinterpret_cast<sockaddr*>(&sa), sizeof sa) < 0) {
    rc = errno;
  } else {
    alignas(nlmsghdr) char buf[512];
    timeval tv{0, 200'000};
    (void)::setsockopt(nl, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    const ssize_t got = ::recv(nl, buf, sizeof buf, 0);
    if (got < 0) {
      rc = errno;
    } else if (static_cast<std::size_t>(got) >= NLMSG_LENGTH(sizeof(nlmsgerr))) {
      const auto* h = reinterpret_cast<const nlmsghdr*>(buf);
      if (h->nlmsg_type == NLMSG_ERROR) {
        const auto* e = reinterpret_cast<const nlmsgerr*>(buf + NLMSG_HDRLEN);
        rc = -e->error;
      }
    }
  }
  ::close(nl);
  return rc;
}

}  // namespace nccomp::drivers::can
