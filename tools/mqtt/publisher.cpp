#include "tools/mqtt/publisher.hpp"

#include <spdlog/spdlog.h>

#include <chrono>
#include <ctime>

#include "client/protocol.hpp"
#include "client/status_client.hpp"
#include "formats/measurement_log/measurement_log.hpp"

namespace nccomp::tools::mqtt {

namespace {

constexpr std::int64_t kNs = 1'000'000'000;
constexpr std::size_t kRowsPerPoll = 10'000;

std::int64_t mono_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * kNs + ts.tv_nsec;
}

std::int64_t real_ns() {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * kNs + ts.tv_nsec;
}

std::int64_t after_s(std::int64_t now, double s) {
  return now + static_cast<std::int64_t>(s * 1e9);
}

}  // namespace

Publisher::Publisher(PublishConfig config, std::string password)
    : config_(std::move(config)),
      queue_(DiskQueue::Options{config_.queue_directory,
                                static_cast<std::uint64_t>(config_.max_messages),
                                config_.queue_fsync_interval_s}),
      source_(config_.log_directory) {
  queue_.open();
  if (!queue_.cursor().empty()) source_.set_cursor(LogCursor::parse(queue_.cursor()));
  memory_ = StatusMemory::from_json(queue_.app_state().value("status", nlohmann::json{}));
  heartbeat_seq_ = queue_.app_state().value("heartbeat_seq", std::uint64_t{0});
  last_dropped_ = queue_.dropped_total();
  nlohmann::ordered_json will;
  will["machine"] = config_.machine;
  will["site"] = config_.site;
  will["online"] = false;
  link_ =
      std::make_unique<MqttLink>(config_.broker, std::move(password),
                                 Will{topic(config_.site, config_.machine, "status"), will.dump()});
}

Publisher::~Publisher() = default;

void Publisher::warn_every(const std::string& key, const std::string& text, std::int64_t now,
                           std::int64_t every_ns) {
  auto it = last_warned_.find(key);
  if (it != last_warned_.end() && now - it->second < every_ns) return;
  last_warned_[key] = now;
  spdlog::warn("{}", text);
}

void Publisher::handle(const LinkEvent& e, std::int64_t now) {
  using T = LinkEvent::Type;
  switch (e.type) {
    case T::kConnected:
      connected_ = true;
      spdlog::info("connected to {} as {} ({} message(s) queued)", config_.broker.uri,
                   config_.broker.client_id, queue_.queued());
      backoff_s_ = 1.0;
      queue_.rewind();
      in_flight_.clear();
      paused_until_ns_ = 0;
      next_heartbeat_ns_ = now;
      last_warned_.erase("connect");
      break;
    case T::kConnectFailed:
      warn_every("connect",
                 "cannot connect to " + config_.broker.uri + " as " +
                     (config_.broker.username.empty() ? "(no user)" : config_.broker.username) +
                     ": " + e.text + "; " + std::to_string(queue_.queued()) +
                     " message(s) stay queued, next try in " +
                     std::to_string(static_cast<int>(backoff_s_)) + " s",
                 now, 60 * kNs);
      next_connect_ns_ = after_s(now, backoff_s_);
      backoff_s_ = std::min(backoff_s_ * 2.0, config_.broker.reconnect_max_s);
      break;
    case T::kConnectionLost:
      connected_ = false;
      spdlog::warn("connection to {} lost ({}); {} message(s) queued", config_.broker.uri, e.text,
                   queue_.queued());
      queue_.rewind();
      in_flight_.clear();
      next_connect_ns_ = after_s(now, 1.0);
      break;
    case T::kDelivered:
      if (e.tag == 0) break;  // the heartbeat
      queue_.ack(e.tag);
      in_flight_.erase(e.tag);
      ++published_;
      break;
    case T::kRefused:
      if (e.tag == 0) {
        warn_every("refused-status", "the broker refused the heartbeat: " + e.text, now, 60 * kNs);
        break;
      }
      ++refused_;
      warn_every("refused",
                 "the broker refused a message under nccomp/" + config_.site + "/" +
                     config_.machine + "/ (" + e.text + "): check the broker's ACL for user '" +
                     config_.broker.username + "'; the messages stay queued, retrying in " +
                     std::to_string(static_cast<int>(config_.broker.reconnect_max_s)) + " s (" +
                     std::to_string(refused_) + " refusal(s) so far)",
                 now, 60 * kNs);
      paused_until_ns_ = after_s(now, config_.broker.reconnect_max_s);
      queue_.rewind();
      in_flight_.clear();
      break;
    case T::kFailed:
      in_flight_.erase(e.tag);
      break;
    case T::kSubscribed:
      break;
  }
}

void Publisher::poll_log() {
  std::vector<LogProblem> problems;
  std::vector<LogRow> rows;
  const LogCursor start = source_.cursor();
  try {
    rows = source_.poll(kRowsPerPoll, problems);
  } catch (const std::exception& e) {
    warn_every("log-dir", e.what(), mono_ns(), 60 * kNs);
    return;
  }
  for (const LogProblem& p : problems) {
    ++source_problems_;
    // Built with +=: GCC 12 warns falsely (-Wrestrict) about ":" + std::string at -O3.
    std::string where = p.file;
    if (p.line > 0) {
      where += ':';
      where += std::to_string(p.line);
    }
    spdlog::warn("{}: {}", where, p.message);
  }
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const LogRow& r = rows[i];
    const auto m = r.columns.find("machine");
    if (m == r.columns.end() || *m != config_.machine) {
      // Publishing a row under another machine's topic would file it wrongly: stop here until
      // the configurations agree (the row stays in the log, the next poll reads it again).
      source_error_ = "the log " + r.file + " has rows of machine '" +
                      (m == r.columns.end() ? "" : m->get<std::string>()) +
                      "' but this publisher is machine '" + config_.machine +
                      "' ([publish] machine and nccompd's [measurement_log] machine_id must "
                      "agree); publishing stops at this row";
      warn_every("machine", source_error_, mono_ns(), 60 * kNs);
      source_.set_cursor(i > 0 ? rows[i - 1].after : start);
      return;
    }
    source_error_.clear();
    const std::string kind = "measurements";
    const std::uint64_t seq = queue_.next_seq(kind);
    nlohmann::ordered_json payload;
    payload["seq"] = seq;
    for (const auto& [k, v] : r.columns.items()) payload[k] = v;
    queue_.append(kind, seq, r.after.to_string(), payload.dump());
  }
  // Rows skipped after the last queued one (a v1 file, a malformed row) are not read again.
  queue_.set_cursor(source_.cursor().to_string());
}

void Publisher::poll_status() {
  std::string answer;
  try {
    answer = client::query(config_.status_socket, client::kStatusJson);
  } catch (const std::exception& e) {
    if (daemon_reachable_ || last_warned_.count("status") == 0) {
      warn_every("status",
                 "status socket " + config_.status_socket + ": " + e.what() +
                     " (no alarms or model changes are published until it answers)",
                 mono_ns(), 600 * kNs);
    }
    daemon_reachable_ = false;
    daemon_summary_ = nullptr;
    return;
  }
  try {
    const nlohmann::json status = nlohmann::json::parse(answer);
    if (!daemon_reachable_) spdlog::info("status socket {} answers", config_.status_socket);
    daemon_reachable_ = true;
    last_warned_.erase("status");
    const auto messages =
        digest_status(status, memory_, static_cast<double>(mono_ns()) / 1e9, real_ns());
    daemon_summary_ = daemon_summary(status);
    for (const StatusMessage& m : messages) {
      const std::uint64_t seq = queue_.next_seq(m.kind);
      nlohmann::ordered_json payload;
      payload["seq"] = seq;
      payload["machine"] = config_.machine;
      for (const auto& [k, v] : m.payload.items()) payload[k] = v;
      queue_.append(m.kind, seq, source_.cursor().to_string(), payload.dump());
    }
    if (!messages.empty()) {
      // The dedupe memory goes to disk with the messages: a restart publishes neither twice.
      queue_.app_state()["status"] = memory_.to_json();
      queue_.flush(true);
      queue_.save_state();
    } else {
      queue_.app_state()["status"] = memory_.to_json();
    }
  } catch (const std::exception& e) {
    warn_every("status-json",
               "status socket " + config_.status_socket +
                   ": an answer that is not nccompd's status JSON (" + e.what() + ")",
               mono_ns(), 600 * kNs);
  }
}

void Publisher::send() {
  QueuedMessage m;
  while (in_flight_.size() < static_cast<std::size_t>(config_.broker.max_inflight) &&
         queue_.next(m)) {
    if (!link_->publish(topic(config_.site, config_.machine, m.kind), m.payload, m.id)) {
      queue_.rewind();
      in_flight_.clear();
      return;
    }
    in_flight_.insert(m.id);
  }
}

void Publisher::heartbeat(bool online) {
  nlohmann::ordered_json p;
  p["seq"] = ++heartbeat_seq_;
  p["machine"] = config_.machine;
  p["site"] = config_.site;
  p["utc"] = formats::measurement_log::format_utc(real_ns());
  p["online"] = online;
  p["daemon"] = daemon_reachable_ ? daemon_summary_ : nlohmann::ordered_json(nullptr);
  nlohmann::ordered_json q;
  q["queued"] = queue_.queued();
  q["published"] = published_;
  q["acknowledged"] = queue_.acknowledged();
  q["dropped"] = {{"measurements", queue_.dropped("measurements")},
                  {"alarms", queue_.dropped("alarms")},
                  {"model", queue_.dropped("model")}};
  q["refused"] = refused_;
  q["source_problems"] = source_problems_;
  q["log_files_missed"] = source_.files_missed();
  q["source_error"] = source_error_.empty() ? nlohmann::ordered_json(nullptr)
                                            : nlohmann::ordered_json(source_error_);
  p["publisher"] = q;
  queue_.app_state()["heartbeat_seq"] = heartbeat_seq_;
  link_->publish(topic(config_.site, config_.machine, "status"), p.dump(), 0, true);
}

int Publisher::run(const std::atomic<bool>& stop) {
  spdlog::info("nccomp publish: machine {} at site {}, log {}, queue {} ({} queued, at most {})",
               config_.machine, config_.site, config_.log_directory, config_.queue_directory,
               queue_.queued(), config_.max_messages);
  std::int64_t now = mono_ns();
  next_connect_ns_ = now;
  next_log_ns_ = now;
  next_status_ns_ = now;
  while (!stop.load()) {
    for (const LinkEvent& e : link_->wait(20)) handle(e, mono_ns());
    now = mono_ns();
    if (!connected_ && now >= next_connect_ns_) {
      next_connect_ns_ = after_s(now, 15.0);  // the attempt's result sets the next one
      link_->connect();
    }
    if (now >= next_log_ns_) {
      next_log_ns_ = after_s(now, config_.log_poll_s);
      poll_log();
    }
    if (!config_.status_socket.empty() && now >= next_status_ns_) {
      next_status_ns_ = after_s(now, config_.status_poll_s);
      poll_status();
    }
    try {
      queue_.flush();
    } catch (const std::exception& e) {
      spdlog::error("queue: {}", e.what());
      return 1;
    }
    if (queue_.dropped_total() != last_dropped_) {
      spdlog::warn(
          "queue full ({} messages): dropped {} oldest message(s); dropped so far: {} "
          "measurement row(s), {} alarm message(s), {} model message(s)",
          config_.max_messages, queue_.dropped_total() - last_dropped_,
          queue_.dropped("measurements"), queue_.dropped("alarms"), queue_.dropped("model"));
      last_dropped_ = queue_.dropped_total();
    }
    // The connection as the events say (not link_->connected(), which turns true before the
    // kConnected event rewinds the queue: messages sent in between would go twice).
    if (connected_ && now >= paused_until_ns_) send();
    if (connected_ && now >= next_heartbeat_ns_) {
      next_heartbeat_ns_ = after_s(now, config_.heartbeat_s);
      heartbeat(true);
    }
  }
  spdlog::info("stopping: {} message(s) queued, {} published in this run", queue_.queued(),
               published_);
  if (connected_) {
    heartbeat(false);
    const auto until = mono_ns() + 2 * kNs;
    while (link_->in_flight() > 0 && mono_ns() < until) {
      for (const LinkEvent& e : link_->wait(20)) handle(e, mono_ns());
    }
    link_->disconnect();
  }
  queue_.close();
  return 0;
}

}  // namespace nccomp::tools::mqtt
