// The NC side of Modbus, written with libmodbus: a server (TCP on an address / port, or RTU on
// a serial device) over a full 65536-entry register space per table, with fault-triggering
// addresses in the style of libmodbus' own unit-test server. Used by the HIL tests, the
// benchmark, and ncsim (the virtual NC).
//
// Fault-triggering addresses (any table): a request whose address range touches one of them
// gets that fault instead of a normal answer.
//   kDelayAddress              answered normally after delay_ms (set_delay_ms)
//   kExceptionBase + code      answered with Modbus exception `code` (1..11)
//   kWrongTidAddress           TCP: answered with transaction id + 1; RTU: from another unit id
//   kSilentAddress             never answered
// Whole-server faults: set_silent(true) stops answering every request while keeping the
// connection open (a hung NC, a pulled cable as seen from the client); set_read_exception(code)
// answers every read (functions 1-4) with Modbus exception `code` while writes still work (an NC
// whose PLC lost its register map); 0 ends it.
//
// Threads: the server runs its own thread; update() / read() / writes() may be called from any
// thread. A request is answered under the same mutex update() takes, so a change made in one
// update() call is seen by a client all or nothing.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <span>
#include <string>
#include <thread>
#include <vector>

namespace nccomp::sim::modbus_nc {

inline constexpr std::uint16_t kDelayAddress = 0xFF00;
inline constexpr std::uint16_t kExceptionBase = 0xFF10;  // + exception code 1..11
inline constexpr std::uint16_t kWrongTidAddress = 0xFF20;
inline constexpr std::uint16_t kSilentAddress = 0xFF21;

struct ServerConfig {
  bool rtu{false};
  /// TCP: the address to bind (127.0.0.1 for tests) and the port; 0 = an ephemeral port.
  std::string bind_address{"127.0.0.1"};
  std::uint16_t port{0};
  /// RTU: the serial device (e.g. one end of a pseudo-terminal pair).
  std::string device{};
  int baud{115200};
  char parity{'N'};
  int data_bits{8};
  int stop_bits{1};
  std::uint8_t unit_id{1};
};

/// The four tables, as the NC sees them (bits as 0 / 1 bytes).
struct Tables {
  std::span<std::uint8_t> coils;
  std::span<std::uint8_t> discrete_inputs;
  std::span<std::uint16_t> holding;
  std::span<std::uint16_t> input;
};

/// One write request received (function 5, 6, 15 or 16).
struct WriteRecord {
  std::uint8_t function{0};
  std::uint16_t address{0};
  std::vector<std::uint16_t> values{};
};

class NcServer {
 public:
  explicit NcServer(ServerConfig config);
  ~NcServer();
  NcServer(const NcServer&) = delete;
  NcServer& operator=(const NcServer&) = delete;

  /// Binds / opens and starts the server thread. Throws std::runtime_error with the reason.
  /// After stop(), start() again serves the same port (a restarted NC).
  void start();
  /// Closes every connection and the listening socket; the registers are kept.
  void stop();
  [[nodiscard]] bool running() const noexcept { return thread_.joinable(); }
  /// TCP: the bound port (the ephemeral one after start with port 0).
  [[nodiscard]] std::uint16_t port() const noexcept { return config_.port; }

  /// Applies fn to the tables atomically with respect to requests.
  void update(const std::function<void(Tables&)>& fn);
  /// Reads holding registers.
  [[nodiscard]] std::vector<std::uint16_t> holding(std::uint16_t address, std::uint16_t count);
  /// Every write request received so far, oldest first.
  [[nodiscard]] std::vector<WriteRecord> writes();
  [[nodiscard]] std::uint64_t requests() const noexcept { return requests_.load(); }

  /// Called on the server thread, under the table mutex, for every write request before it is
  /// applied: false refuses it with exception 3 (illegal data value) and leaves the registers as
  /// they were, like an NC that range-checks its offsets (ncsim). Set before start().
  using WriteFilter = std::function<bool(const WriteRecord&)>;
  void set_write_filter(WriteFilter filter) { write_filter_ = std::move(filter); }
  /// Called on the server thread, under the table mutex, after a write request was applied and
  /// answered normally: it may change the tables, like an NC that rounds, clamps or silently
  /// ignores a value it acknowledged (what a client's read-back verification is for). A read
  /// that follows sees the change. Set before start().
  using AfterWrite = std::function<void(const WriteRecord&, Tables&)>;
  void set_after_write(AfterWrite fn) { after_write_ = std::move(fn); }

  void set_delay_ms(int ms) noexcept { delay_ms_.store(ms); }
  void set_silent(bool silent) noexcept { silent_.store(silent); }
  void set_read_exception(int code) noexcept { read_exception_.store(code); }

 private:
  void run();
  void handle(void* ctx, int fd, const std::uint8_t* query, int length);
  /// The tables over the mapping (caller holds mutex_).
  Tables tables();

  ServerConfig config_;
  std::mutex mutex_;
  void* mapping_{nullptr};  // modbus_mapping_t, guarded by mutex_
  std::vector<WriteRecord> writes_;
  WriteFilter write_filter_;
  AfterWrite after_write_;
  std::thread thread_;
  int stop_pipe_[2]{-1, -1};
  std::atomic<int> delay_ms_{500};
  std::atomic<bool> silent_{false};
  std::atomic<int> read_exception_{0};
  std::atomic<std::uint64_t> requests_{0};
  void* ctx_{nullptr};  // modbus_t, server thread after start()
  int listen_fd_{-1};
};

}  // namespace nccomp::sim::modbus_nc
