#include "sim/modbus_nc/nc_server.hpp"

#include <arpa/inet.h>
#include <modbus/modbus.h>
#include <netinet/in.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <stdexcept>

namespace nccomp::sim::modbus_nc {
namespace {

modbus_mapping_t* mapping(void* p) { return static_cast<modbus_mapping_t*>(p); }

constexpr int kTableSize = 65536;

bool touches(std::uint16_t first, std::uint32_t count, std::uint16_t address) {
  return address >= first && address < first + count;
}

}  // namespace

NcServer::NcServer(ServerConfig config) : config_(std::move(config)) {
  mapping_ = modbus_mapping_new(kTableSize, kTableSize, kTableSize, kTableSize);
  if (mapping_ == nullptr) {
    throw std::runtime_error("modbus_nc: cannot allocate the register map");
  }
}

NcServer::~NcServer() {
  stop();
  modbus_mapping_free(mapping(mapping_));
}

void NcServer::start() {
  if (thread_.joinable()) {
    throw std::logic_error("modbus_nc: already running");
  }
  modbus_t* ctx = nullptr;
  if (config_.rtu) {
    ctx = modbus_new_rtu(config_.device.c_str(), config_.baud, config_.parity, config_.data_bits,
                         config_.stop_bits);
    if (ctx == nullptr || modbus_connect(ctx) == -1) {
      const std::string why = modbus_strerror(errno);
      if (ctx != nullptr) {
        modbus_free(ctx);
      }
      throw std::runtime_error("modbus_nc: cannot open " + config_.device + ": " + why);
    }
  } else {
    ctx = modbus_new_tcp(config_.bind_address.c_str(), config_.port);
    if (ctx == nullptr) {
      throw std::runtime_error("modbus_nc: bad bind address " + config_.bind_address);
    }
    listen_fd_ = modbus_tcp_listen(ctx, 4);
    if (listen_fd_ == -1) {
      const std::string why = modbus_strerror(errno);
      modbus_free(ctx);
      throw std::runtime_error("modbus_nc: cannot listen on " + config_.bind_address + ":" +
                               std::to_string(config_.port) + ": " + why);
    }
    sockaddr_in addr{};
    socklen_t len = sizeof(addr);
    getsockname(listen_fd_, reinterpret_cast<sockaddr*>(&addr), &len);
    config_.port = ntohs(addr.sin_port);
  }
  modbus_set_slave(ctx, config_.unit_id);
  ctx_ = ctx;
  if (pipe(stop_pipe_) != 0) {
    throw std::runtime_error("modbus_nc: pipe failed");
  }
  thread_ = std::thread([this] { run(); });
}

void NcServer::stop() {
  if (!thread_.joinable()) {
    return;
  }
  const char c = 'x';
  (void)!write(stop_pipe_[1], &c, 1);
  thread_.join();
  close(stop_pipe_[0]);
  close(stop_pipe_[1]);
  stop_pipe_[0] = stop_pipe_[1] = -1;
  if (listen_fd_ != -1) {
    close(listen_fd_);
    listen_fd_ = -1;
  }
  auto* ctx = static_cast<modbus_t*>(ctx_);
  if (config_.rtu) {
    modbus_close(ctx);
  }
  modbus_free(ctx);
  ctx_ = nullptr;
}

Tables NcServer::tables() {
  modbus_mapping_t* m = mapping(mapping_);
  return Tables{{m->tab_bits, kTableSize},
                {m->tab_input_bits, kTableSize},
                {m->tab_registers, kTableSize},
                {m->tab_input_registers, kTableSize}};
}

void NcServer::update(const std::function<void(Tables&)>& fn) {
  const std::lock_guard<std::mutex> lock(mutex_);
  Tables t = tables();
  fn(t);
}

std::vector<std::uint16_t> NcServer::holding(std::uint16_t address, std::uint16_t count) {
  const std::lock_guard<std::mutex> lock(mutex_);
  const modbus_mapping_t* m = mapping(mapping_);
  const auto n = std::min<std::size_t>(count, static_cast<std::size_t>(kTableSize - address));
  return {m->tab_registers + address, m->tab_registers + address + n};
}

std::vector<WriteRecord> NcServer::writes() {
  const std::lock_guard<std::mutex> lock(mutex_);
  return writes_;
}

void NcServer::handle(void* ctx_p, int fd, const std::uint8_t* query, int length) {
  auto* ctx = static_cast<modbus_t*>(ctx_p);
  (void)fd;
  ++requests_;
  const int hl = modbus_get_header_length(ctx);
  const std::uint8_t function = query[hl];
  const auto address = static_cast<std::uint16_t>((query[hl + 1] << 8) | query[hl + 2]);
  std::uint32_t count = 1;
  if (function == 1 || function == 2 || function == 3 || function == 4 || function == 15 ||
      function == 16) {
    count = static_cast<std::uint32_t>((query[hl + 3] << 8) | query[hl + 4]);
  }
  if (silent_.load() || touches(address, count, kSilentAddress)) {
    return;
  }
  if (touches(address, count, kDelayAddress)) {
    std::this_thread::sleep_for(std::chrono::milliseconds(delay_ms_.load()));
  }
  if (const int code = read_exception_.load(); code != 0 && function >= 1 && function <= 4) {
    modbus_reply_exception(ctx, query, static_cast<unsigned>(code));
    return;
  }
  for (unsigned code = 1; code <= 11; ++code) {
    if (touches(address, count, static_cast<std::uint16_t>(kExceptionBase + code))) {
      modbus_reply_exception(ctx, query, code);
      return;
    }
  }
  std::vector<std::uint8_t> q(query, query + length);
  if (touches(address, count, kWrongTidAddress)) {
    if (config_.rtu) {
      q[0] = static_cast<std::uint8_t>(q[0] + 1);  // answer as another unit
    } else {
      q[1] = static_cast<std::uint8_t>(q[1] + 1);  // transaction id + 1
    }
  }
  const std::lock_guard<std::mutex> lock(mutex_);
  if (function == 5 || function == 6 || function == 15 || function == 16) {
    WriteRecord w;
    w.function = function;
    w.address = address;
    if (function == 16) {
      for (std::uint32_t i = 0; i < count && hl + 6 + 2 * static_cast<int>(i) + 1 < length; ++i) {
        const int o = hl + 6 + 2 * static_cast<int>(i);
        w.values.push_back(static_cast<std::uint16_t>((query[o] << 8) | query[o + 1]));
      }
    } else if (function == 5 || function == 6) {
      w.values.push_back(static_cast<std::uint16_t>((query[hl + 3] << 8) | query[hl + 4]));
    }
    if (write_filter_ && !write_filter_(w)) {
      modbus_reply_exception(ctx, query, MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE);
      return;
    }
    const int rc = modbus_reply(ctx, q.data(), length, mapping(mapping_));
    if (after_write_ && rc != -1) {
      Tables t = tables();
      after_write_(w, t);
    }
    writes_.push_back(std::move(w));
    return;
  }
  modbus_reply(ctx, q.data(), length, mapping(mapping_));
}

void NcServer::run() {
  auto* ctx = static_cast<modbus_t*>(ctx_);
  std::vector<std::uint8_t> query(MODBUS_MAX_ADU_LENGTH);
  std::vector<int> clients;
  if (config_.rtu) {
    clients.push_back(modbus_get_socket(ctx));
  }
  for (;;) {
    fd_set set;
    FD_ZERO(&set);
    FD_SET(stop_pipe_[0], &set);
    int maxfd = stop_pipe_[0];
    if (listen_fd_ != -1) {
      FD_SET(listen_fd_, &set);
      maxfd = std::max(maxfd, listen_fd_);
    }
    for (int c : clients) {
      FD_SET(c, &set);
      maxfd = std::max(maxfd, c);
    }
    if (select(maxfd + 1, &set, nullptr, nullptr, nullptr) == -1) {
      if (errno == EINTR) {
        continue;
      }
      break;
    }
    if (FD_ISSET(stop_pipe_[0], &set)) {
      break;
    }
    if (listen_fd_ != -1 && FD_ISSET(listen_fd_, &set)) {
      const int c = accept(listen_fd_, nullptr, nullptr);
      if (c != -1) {
        clients.push_back(c);
      }
    }
    for (auto it = clients.begin(); it != clients.end();) {
      const int c = *it;
      if (!FD_ISSET(c, &set)) {
        ++it;
        continue;
      }
      modbus_set_socket(ctx, c);
      const int rc = modbus_receive(ctx, query.data());
      if (rc > 0) {
        handle(ctx, c, query.data(), rc);
        ++it;
      } else if (rc == -1 && !config_.rtu) {
        close(c);  // the client closed or sent garbage: drop it like a real NC would
        it = clients.erase(it);
      } else {
        if (config_.rtu && rc == -1) {
          modbus_flush(ctx);
        }
        ++it;
      }
    }
  }
  if (!config_.rtu) {
    for (int c : clients) {
      close(c);
    }
  } else {
    modbus_set_socket(ctx, clients.front());
  }
}

}  // namespace nccomp::sim::modbus_nc
