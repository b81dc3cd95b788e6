#include "tools/mqtt/mqtt_link.hpp"

#include <MQTTReasonCodes.h>

#include <chrono>
#include <cstring>
#include <stdexcept>

namespace nccomp::tools::mqtt {

std::string reason_text(int reason) {
  const char* t = MQTTReasonCode_toString(static_cast<enum MQTTReasonCodes>(reason));
  return std::to_string(reason) + " " + (t != nullptr ? t : "unknown");
}

MqttLink::MqttLink(BrokerOptions options, std::string password, std::optional<Will> will)
    : options_(std::move(options)), password_(std::move(password)), will_(std::move(will)) {
  create_client();
}

void MqttLink::create_client() {
  MQTTAsync_createOptions co = MQTTAsync_createOptions_initializer5;
  // Paho's own buffer for messages handed over while the connection is down: none, the
  // publisher keeps them in its queue on disk.
  co.sendWhileDisconnected = 0;
  const int rc =
      MQTTAsync_createWithOptions(&client_, options_.uri.c_str(), options_.client_id.c_str(),
                                  MQTTCLIENT_PERSISTENCE_NONE, nullptr, &co);
  if (rc != MQTTASYNC_SUCCESS) {
    client_ = nullptr;
    throw std::runtime_error("MQTT client for '" + options_.uri + "' (client id '" +
                             options_.client_id + "'): " + MQTTAsync_strerror(rc));
  }
  MQTTAsync_setCallbacks(client_, this, &MqttLink::on_connection_lost, &MqttLink::on_message,
                         nullptr);
}

MqttLink::~MqttLink() {
  if (client_ != nullptr) {
    if (MQTTAsync_isConnected(client_)) disconnect(1000);
    MQTTAsync_destroy(&client_);  // no callback runs after this
  }
}

void MqttLink::subscribe_on_connect(std::string filter, MessageHandler handler) {
  std::lock_guard<std::mutex> lock(mu_);
  filter_ = std::move(filter);
  handler_ = std::move(handler);
}

void MqttLink::push(LinkEvent e) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    events_.push_back(std::move(e));
  }
  cv_.notify_one();
}

void MqttLink::connect() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (connecting_ || connected_) return;
  }
  if (used_) {
    // A fresh Paho client for every attempt after the first. Paho 1.3.11 keeps the previous
    // connection's in-flight messages and their commands: resending them on the resumed session
    // raced with its send thread (a heap-use-after-free under ASan), and with clean start
    // instead, 20 rows were reported acknowledged that the broker never received (the
    // broker-restart test, MqttHil.*; a PUBACK matched to a stale command). The owner sends the
    // unacknowledged messages again from its own queue; the broker resumes the session all the same
    // (clean start off, same client id). Cost: Paho does not free those stale messages on destroy
    // (about 300 bytes per message in flight at the loss, at most max_inflight per reconnect).
    MQTTAsync_destroy(&client_);  // no callback of the old client runs after this
    {
      std::lock_guard<std::mutex> lock(mu_);
      pending_.clear();
    }
    create_client();
  }
  used_ = true;
  {
    std::lock_guard<std::mutex> lock(mu_);
    connecting_ = true;
  }
  MQTTAsync_connectOptions o = MQTTAsync_connectOptions_initializer5;
  o.keepAliveInterval = options_.keepalive_s;
  o.cleanstart = 0;
  o.maxInflight = options_.max_inflight + 16;
  o.connectTimeout = 10;
  o.automaticReconnect = 0;
  o.onSuccess5 = &MqttLink::on_connected;
  o.onFailure5 = &MqttLink::on_connect_failed;
  o.context = this;
  if (!options_.username.empty()) o.username = options_.username.c_str();
  if (!password_.empty()) o.password = password_.c_str();
  MQTTProperties props = MQTTProperties_initializer;
  MQTTProperty expiry{};
  expiry.identifier = MQTTPROPERTY_CODE_SESSION_EXPIRY_INTERVAL;
  expiry.value.integer4 = static_cast<unsigned int>(options_.session_expiry_s);
  MQTTProperties_add(&props, &expiry);
  o.connectProperties = &props;
  MQTTAsync_willOptions wo = MQTTAsync_willOptions_initializer;
  if (will_) {
    wo.topicName = will_->topic.c_str();
    wo.message = nullptr;
    wo.payload.data = will_->payload.data();
    wo.payload.len = static_cast<int>(will_->payload.size());
    wo.qos = 1;
    wo.retained = 1;
    o.will = &wo;
  }
  MQTTAsync_SSLOptions ssl = MQTTAsync_SSLOptions_initializer;
  if (options_.uri.rfind("ssl://", 0) == 0 || options_.uri.rfind("mqtts://", 0) == 0) {
    ssl.enableServerCertAuth = 1;
    ssl.verify = 1;
    if (!options_.ca_file.empty()) ssl.trustStore = options_.ca_file.c_str();
    if (!options_.cert_file.empty()) ssl.keyStore = options_.cert_file.c_str();
    if (!options_.key_file.empty()) ssl.privateKey = options_.key_file.c_str();
    o.ssl = &ssl;
  }
  const int rc = MQTTAsync_connect(client_, &o);
  MQTTProperties_free(&props);
  if (rc != MQTTASYNC_SUCCESS) {
    {
      std::lock_guard<std::mutex> lock(mu_);
      connecting_ = false;
    }
    push(LinkEvent{LinkEvent::Type::kConnectFailed, 0, 0, MQTTAsync_strerror(rc)});
  }
}

bool MqttLink::connected() const {
  std::lock_guard<std::mutex> lock(mu_);
  return connected_;
}

std::size_t MqttLink::in_flight() const {
  std::lock_guard<std::mutex> lock(mu_);
  return pending_.size();
}

void MqttLink::on_connected(void* ctx, MQTTAsync_successData5* /*r*/) {
  auto* self = static_cast<MqttLink*>(ctx);
  {
    std::lock_guard<std::mutex> lock(self->mu_);
    self->connected_ = true;
    self->connecting_ = false;
  }
  self->push(LinkEvent{LinkEvent::Type::kConnected, 0, 0, {}});
}

void MqttLink::on_subscribed(void* ctx, MQTTAsync_successData5* r) {
  auto* self = static_cast<MqttLink*>(ctx);
  // A refused subscription is a success with an error reason (e.g. 135: the ACL).
  const int reason = r != nullptr ? static_cast<int>(r->reasonCode) : 0;
  if (reason >= MQTTREASONCODE_UNSPECIFIED_ERROR) {
    self->push(LinkEvent{LinkEvent::Type::kRefused, 0, reason,
                         "subscription to " + self->filter_ + " refused: " + reason_text(reason)});
    return;
  }
  self->push(LinkEvent{LinkEvent::Type::kSubscribed, 0, reason, self->filter_});
}

void MqttLink::on_subscribe_failed(void* ctx, MQTTAsync_failureData5* r) {
  auto* self = static_cast<MqttLink*>(ctx);
  const int reason = r != nullptr ? static_cast<int>(r->reasonCode) : 0;
  self->push(LinkEvent{LinkEvent::Type::kRefused, 0, reason,
                       "subscription to " + self->filter_ + " failed: " + reason_text(reason)});
}

void MqttLink::on_connect_failed(void* ctx, MQTTAsync_failureData5* r) {
  auto* self = static_cast<MqttLink*>(ctx);
  {
    std::lock_guard<std::mutex> lock(self->mu_);
    self->connecting_ = false;
  }
  LinkEvent e{LinkEvent::Type::kConnectFailed, 0, 0, {}};
  if (r != nullptr) {
    // A refusal by the broker comes as its CONNACK reason code (Paho puts it in `code`).
    e.reason = r->reasonCode != MQTTREASONCODE_SUCCESS ? static_cast<int>(r->reasonCode) : r->code;
    e.text = r->code > 0 ? reason_text(r->code)
                         : (r->message != nullptr ? r->message : MQTTAsync_strerror(r->code));
  }
  self->push(std::move(e));
}

void MqttLink::on_connection_lost(void* ctx, char* cause) {
  auto* self = static_cast<MqttLink*>(ctx);
  {
    std::lock_guard<std::mutex> lock(self->mu_);
    self->connected_ = false;
  }
  self->push(LinkEvent{LinkEvent::Type::kConnectionLost, 0, 0,
                       cause != nullptr ? cause : "connection lost"});
  if (cause != nullptr) MQTTAsync_free(cause);
}

int MqttLink::on_message(void* ctx, char* topic, int topic_len, MQTTAsync_message* m) {
  auto* self = static_cast<MqttLink*>(ctx);
  const std::string t =
      topic_len > 0 ? std::string(topic, static_cast<std::size_t>(topic_len)) : std::string(topic);
  const std::string payload(static_cast<const char*>(m->payload),
                            static_cast<std::size_t>(m->payloadlen));
  bool taken = true;
  if (self->handler_) taken = self->handler_(t, payload);
  if (taken) {
    MQTTAsync_freeMessage(&m);
    MQTTAsync_free(topic);
    return 1;
  }
  return 0;
}

void MqttLink::finish(Pending* p, LinkEvent e) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    pending_.erase(p);
    events_.push_back(std::move(e));
  }
  cv_.notify_one();
}

void MqttLink::on_published(void* ctx, MQTTAsync_successData5* /*r*/) {
  auto* p = static_cast<Pending*>(ctx);
  p->link->finish(p, LinkEvent{LinkEvent::Type::kDelivered, p->tag, 0, {}});
}

void MqttLink::on_publish_failed(void* ctx, MQTTAsync_failureData5* r) {
  auto* p = static_cast<Pending*>(ctx);
  LinkEvent e{LinkEvent::Type::kFailed, p->tag, 0, {}};
  if (r != nullptr && r->reasonCode >= MQTTREASONCODE_UNSPECIFIED_ERROR) {
    // The broker answered the PUBLISH with an error reason (an ACL refusal is 135).
    e.type = LinkEvent::Type::kRefused;
    e.reason = static_cast<int>(r->reasonCode);
    e.text = reason_text(e.reason);
  } else if (r != nullptr) {
    e.reason = r->code;
    e.text = r->message != nullptr ? r->message : MQTTAsync_strerror(r->code);
  }
  p->link->finish(p, std::move(e));
}

bool MqttLink::publish(const std::string& topic, const std::string& payload, std::uint64_t tag,
                       bool retained) {
  auto owned = std::make_unique<Pending>(Pending{this, tag});
  Pending* p = owned.get();
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (!connected_) return false;
    pending_.emplace(p, std::move(owned));
  }
  MQTTAsync_responseOptions ro = MQTTAsync_responseOptions_initializer;
  ro.onSuccess5 = &MqttLink::on_published;
  ro.onFailure5 = &MqttLink::on_publish_failed;
  ro.context = p;
  MQTTAsync_message m = MQTTAsync_message_initializer;
  m.payload = const_cast<char*>(payload.data());
  m.payloadlen = static_cast<int>(payload.size());
  m.qos = 1;
  m.retained = retained ? 1 : 0;
  const int rc = MQTTAsync_sendMessage(client_, topic.c_str(), &m, &ro);
  if (rc != MQTTASYNC_SUCCESS) {
    std::lock_guard<std::mutex> lock(mu_);
    pending_.erase(p);
    return false;
  }
  return true;
}

std::vector<LinkEvent> MqttLink::wait(int timeout_ms) {
  std::vector<LinkEvent> out;
  {
    std::unique_lock<std::mutex> lock(mu_);
    cv_.wait_for(lock, std::chrono::milliseconds(timeout_ms), [this] { return !events_.empty(); });
    out.assign(std::make_move_iterator(events_.begin()), std::make_move_iterator(events_.end()));
    events_.clear();
  }
  for (const LinkEvent& e : out) {
    if (e.type == LinkEvent::Type::kConnected && !filter_.empty()) {
      // On the owner's thread (never while connect() replaces the client). The broker may have
      // lost the session (no persistence): subscribe after every connect.
      MQTTAsync_responseOptions ro = MQTTAsync_responseOptions_initializer;
      ro.onSuccess5 = &MqttLink::on_subscribed;
      ro.onFailure5 = &MqttLink::on_subscribe_failed;
      ro.context = this;
      MQTTAsync_subscribe(client_, filter_.c_str(), 1, &ro);
    }
  }
  return out;
}

void MqttLink::disconnect(int timeout_ms) {
  MQTTAsync_disconnectOptions o = MQTTAsync_disconnectOptions_initializer5;
  o.timeout = timeout_ms;
  MQTTAsync_disconnect(client_, &o);
  const auto until = std::chrono::steady_clock::now() + std::chrono::milliseconds(timeout_ms);
  while (MQTTAsync_isConnected(client_) && std::chrono::steady_clock::now() < until) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  std::lock_guard<std::mutex> lock(mu_);
  connected_ = false;
}

}  // namespace nccomp::tools::mqtt
