// bench_mqtt_rowgen DIR MACHINES RATE_PER_MACHINE SECONDS
// Writes DIR/<machine>/measurements.csv for machines m000, m001, … with nccompd's measurement-log
// writer (v2, one context column), RATE_PER_MACHINE rows/s each, for SECONDS; prints the rows
// written per machine. A row's utc is the time it is handed to the writer (its clock_ns).
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "daemon/measurement_log.hpp"

int main(int argc, char** argv) {
  if (argc != 5) {
    std::fprintf(stderr, "usage: %s DIR MACHINES RATE_PER_MACHINE SECONDS\n", argv[0]);
    return 2;
  }
  const std::string dir = argv[1];
  const int machines = std::atoi(argv[2]);
  const double rate = std::atof(argv[3]);
  const double seconds = std::atof(argv[4]);
  std::vector<std::unique_ptr<nccomp::daemon::MeasurementLogWriter>> writers;
  for (int m = 0; m < machines; ++m) {
    char name[16];
    std::snprintf(name, sizeof name, "m%03d", m);
    nccomp::daemon::MeasurementLogOptions o;
    o.directory = dir + "/" + name;
    o.machine_id = name;
    o.context_columns = {{"spindle_temp_c", 0}};
    o.keep_files = 100;
    writers.push_back(std::make_unique<nccomp::daemon::MeasurementLogWriter>(o));
    writers.back()->start();
  }
  const auto total = static_cast<long>(rate * machines * seconds);
  const auto start = std::chrono::steady_clock::now();
  std::vector<long> rows(static_cast<std::size_t>(machines), 0);
  for (long i = 0; i < total; ++i) {
    const auto m = static_cast<std::size_t>(i % machines);
    nccomp::core::MeasurementRecord r;
    timespec ts{};
    clock_gettime(CLOCK_MONOTONIC, &ts);
    r.clock_ns = static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
    r.time_ns = r.clock_ns;
    r.kind = nccomp::core::MeasurementKind::kContour;
    r.point = static_cast<std::int32_t>(rows[m]);
    r.part = 1;
    r.tool = 12;
    r.measured_um = 1.0;
    r.position_mm = {100.0, -20.0, -5.0};
    r.context[0] = 25.0;
    while (!writers[m]->ring().try_push(r))
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    ++rows[m];
    std::this_thread::sleep_until(start +
                                  std::chrono::nanoseconds(static_cast<std::int64_t>(
                                      static_cast<double>(i + 1) * 1e9 / (rate * machines))));
  }
  for (auto& w : writers) w->stop();
  long sum = 0;
  for (long n : rows) sum += n;
  std::printf("rows %ld machines %d rate_per_machine %g seconds %g\n", sum, machines, rate,
              seconds);
  return 0;
}
