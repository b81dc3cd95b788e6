// One MQTT 5 connection through Eclipse Paho's asynchronous C client (libpaho-mqtt3as):
// persistent session (clean start off, a session expiry, a fixed client id), QoS 1, optional TLS
// and user name / password, an optional retained last will. Paho's callbacks run on Paho's
// threads; they only queue events, which the owner takes with wait() on its own thread. The
// owner decides when to (re)connect. Not real-time.
#pragma once

#include <MQTTAsync.h>

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include "tools/mqtt/mqtt_config.hpp"

namespace nccomp::tools::mqtt {

struct LinkEvent {
  enum class Type {
    kConnected,       // the connection is up
    kSubscribed,      // the broker granted the subscription (text: the filter)
    kConnectFailed,   // a connect attempt failed: reason / text say why
    kConnectionLost,  // an established connection broke
    kDelivered,       // the broker acknowledged message `tag`
    kRefused,         // the broker refused message `tag` (reason: an MQTT 5 reason code)
    kFailed,          // message `tag` was not delivered (the connection went)
  };
  Type type{Type::kConnected};
  std::uint64_t tag{0};
  int reason{0};
  std::string text;
};

struct Will {
  std::string topic;
  std::string payload;
};

/// Text for an MQTT 5 reason code, e.g. "135 not authorized".
[[nodiscard]] std::string reason_text(int reason);

class MqttLink {
 public:
  /// Called on Paho's thread for every message of a subscription; true = processed (Paho then
  /// acknowledges it), false = not taken now (redelivered later).
  using MessageHandler = std::function<bool(const std::string& topic, const std::string& payload)>;

  /// password: empty = none. Throws std::runtime_error if Paho refuses the options.
  MqttLink(BrokerOptions options, std::string password, std::optional<Will> will = std::nullopt);
  ~MqttLink();
  MqttLink(const MqttLink&) = delete;
  MqttLink& operator=(const MqttLink&) = delete;

  /// Subscriptions made (again) after every connect; set before connect().
  void subscribe_on_connect(std::string filter, MessageHandler handler);
  /// Starts a connect attempt; its result arrives as an event.
  void connect();
  [[nodiscard]] bool connected() const;
  /// Sends a message (QoS 1 unless qos_0); its acknowledgement arrives as an event with `tag`.
  /// False if it could not be handed to Paho (not connected, too many in flight).
  bool publish(const std::string& topic, const std::string& payload, std::uint64_t tag,
               bool retained = false);
  /// Waits up to timeout_ms for events and returns them (possibly none); subscribes after a
  /// connect. Call from one thread, the one that calls connect().
  std::vector<LinkEvent> wait(int timeout_ms);
  /// Disconnects (waits up to timeout_ms for Paho to finish).
  void disconnect(int timeout_ms = 2000);
  /// Messages handed to Paho and not yet acknowledged or failed.
  [[nodiscard]] std::size_t in_flight() const;

 private:
  struct Pending {
    MqttLink* link;
    std::uint64_t tag;
  };
  static void on_connected(void* ctx, MQTTAsync_successData5* r);
  static void on_connect_failed(void* ctx, MQTTAsync_failureData5* r);
  static void on_connection_lost(void* ctx, char* cause);
  static int on_message(void* ctx, char* topic, int topic_len, MQTTAsync_message* m);
  static void on_published(void* ctx, MQTTAsync_successData5* r);
  static void on_publish_failed(void* ctx, MQTTAsync_failureData5* r);
  static void on_subscribed(void* ctx, MQTTAsync_successData5* r);
  static void on_subscribe_failed(void* ctx, MQTTAsync_failureData5* r);
  void create_client();
  void push(LinkEvent e);
  void finish(Pending* p, LinkEvent e);

  BrokerOptions options_;
  std::string password_;
  std::optional<Will> will_;
  MQTTAsync client_{nullptr};
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::deque<LinkEvent> events_;
  bool connected_{false};
  bool connecting_{false};
  bool used_{false};
  std::unordered_map<Pending*, std::unique_ptr<Pending>> pending_;
  std::string filter_;
  MessageHandler handler_;
};

}  // namespace nccomp::tools::mqtt
