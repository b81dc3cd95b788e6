// nccomp-page's HTTP server: cpp-httplib (Debian's libcpp-httplib) in front of PageService.
// Every route goes to PageService::handle() but /events, the server-sent events stream of
// status snapshots. Not real-time.
#pragma once

#include <atomic>
#include <memory>
#include <string>

#include "tools/page/page_service.hpp"

namespace httplib {
class Server;
}

namespace nccomp::page {

class PageServer {
 public:
  /// max_watchers: pages watching /events at once (each holds a server thread); one more is
  /// answered 503.
  explicit PageServer(int max_watchers);
  ~PageServer();
  PageServer(const PageServer&) = delete;
  PageServer& operator=(const PageServer&) = delete;

  /// Binds host (an IPv4 address) and port (0: a free port); returns the port. Throws
  /// std::runtime_error naming the address when it cannot.
  int bind(const std::string& host, int port);

  /// Serves service until stop(); blocks.
  void serve(PageService& service);

  /// Ends serve() (any thread).
  void stop();

 private:
  std::unique_ptr<httplib::Server> server_;
  int max_watchers_;
  std::atomic<int> watchers_{0};
  std::atomic<bool> stopping_{false};
};

}  // namespace nccomp::page
