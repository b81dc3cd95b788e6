#include "tools/page/page_server.hpp"

#include <httplib.h>

#include <nlohmann/json.hpp>
#include <stdexcept>

namespace nccomp::page {

namespace {

// How long an idle /events stream waits before a keep-alive comment [s]; also how long a
// closed browser tab can hold its server thread.
constexpr double kKeepAliveS = 10.0;
constexpr std::size_t kMaxPayloadBytes = 64U * 1024U;

void security_headers(httplib::Response& res, const std::string& content_type) {
  res.set_header("X-Content-Type-Options", "nosniff");
  res.set_header("Cache-Control", "no-store");
  res.set_header("Referrer-Policy", "no-referrer");
  if (content_type.rfind("image/svg+xml", 0) == 0) {
    // A plot is shown as an image; opened by itself it runs nothing.
    res.set_header("Content-Security-Policy", "default-src 'none'; style-src 'unsafe-inline'");
  } else {
    res.set_header("Content-Security-Policy",
                   "default-src 'self'; img-src 'self'; frame-ancestors 'none'; form-action "
                   "'none'; base-uri 'none'");
  }
}

HttpRequest to_request(const httplib::Request& req) {
  HttpRequest r;
  r.method = req.method;
  r.path = req.path;
  r.content_type = req.get_header_value("Content-Type");
  r.origin = req.get_header_value("Origin");
  r.host = req.get_header_value("Host");
  r.body = req.body;
  r.client = Endpoint{req.remote_addr, req.remote_port};
  r.server = Endpoint{req.local_addr, req.local_port};
  return r;
}

}  // namespace

PageServer::PageServer(int max_watchers)
    : server_(std::make_unique<httplib::Server>()), max_watchers_(max_watchers) {
  const auto threads = static_cast<std::size_t>(max_watchers) + 4U;
  server_->new_task_queue = [threads] { return new httplib::ThreadPool(threads); };
  server_->set_payload_max_length(kMaxPayloadBytes);
  server_->set_read_timeout(5, 0);
  server_->set_write_timeout(5, 0);
}

PageServer::~PageServer() = default;

int PageServer::bind(const std::string& host, int port) {
  const int bound =
      port == 0 ? server_->bind_to_any_port(host) : (server_->bind_to_port(host, port) ? port : -1);
  if (bound <= 0) {
    throw std::runtime_error("cannot listen on " + host + ":" + std::to_string(port) +
                             " (address in use, or not an address of this host)");
  }
  return bound;
}

void PageServer::serve(PageService& service) {
  const auto forward = [&service](const httplib::Request& req, httplib::Response& res) {
    const HttpReply r = service.handle(to_request(req));
    res.status = r.status;
    if (!r.allow.empty()) res.set_header("Allow", r.allow);
    security_headers(res, r.content_type);
    res.set_content(r.body, r.content_type.c_str());
  };
  server_->Get("/events", [this, &service](const httplib::Request& req, httplib::Response& res) {
    const HttpReply judged = service.handle(to_request(req));
    if (judged.status != 200) {
      res.status = judged.status;
      security_headers(res, judged.content_type);
      res.set_content(judged.body, judged.content_type.c_str());
      return;
    }
    security_headers(res, "text/event-stream");
    if (watchers_.fetch_add(1) >= max_watchers_) {
      watchers_.fetch_sub(1);
      service.count_bad_request();
      res.status = 503;
      res.set_content(nlohmann::json{{"error", "busy: " + std::to_string(max_watchers_) +
                                                   " pages are watching (--max-watchers)"}}
                              .dump() +
                          "\n",
                      "application/json");
      return;
    }
    auto last = std::make_shared<std::uint64_t>(0);
    res.set_chunked_content_provider(
        "text/event-stream",
        [this, &service, last](std::size_t, httplib::DataSink& sink) {
          if (stopping_) return false;
          const auto s = service.next_snapshot(*last, kKeepAliveS);
          if (stopping_) return false;
          if (!s) {
            static constexpr char kComment[] = ": keep-alive\n\n";
            return sink.write(kComment, sizeof kComment - 1);
          }
          *last = s->number;
          const std::string event = "data: " + s->json + "\n\n";
          return sink.write(event.data(), event.size());
        },
        [this](bool) { watchers_.fetch_sub(1); });
  });
  server_->Get(".*", forward);
  server_->Post(".*", forward);
  server_->Put(".*", forward);
  server_->Delete(".*", forward);
  server_->Patch(".*", forward);
  server_->Options(".*", forward);
  // httplib's own refusals (a malformed request line, a body beyond the payload limit): a JSON
  // reason, counted as ours are.
  server_->set_error_handler(httplib::Server::HandlerWithResponse([&service](
                                                                      const httplib::Request&,
                                                                      httplib::Response& res) {
    if (!res.body.empty()) return httplib::Server::HandlerResponse::Unhandled;
    service.count_bad_request();
    res.set_content(
        nlohmann::json{{"error", "bad request (HTTP " + std::to_string(res.status) + ")"}}.dump() +
            "\n",
        "application/json");
    return httplib::Server::HandlerResponse::Handled;
  }));
  server_->set_exception_handler(
      [&service](const httplib::Request&, httplib::Response& res, std::exception_ptr) {
        service.count_bad_request();
        res.status = 500;
        res.set_content("{\"error\":\"internal error\"}\n", "application/json");
      });
  server_->listen_after_bind();
}

void PageServer::stop() {
  stopping_ = true;
  server_->stop();
}

}  // namespace nccomp::page
