// modbus_map: the commissioning view of a [modbus] register map.
//
//   modbus_map CONFIG.toml           validate; print the read requests of one poll, where each
//                                    signal and offset sits, and on RTU the bus budget
//   modbus_map CONFIG.toml --read    additionally connect with the real driver, poll for one
//                                    second and print what was decoded, the counters, and the
//                                    values the NC's offset registers hold now
//
// Exit codes: 0 ok, 1 --read could not reach the NC (or decoded no axis sample), 2 usage,
// 3 config refused (the message names file, line and key path).
#include <modbus/modbus.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>
#include <thread>
#include <variant>

#include "drivers/modbus/config.hpp"
#include "drivers/modbus/modbus_bus.hpp"
#include "formats/toml/diagnostics.hpp"
#include "nccomp_version.hpp"

namespace mb = nccomp::drivers::modbus;

namespace {

const char* table_name(mb::Table t) {
  switch (t) {
    case mb::Table::kCoil:
      return "coil";
    case mb::Table::kDiscreteInput:
      return "discrete_input";
    case mb::Table::kHolding:
      return "holding";
    case mb::Table::kInput:
      return "input";
  }
  return "?";
}

const char* type_name(mb::ValueType t) {
  switch (t) {
    case mb::ValueType::kBool:
      return "bool";
    case mb::ValueType::kInt16:
      return "int16";
    case mb::ValueType::kUint16:
      return "uint16";
    case mb::ValueType::kInt32:
      return "int32";
    case mb::ValueType::kUint32:
      return "uint32";
    case mb::ValueType::kFloat32:
      return "float32";
  }
  return "?";
}

std::string describe(const mb::Encoding& e) {
  std::string s = type_name(e.type);
  if (mb::width(e.type) == 2 && e.word_order == mb::WordOrder::kLowFirst) {
    s += " low_first";
  }
  if (e.byte_order == mb::ByteOrder::kSwapped) {
    s += " swapped";
  }
  char buf[64];
  if (std::fabs(e.scale - 1.0) > 0.0) {
    std::snprintf(buf, sizeof(buf), " scale %g", e.scale);
    s += buf;
  }
  if (std::fabs(e.offset) > 0.0) {
    std::snprintf(buf, sizeof(buf), " offset %g", e.offset);
    s += buf;
  }
  return s;
}

void print_plan(const mb::ModbusConfig& c) {
  if (c.transport == mb::Transport::kTcp) {
    std::printf("transport tcp %s:%u unit %u, poll %.6g Hz, offsets at most %.6g Hz\n",
                c.host.c_str(), c.port, c.unit_id, c.poll_rate_hz, c.offset_write_rate_hz);
  } else {
    std::printf("transport rtu %s %u baud, unit %u, poll %.6g Hz, offsets at most %.6g Hz\n",
                c.device.c_str(), c.baud, c.unit_id, c.poll_rate_hz, c.offset_write_rate_hz);
    std::printf(
        "rtu: frame gap %.3f ms, %.2f ms of bus time per poll (%.0f %% of the period), "
        "%.2f ms to write every offset once\n",
        mb::rtu_frame_gap_s(c) * 1e3, c.poll_bus_time_s * 1e3,
        c.poll_bus_time_s * c.poll_rate_hz * 100.0, c.write_bus_time_s * 1e3);
  }
  std::printf("%zu read request(s) per poll:\n", c.blocks.size());
  for (std::size_t b = 0; b < c.blocks.size(); ++b) {
    const mb::ReadBlock& rb = c.blocks[b];
    std::printf("  [%zu] %s %u..%u (%u)\n", b, table_name(rb.table), rb.start,
                rb.start + rb.count - 1U, rb.count);
    for (std::size_t g = 0; g < mb::kGroupCount; ++g) {
      const auto group = static_cast<mb::Group>(g);
      for (std::size_t f = 0; f < mb::field_count(group); ++f) {
        const mb::SignalMap& s = c.groups[g].fields[f];
        if (s.mapped && s.block == b) {
          std::printf("      %-6u %s.%s  %s%s\n", s.address,
                      std::string(mb::group_key(group)).c_str(),
                      std::string(mb::field_key(group, f)).c_str(), describe(s.encoding).c_str(),
                      s.count > 1 ? (" x" + std::to_string(s.count)).c_str() : "");
        }
      }
    }
    for (const mb::TemperatureMap& t : c.temperatures) {
      if (t.value.block == b) {
        std::printf("      %-6u temperature sensor %u  %s\n", t.value.address, t.sensor,
                    describe(t.value.encoding).c_str());
      }
    }
  }
  std::printf("%zu offset register(s), written with function 16:\n", c.offsets.size());
  for (const mb::OffsetMap& o : c.offsets) {
    std::printf("  register_index %-4u -> holding %u  %s\n", o.register_index, o.address,
                describe(o.encoding).c_str());
  }
}

int read_once(const mb::ModbusConfig& c) {
  mb::ModbusBus bus(c);
  bus.start();
  std::this_thread::sleep_for(std::chrono::seconds(1));
  bus.stop();
  const mb::ModbusStatus st = bus.modbus_status();
  nccomp::core::Event e;
  nccomp::core::AxisSample last{};
  std::size_t samples = 0;
  std::size_t events = 0;
  while (bus.rx().try_pop(e)) {
    if (const auto* a = std::get_if<nccomp::core::AxisSample>(&e)) {
      last = *a;
      ++samples;
    } else {
      ++events;
    }
  }
  std::printf(
      "read for 1 s: %llu polls, %zu axis samples, %zu events, %llu lost, "
      "%llu invalid values\n",
      static_cast<unsigned long long>(st.polls), samples, events,
      static_cast<unsigned long long>(st.events_lost),
      static_cast<unsigned long long>(st.values_invalid));
  std::printf(
      "faults: %llu timeouts, %llu bad responses, %llu crc, %llu connection errors, "
      "exceptions:",
      static_cast<unsigned long long>(st.timeouts),
      static_cast<unsigned long long>(st.bad_responses),
      static_cast<unsigned long long>(st.crc_errors),
      static_cast<unsigned long long>(st.connection_errors));
  for (std::size_t k = 0; k < st.exceptions.size(); ++k) {
    if (st.exceptions[k] != 0) {
      std::printf(" code %zu x%llu", k, static_cast<unsigned long long>(st.exceptions[k]));
    }
  }
  std::printf("\n");
  if (samples == 0) {
    std::printf("no axis sample decoded (errno %d: %s)\n", st.last_errno,
                modbus_strerror(st.last_errno));
    return 1;
  }
  std::printf("last sample:");
  static const char* const kAxes[] = {"x", "y", "z", "a", "b", "c"};
  for (std::size_t i = 0; i < last.axis_count; ++i) {
    std::printf(" %s=%.4f", kAxes[i], last.position_mm[i]);
  }
  std::printf(" path=%.3f tool=%d cutting=%d", last.program_path_mm, last.tool,
              last.cutting ? 1 : 0);
  if (last.has_normal) {
    std::printf(" normal=(%.4f, %.4f, %.4f)", last.normal[0], last.normal[1], last.normal[2]);
  }
  std::printf("\n");
  // What the NC's offset registers hold now (read with a plain client, after the driver left).
  if (c.offsets.empty() || c.transport != mb::Transport::kTcp) {
    return 0;
  }
  modbus_t* ctx = modbus_new_tcp_pi(c.host.c_str(), std::to_string(c.port).c_str());
  if (ctx == nullptr || modbus_connect(ctx) != 0) {
    if (ctx != nullptr) {
      modbus_free(ctx);
    }
    return 1;
  }
  modbus_set_slave(ctx, c.unit_id);
  std::printf("offset registers on the NC now:\n");
  for (const mb::OffsetMap& o : c.offsets) {
    std::uint16_t regs[2] = {0, 0};
    const int n = mb::width(o.encoding.type);
    if (modbus_read_registers(ctx, o.address, n, regs) == n) {
      std::printf("  register_index %-4u = %.3f um\n", o.register_index,
                  mb::decode(std::span<const std::uint16_t>(regs, static_cast<std::size_t>(n)),
                             o.encoding));
    } else {
      std::printf("  register_index %-4u : %s\n", o.register_index, modbus_strerror(errno));
    }
  }
  modbus_close(ctx);
  modbus_free(ctx);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  constexpr const char* kUsage =
      "usage: modbus_map CONFIG.toml [--read]\n"
      "       modbus_map --help | --version\n";
  if (argc == 2 && (std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h")) {
    std::printf(
        "modbus_map — the commissioning view of a [modbus] register map\n%s\n"
        "  CONFIG.toml   a file with the [modbus] table (or including it)\n"
        "  --read        also connect with the real driver, poll for one second and print what\n"
        "                was decoded and what the NC's offset registers hold\n"
        "Exit status: 0 ok, 1 --read could not reach the NC, 2 usage, 3 the map is invalid.\n",
        kUsage);
    return 0;
  }
  if (argc == 2 && std::string(argv[1]) == "--version") {
    std::printf("modbus_map %s\n", nccomp::kVersion);
    return 0;
  }
  if (argc < 2 || argc > 3 || (argc == 3 && std::string(argv[2]) != "--read") ||
      argv[1][0] == '-') {
    std::fprintf(stderr, "%s", kUsage);
    return 2;
  }
  mb::ModbusConfig c;
  try {
    c = mb::load_modbus_config(argv[1]);
  } catch (const nccomp::formats::DiagnosticsError& e) {
    std::fprintf(stderr, "modbus_map: %s\n", e.what());
    return 3;
  }
  print_plan(c);
  return argc == 3 ? read_once(c) : 0;
}
