// cpp-httplib's Server with a front that no slow client can hold: the
// workbench's and /metrics' HTTP server.
//
// httplib gives each accepted connection a thread of its pool for as long as
// it lives, and its read timeout is per read: a client that sends its
// request's head a byte every few seconds holds a thread for ever, and 40 of
// them hold the whole pool (issue 30, item 4). Here the accept loop hands
// each connection to one epoll thread (the front), which gathers the request
// line and headers without a thread per connection, under a deadline for the
// whole head and a cap on the connections waiting for one (and, with TLS,
// does the handshake there too, non-blocking). Only a complete head goes to a
// worker, which runs httplib's process_request over a Stream that serves the
// gathered bytes first and then the socket, with a deadline for each read
// and a least average rate for a body; a kept-alive connection goes back to
// the front between requests rather than holding its worker.
//
// Built on what the Debian package's header declares: Server's
// process_and_close_socket is a private virtual (overriding it is legal C++;
// SSLServer does the same), process_request is protected, and the accept
// loop runs its closure through new_task_queue, which is given a queue that
// runs it inline (so the override is called on the accept thread and only
// passes the socket on).
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <httplib.h>

namespace riccati::service {

struct HardenedOptions {
  int workers = 8;  // threads that run requests (an event stream holds one while it lasts)
  // The request line and headers must all arrive within this (from the
  // connection's accept, or its first byte after a kept-alive request).
  std::chrono::milliseconds head_timeout{10'000};
  // A kept-alive connection may wait this long for its next request's first byte.
  std::chrono::milliseconds keep_alive_idle{5'000};
  // Connections waiting for a head (more are closed at once), at most a
  // quarter of RLIMIT_NOFILE; and of them from one address.
  std::size_t max_waiting = 1024;
  std::size_t max_waiting_per_client = 256;
  std::size_t max_head_bytes = 64 * 1024;  // request line and headers
  // A read of a body that waits this long without a byte fails; and after
  // that long, a body must have come at min_body_rate bytes/s on average.
  std::chrono::milliseconds read_timeout{10'000};
  std::int64_t min_body_rate = 4096;
  std::chrono::milliseconds write_timeout{30'000};  // a write that cannot go on this long fails
  int keep_alive_max = 100;  // requests on one connection
};

class HardenedServer final : public httplib::Server {
 public:
  explicit HardenedServer(HardenedOptions options);
  ~HardenedServer() override;
  HardenedServer(const HardenedServer&) = delete;
  HardenedServer& operator=(const HardenedServer&) = delete;

  // TLS with this certificate chain and key (PEM), and client certificates
  // signed by `client_ca` when it is not empty; before listening. False
  // with the reason in `error`.
  bool use_tls(const std::string& cert, const std::string& key, const std::string& client_ca, std::string* error);
  bool tls() const { return ssl_ctx_ != nullptr; }

  // Binds (port 0: any free one) with a listen backlog of 1024 (httplib's
  // is 5: a burst of connections past it waits for SYN retries, a second
  // and more); the bound port, or -1.
  int bind_port(const std::string& host, int port);

  // Stops accepting (Server::stop), closes the connections waiting for a
  // head, and ends the workers: their reads and writes fail within 100 ms.
  // The caller joins the thread that runs listen_after_bind.
  void shutdown();

  // From a handler or the pre-routing handler: this connection closes after
  // the response (a refusal that left the body unread: what follows on the
  // connection is not a request).
  static void close_after_response();
  // From a handler whose body read failed: why, when it came too slowly
  // ("no byte of the body for 10 s", ...), else empty.
  static const std::string& read_failure();

  // How many connections were closed for a late head, or refused at the caps (for tests and the log).
  std::uint64_t heads_timed_out() const { return heads_timed_out_; }

 private:
  struct Conn;
  class ConnStream;

  bool process_and_close_socket(socket_t sock) override;
  void front_loop();
  void worker_loop();
  void serve(std::unique_ptr<Conn> conn);
  void hand_to_front(std::unique_ptr<Conn> conn);
  void close_conn(std::unique_ptr<Conn> conn, const char* answer = nullptr);

  const HardenedOptions options_;
  std::size_t max_waiting_ = 0;  // options_' caps, within the process's file descriptors
  std::size_t max_waiting_per_client_ = 0;
  struct ssl_ctx_st* ssl_ctx_ = nullptr;
  int epoll_fd_ = -1;
  int wake_fd_ = -1;  // eventfd: conns handed to the front, or shutdown
  std::atomic<bool> stopping_{false};
  std::atomic<std::uint64_t> heads_timed_out_{0};

  std::mutex incoming_mu_;
  std::vector<std::unique_ptr<Conn>> incoming_;  // accepted, or back from a worker

  std::mutex ready_mu_;
  std::condition_variable ready_cv_;
  std::deque<std::unique_ptr<Conn>> ready_;  // a complete head gathered

  std::thread front_;
  std::vector<std::thread> workers_;
};

}  // namespace riccati::service
