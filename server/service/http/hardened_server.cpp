#include "service/http/hardened_server.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <openssl/err.h>
#include <openssl/ssl.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <sys/epoll.h>
#include <sys/eventfd.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <unistd.h>

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <unordered_map>

namespace riccati::service {
namespace {

using Clock = std::chrono::steady_clock;
constexpr std::chrono::milliseconds kSlice{100};  // how often blocked reads and writes look at shutdown
// A refused request's unread body is read and dropped for at most this
// long and this many bytes before its connection closes.
constexpr std::chrono::milliseconds kDrainTime{2000};
constexpr std::size_t kMaxDrained = 4 << 20;

// The accept loop's closure run where it is given: on the accept thread,
// where process_and_close_socket only passes the socket to the front.
class InlineQueue final : public httplib::TaskQueue {
 public:
  void enqueue(std::function<void()> fn) override { fn(); }
  void shutdown() override {}
};

// Our threads never die of SIGPIPE (a client gone while TLS writes to it).
void block_sigpipe() {
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGPIPE);
  pthread_sigmask(SIG_BLOCK, &set, nullptr);
}

std::string peer_address(int fd) {
  sockaddr_storage addr{};
  socklen_t len = sizeof addr;
  if (getpeername(fd, reinterpret_cast<sockaddr*>(&addr), &len) != 0) return {};
  char text[INET6_ADDRSTRLEN] = {};
  if (addr.ss_family == AF_INET) {
    inet_ntop(AF_INET, &reinterpret_cast<sockaddr_in*>(&addr)->sin_addr, text, sizeof text);
  } else if (addr.ss_family == AF_INET6) {
    inet_ntop(AF_INET6, &reinterpret_cast<sockaddr_in6*>(&addr)->sin6_addr, text, sizeof text);
  }
  return text;
}

void address_of(int fd, bool peer, std::string& ip, int& port) {
  sockaddr_storage addr{};
  socklen_t len = sizeof addr;
  const int r = peer ? getpeername(fd, reinterpret_cast<sockaddr*>(&addr), &len)
                     : getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
  if (r != 0) return;
  char text[INET6_ADDRSTRLEN] = {};
  if (addr.ss_family == AF_INET) {
    const auto* a = reinterpret_cast<sockaddr_in*>(&addr);
    inet_ntop(AF_INET, &a->sin_addr, text, sizeof text);
    port = ntohs(a->sin_port);
  } else if (addr.ss_family == AF_INET6) {
    const auto* a = reinterpret_cast<sockaddr_in6*>(&addr);
    inet_ntop(AF_INET6, &a->sin6_addr, text, sizeof text);
    port = ntohs(a->sin6_port);
  }
  ip = text;
}

// Set by serve() around process_request: a handler asks for the connection
// to close after its response.
thread_local bool t_close_after = false;
// Why the last read of a body failed, when it was too slow (else empty).
thread_local std::string t_read_failure;

std::string plain_answer(int status, const char* reason, const std::string& text) {
  return "HTTP/1.1 " + std::to_string(status) + " " + reason +
         "\r\nConnection: close\r\nContent-Type: text/plain\r\nContent-Length: " + std::to_string(text.size() + 1) +
         "\r\n\r\n" + text + "\n";
}

}  // namespace

struct HardenedServer::Conn {
  int fd = -1;
  SSL* ssl = nullptr;
  bool handshaking = false;
  std::string client;     // the peer's address, for the per-client cap
  std::string buffer;     // bytes read; from `consumed` on, not yet given to httplib
  std::size_t consumed = 0;  // (httplib reads a head a byte at a time: no erase per byte)
  std::size_t scanned = 0;  // of buffer, searched for the head's end
  Clock::time_point deadline{};
  bool awaiting_first_byte = false;  // kept alive: the idle wait, then the head's deadline
  bool registered = false;           // in the front's epoll set
  // Refused with its body unread: the response sent and our side shut
  // down, what the client still sends is read and dropped for a while, so
  // that our close does not reset the connection under the response.
  bool draining = false;
  std::size_t drained = 0;
  std::uint32_t events = 0;
  int served = 0;  // requests on this connection

  // The head (request line and headers) is all in the buffer.
  bool head_complete() {
    const std::size_t from = scanned >= 3 ? scanned - 3 : 0;
    const std::size_t at = buffer.find("\r\n\r\n", from);
    scanned = buffer.size();
    return at != std::string::npos;
  }
  void rescan() { scanned = 0; }
};

// What httplib reads a request from and writes its response to: the bytes
// the front gathered, then the socket (non-blocking, waited on with poll in
// slices so that shutdown is seen), plain or TLS.
class HardenedServer::ConnStream final : public httplib::Stream {
 public:
  ConnStream(const HardenedServer& server, Conn& conn) : server_(server), conn_(conn) {}

  bool is_readable() const override {
    if (conn_.consumed < conn_.buffer.size()) return true;
    if (conn_.ssl != nullptr && SSL_pending(conn_.ssl) > 0) return true;
    return wait(POLLIN, Clock::now() + server_.options_.read_timeout);
  }
  bool is_writable() const override {
    return !failed_ && wait(POLLOUT, Clock::now() + server_.options_.write_timeout);
  }

  ssize_t read(char* ptr, std::size_t size) override {
    if (conn_.consumed < conn_.buffer.size()) {
      const std::size_t n = std::min(size, conn_.buffer.size() - conn_.consumed);
      std::memcpy(ptr, conn_.buffer.data() + conn_.consumed, n);
      conn_.consumed += n;
      if (conn_.consumed == conn_.buffer.size()) {
        conn_.buffer.clear();
        conn_.consumed = 0;
      }
      return static_cast<ssize_t>(n);
    }
    if (!body_started_) {
      body_started_ = true;
      body_began_ = last_byte_ = Clock::now();
    }
    for (;;) {
      int want = 0;
      if (conn_.ssl != nullptr) {
        ERR_clear_error();
        const int r = SSL_read(conn_.ssl, ptr, static_cast<int>(std::min<std::size_t>(size, 1 << 30)));
        if (r > 0) return got(r);
        const int e = SSL_get_error(conn_.ssl, r);
        if (e == SSL_ERROR_ZERO_RETURN) return 0;
        if (e == SSL_ERROR_WANT_READ) {
          want = POLLIN;
        } else if (e == SSL_ERROR_WANT_WRITE) {
          want = POLLOUT;
        } else {
          return fail();
        }
      } else {
        const ssize_t r = ::recv(conn_.fd, ptr, size, 0);
        if (r > 0) return got(r);
        if (r == 0) return 0;
        if (errno == EINTR) continue;
        if (errno != EAGAIN && errno != EWOULDBLOCK) return fail();
        want = POLLIN;
      }
      // The next byte's deadline: read_timeout from now, and the body's
      // least average rate after its first read_timeout.
      const auto idle_deadline = Clock::now() + server_.options_.read_timeout;
      const auto rate_deadline =
          body_began_ + server_.options_.read_timeout +
          std::chrono::milliseconds(body_bytes_ * 1000 / std::max<std::int64_t>(1, server_.options_.min_body_rate));
      if (!wait(want, std::min(idle_deadline, rate_deadline))) {
        // Too slow (the answer can still be written), or stopping.
        const double read_s = std::chrono::duration<double>(server_.options_.read_timeout).count();
        t_read_failure = server_.stopping_ ? "riccatid is stopping"
                         : Clock::now() - last_byte_ < server_.options_.read_timeout
                             ? "the body came at under " + std::to_string(server_.options_.min_body_rate) +
                                   " bytes/s after its first " + std::to_string(read_s).substr(0, 4) + " s"
                             : "no byte of the body for " + std::to_string(read_s).substr(0, 4) + " s";
        return -1;
      }
    }
  }

  ssize_t write(const char* ptr, std::size_t size) override {
    if (failed_) return -1;
    note_status(ptr, size);
    const auto deadline = Clock::now() + server_.options_.write_timeout;
    for (;;) {
      int want = 0;
      if (conn_.ssl != nullptr) {
        ERR_clear_error();
        const int r = SSL_write(conn_.ssl, ptr, static_cast<int>(std::min<std::size_t>(size, 1 << 30)));
        if (r > 0) return r;
        const int e = SSL_get_error(conn_.ssl, r);
        if (e == SSL_ERROR_WANT_WRITE) {
          want = POLLOUT;
        } else if (e == SSL_ERROR_WANT_READ) {
          want = POLLIN;
        } else {
          return fail();
        }
      } else {
        const ssize_t r = ::send(conn_.fd, ptr, size, MSG_NOSIGNAL);
        if (r >= 0) return r;
        if (errno == EINTR) continue;
        if (errno != EAGAIN && errno != EWOULDBLOCK) return fail();
        want = POLLOUT;
      }
      if (!wait(want, deadline)) return fail();
    }
  }

  void get_remote_ip_and_port(std::string& ip, int& port) const override { address_of(conn_.fd, true, ip, port); }
  void get_local_ip_and_port(std::string& ip, int& port) const override { address_of(conn_.fd, false, ip, port); }
  socket_t socket() const override { return conn_.fd; }

  bool failed() const { return failed_; }
  int status() const { return status_; }

 private:
  ssize_t got(ssize_t n) {
    body_bytes_ += n;
    last_byte_ = Clock::now();
    return n;
  }
  ssize_t fail() {
    failed_ = true;
    return -1;
  }

  // The response's status, from its status line (a 100 Continue first is
  // passed over).
  void note_status(const char* ptr, std::size_t size) {
    if (status_ != 0 && status_ != 100) return;
    const std::string_view text(ptr, size);
    if (text.rfind("HTTP/1.", 0) != 0 || text.size() < 12) return;
    status_ = std::atoi(std::string(text.substr(9, 3)).c_str());
  }

  // Until `events` on the socket, the deadline, or shutdown.
  bool wait(int events, Clock::time_point deadline) const {
    for (;;) {
      if (server_.stopping_) return false;
      const auto now = Clock::now();
      if (now >= deadline) return false;
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - now) + std::chrono::milliseconds(1);
      pollfd p{conn_.fd, static_cast<short>(events), 0};
      const int r = ::poll(&p, 1, static_cast<int>(std::min(left, kSlice).count()));
      if (r > 0) return (p.revents & (events | POLLHUP | POLLERR)) != 0;
      if (r < 0 && errno != EINTR) return false;
    }
  }

  const HardenedServer& server_;
  Conn& conn_;
  bool failed_ = false;
  int status_ = 0;
  bool body_started_ = false;
  Clock::time_point body_began_{};
  Clock::time_point last_byte_{};
  std::int64_t body_bytes_ = 0;
};

HardenedServer::HardenedServer(HardenedOptions options) : options_(options) {
  // Waiting connections are file descriptors: at most a quarter of the
  // process's, so that a flood of them leaves the store and gRPC theirs.
  max_waiting_ = options_.max_waiting;
  rlimit files{};
  if (::getrlimit(RLIMIT_NOFILE, &files) == 0 && files.rlim_cur != RLIM_INFINITY) {
    max_waiting_ = std::min<std::size_t>(max_waiting_, std::max<std::size_t>(16, files.rlim_cur / 4));
  }
  max_waiting_per_client_ = std::min(options_.max_waiting_per_client, std::max<std::size_t>(1, max_waiting_ / 4));
  new_task_queue = [] { return new InlineQueue; };
  // Never used by the front and workers (they keep their own deadlines),
  // but httplib sets them on each socket it accepts.
  set_read_timeout(options_.read_timeout);
  set_write_timeout(options_.write_timeout);
  set_keep_alive_max_count(static_cast<std::size_t>(options_.keep_alive_max));
  set_keep_alive_timeout(std::max<time_t>(1, std::chrono::duration_cast<std::chrono::seconds>(options_.keep_alive_idle).count()));
  epoll_fd_ = ::epoll_create1(EPOLL_CLOEXEC);
  wake_fd_ = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
  epoll_event ev{};
  ev.events = EPOLLIN;
  ev.data.ptr = nullptr;  // the wake fd
  ::epoll_ctl(epoll_fd_, EPOLL_CTL_ADD, wake_fd_, &ev);
  front_ = std::thread([this] { front_loop(); });
  for (int i = 0; i < std::max(1, options_.workers); ++i) workers_.emplace_back([this] { worker_loop(); });
}

HardenedServer::~HardenedServer() {
  shutdown();
  if (ssl_ctx_ != nullptr) SSL_CTX_free(ssl_ctx_);
  if (epoll_fd_ >= 0) ::close(epoll_fd_);
  if (wake_fd_ >= 0) ::close(wake_fd_);
}

bool HardenedServer::use_tls(const std::string& cert, const std::string& key, const std::string& client_ca,
                             std::string* error) {
  SSL_CTX* ctx = SSL_CTX_new(TLS_server_method());
  if (ctx == nullptr) {
    *error = "cannot create a TLS context";
    return false;
  }
  // As httplib's SSLServer, and no renegotiation (a handshake is CPU that
  // a client could ask for again and again).
  SSL_CTX_set_options(ctx, SSL_OP_NO_COMPRESSION | SSL_OP_NO_SESSION_RESUMPTION_ON_RENEGOTIATION |
                               SSL_OP_NO_RENEGOTIATION);
  SSL_CTX_set_min_proto_version(ctx, TLS1_2_VERSION);
  // Partial writes, and a retried write may come from another address (httplib's buffers move).
  SSL_CTX_set_mode(ctx, SSL_MODE_ENABLE_PARTIAL_WRITE | SSL_MODE_ACCEPT_MOVING_WRITE_BUFFER);
  if (SSL_CTX_use_certificate_chain_file(ctx, cert.c_str()) != 1 ||
      SSL_CTX_use_PrivateKey_file(ctx, key.c_str(), SSL_FILETYPE_PEM) != 1 || SSL_CTX_check_private_key(ctx) != 1) {
    SSL_CTX_free(ctx);
    *error = "cannot use the TLS certificate " + cert + " and key " + key;
    return false;
  }
  if (!client_ca.empty()) {
    if (SSL_CTX_load_verify_locations(ctx, client_ca.c_str(), nullptr) != 1) {
      SSL_CTX_free(ctx);
      *error = "cannot read the client CA " + client_ca;
      return false;
    }
    SSL_CTX_set_verify(ctx, SSL_VERIFY_PEER | SSL_VERIFY_FAIL_IF_NO_PEER_CERT, nullptr);
  }
  ssl_ctx_ = ctx;
  return true;
}

void HardenedServer::close_after_response() { t_close_after = true; }

const std::string& HardenedServer::read_failure() { return t_read_failure; }

int HardenedServer::bind_port(const std::string& host, int port) {
  const int bound = port == 0 ? bind_to_any_port(host) : (bind_to_port(host, port) ? port : -1);
  if (bound >= 0) ::listen(svr_sock_, 1024);  // again, on the bound socket: only the backlog changes
  return bound;
}

// On the accept thread (InlineQueue): the socket goes to the front.
bool HardenedServer::process_and_close_socket(socket_t sock) {
  auto conn = std::make_unique<Conn>();
  conn->fd = sock;
  conn->client = peer_address(sock);
  conn->deadline = Clock::now() + options_.head_timeout;
  ::fcntl(sock, F_SETFL, ::fcntl(sock, F_GETFL) | O_NONBLOCK);
  // httplib writes a response's head and body apart: with Nagle's algorithm
  // the body waits for the client's delayed ACK of the head, 40 ms on every
  // kept-alive request.
  const int one = 1;
  ::setsockopt(sock, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  if (ssl_ctx_ != nullptr) {
    conn->ssl = SSL_new(ssl_ctx_);
    if (conn->ssl == nullptr || SSL_set_fd(conn->ssl, sock) != 1) {
      close_conn(std::move(conn));
      return false;
    }
    SSL_set_accept_state(conn->ssl);
    conn->handshaking = true;
  }
  hand_to_front(std::move(conn));
  return true;
}

void HardenedServer::hand_to_front(std::unique_ptr<Conn> conn) {
  {
    std::lock_guard lock(incoming_mu_);
    if (stopping_) {
      close_conn(std::move(conn));
      return;
    }
    incoming_.push_back(std::move(conn));
  }
  const std::uint64_t one = 1;
  [[maybe_unused]] const auto w = ::write(wake_fd_, &one, sizeof one);
}

void HardenedServer::close_conn(std::unique_ptr<Conn> conn, const char* answer) {
  if (conn == nullptr || conn->fd < 0) return;
  if (answer != nullptr && conn->ssl == nullptr) {
    // Best effort, never waiting: the client may read why.
    [[maybe_unused]] const auto n = ::send(conn->fd, answer, std::strlen(answer), MSG_NOSIGNAL | MSG_DONTWAIT);
  }
  if (conn->ssl != nullptr) {
    if (!conn->handshaking) SSL_shutdown(conn->ssl);  // non-blocking: a close_notify if it goes
    SSL_free(conn->ssl);
    conn->ssl = nullptr;
  }
  ::shutdown(conn->fd, SHUT_RDWR);
  ::close(conn->fd);
  conn->fd = -1;
}

// One thread, every connection that waits for a request's head: the TLS
// handshake and the head's bytes as they come, each connection under its
// deadline; a complete head goes to the workers.
void HardenedServer::front_loop() {
  block_sigpipe();
  std::unordered_map<Conn*, std::unique_ptr<Conn>> waiting;
  std::unordered_map<std::string, std::size_t> per_client;
  const std::string too_slow =
      plain_answer(408, "Request Timeout",
                   "the request line and headers did not all arrive within " +
                       std::to_string(options_.head_timeout.count() / 1000.0).substr(0, 4) +
                       " s (the workbench's head deadline)");
  const std::string too_large = plain_answer(
      431, "Request Header Fields Too Large",
      "the request line and headers are over " + std::to_string(options_.max_head_bytes) + " bytes");
  const std::string too_many = plain_answer(
      503, "Service Unavailable",
      "too many connections wait for their request's headers (at most " + std::to_string(max_waiting_) +
          ", " + std::to_string(max_waiting_per_client_) + " from one address); try again shortly");

  const auto drop = [&](Conn* c, const std::string* answer) {
    auto it = waiting.find(c);
    if (it == waiting.end()) return;
    std::unique_ptr<Conn> conn = std::move(it->second);
    waiting.erase(it);
    if (auto pc = per_client.find(conn->client); pc != per_client.end() && --pc->second == 0) per_client.erase(pc);
    if (conn->registered) ::epoll_ctl(epoll_fd_, EPOLL_CTL_DEL, conn->fd, nullptr);
    close_conn(std::move(conn), answer != nullptr ? answer->c_str() : nullptr);
  };
  const auto ready = [&](Conn* c) {
    auto it = waiting.find(c);
    std::unique_ptr<Conn> conn = std::move(it->second);
    waiting.erase(it);
    if (auto pc = per_client.find(conn->client); pc != per_client.end() && --pc->second == 0) per_client.erase(pc);
    if (conn->registered) ::epoll_ctl(epoll_fd_, EPOLL_CTL_DEL, conn->fd, nullptr);
    conn->registered = false;
    {
      std::lock_guard lock(ready_mu_);
      ready_.push_back(std::move(conn));
    }
    ready_cv_.notify_one();
  };
  const auto watch = [&](Conn* c, std::uint32_t events) {
    if (c->registered && c->events == events) return;
    epoll_event ev{};
    ev.events = events | EPOLLRDHUP;
    ev.data.ptr = c;
    ::epoll_ctl(epoll_fd_, c->registered ? EPOLL_CTL_MOD : EPOLL_CTL_ADD, c->fd, &ev);
    c->registered = true;
    c->events = events;
  };
  // A non-blocking TLS call that could not finish (`result` its return):
  // watch for what it waits for (true), or the connection failed (false).
  const auto tls_waits = [&](Conn* c, int result) -> bool {
    const int e = SSL_get_error(c->ssl, result);
    if (e != SSL_ERROR_WANT_READ && e != SSL_ERROR_WANT_WRITE) return false;
    watch(c, e == SSL_ERROR_WANT_READ ? EPOLLIN : EPOLLOUT);
    return true;
  };
  // Reads what there is; false when the connection is to be dropped.
  const auto progress = [&](Conn* c) -> bool {
    if (c->draining) {
      char sink[16 * 1024];
      for (;;) {
        const ssize_t n = ::recv(c->fd, sink, sizeof sink, 0);
        if (n > 0) {
          c->drained += static_cast<std::size_t>(n);
          if (c->drained > kMaxDrained) return false;
          continue;
        }
        if (n < 0 && errno == EINTR) continue;
        if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
          watch(c, EPOLLIN);
          return true;
        }
        return false;
      }
    }
    if (c->handshaking) {
      ERR_clear_error();
      const int r = SSL_accept(c->ssl);
      if (r != 1) return tls_waits(c, r);
      c->handshaking = false;
    }
    char chunk[16 * 1024];
    for (;;) {
      ssize_t n = 0;
      if (c->ssl != nullptr) {
        ERR_clear_error();
        const int r = SSL_read(c->ssl, chunk, sizeof chunk);
        if (r <= 0) return tls_waits(c, r);
        n = r;
      } else {
        n = ::recv(c->fd, chunk, sizeof chunk, 0);
        if (n == 0) return false;
        if (n < 0) {
          if (errno == EINTR) continue;
          if (errno == EAGAIN || errno == EWOULDBLOCK) {
            watch(c, EPOLLIN);
            return true;
          }
          return false;
        }
      }
      if (c->awaiting_first_byte) {
        c->awaiting_first_byte = false;
        c->deadline = Clock::now() + options_.head_timeout;
      }
      c->buffer.append(chunk, static_cast<std::size_t>(n));
      if (c->head_complete()) {
        ready(c);
        return true;
      }
      if (c->buffer.size() > options_.max_head_bytes) {
        drop(c, &too_large);
        return true;
      }
    }
  };
  const auto admit = [&](std::unique_ptr<Conn> conn) {
    if (conn->fd < 0) return;
    std::size_t& mine = per_client[conn->client];
    if (waiting.size() >= max_waiting_ || mine >= max_waiting_per_client_) {
      if (mine == 0) per_client.erase(conn->client);
      ++heads_timed_out_;
      spdlog::warn("http connection refused client={} waiting={}: at the cap on connections waiting for a head",
                   conn->client, waiting.size());
      close_conn(std::move(conn), too_many.c_str());
      return;
    }
    ++mine;
    Conn* c = conn.get();
    waiting.emplace(c, std::move(conn));
    if (!c->buffer.empty() && c->head_complete()) return ready(c);
    if (!progress(c)) drop(c, nullptr);
  };

  epoll_event events[64];
  auto next_sweep = Clock::now() + kSlice;
  while (!stopping_) {
    const int n = ::epoll_wait(epoll_fd_, events, 64, static_cast<int>(kSlice.count()));
    for (int i = 0; i < n; ++i) {
      if (events[i].data.ptr == nullptr) {
        std::uint64_t count = 0;
        [[maybe_unused]] const auto r = ::read(wake_fd_, &count, sizeof count);
        std::vector<std::unique_ptr<Conn>> taken;
        {
          std::lock_guard lock(incoming_mu_);
          taken.swap(incoming_);
        }
        for (auto& conn : taken) admit(std::move(conn));
        continue;
      }
      Conn* c = static_cast<Conn*>(events[i].data.ptr);
      if (waiting.count(c) == 0) continue;  // dropped or handed on by an earlier event of this batch
      if (!progress(c)) drop(c, nullptr);
    }
    const auto now = Clock::now();
    if (now >= next_sweep) {
      next_sweep = now + kSlice;
      std::vector<Conn*> late;
      for (const auto& [c, conn] : waiting) {
        if (now >= c->deadline) late.push_back(c);
      }
      for (Conn* c : late) {
        // A kept-alive connection that stayed idle, or one drained, just closes.
        const bool idle = c->awaiting_first_byte || c->draining;
        if (!idle) ++heads_timed_out_;
        drop(c, idle ? nullptr : &too_slow);
      }
      if (!late.empty()) spdlog::debug("http connections closed at their head deadline count={}", late.size());
    }
  }
  for (auto& [c, conn] : waiting) close_conn(std::move(conn));
  waiting.clear();
}

void HardenedServer::worker_loop() {
  block_sigpipe();
  for (;;) {
    std::unique_ptr<Conn> conn;
    {
      std::unique_lock lock(ready_mu_);
      ready_cv_.wait(lock, [&] { return stopping_ || !ready_.empty(); });
      if (stopping_) return;
      conn = std::move(ready_.front());
      ready_.pop_front();
    }
    serve(std::move(conn));
  }
}

// Requests on one connection while their heads are here; then the
// connection goes back to the front, or closes.
void HardenedServer::serve(std::unique_ptr<Conn> conn) {
  for (;;) {
    ConnStream stream(*this, *conn);
    const bool last = ++conn->served >= options_.keep_alive_max || stopping_;
    bool connection_closed = false;
    bool has_body = false;
    t_close_after = false;
    t_read_failure.clear();
    const bool ok = process_request(stream, last, connection_closed, [&](httplib::Request& req) {
      // More than one range is ignored (RFC 9110 allows it): httplib would
      // build the whole multipart answer in memory, a copy per range
      // ("bytes=0-,0-,..." 2600 times in 7.8 KB: 378 MB for a 145 KB file).
      if (req.ranges.size() > 1) req.ranges.clear();
      has_body = req.has_header("Transfer-Encoding") ||
                 (req.has_header("Content-Length") && req.get_header_value("Content-Length") != "0");
    });
    // A refused request with a body may have left it unread: what follows
    // is not a request.
    const bool refused = t_close_after || (has_body && stream.status() >= 400);
    const bool close = !ok || connection_closed || last || refused || stream.failed() || stopping_;
    t_close_after = false;
    if (close && refused && ok && !stream.failed() && !stopping_ && conn->ssl == nullptr) {
      // The client may still be sending the body: let it, for a while, before the close.
      ::shutdown(conn->fd, SHUT_WR);
      conn->draining = true;
      conn->buffer.clear();
      conn->consumed = 0;
      conn->deadline = Clock::now() + kDrainTime;
      return hand_to_front(std::move(conn));
    }
    if (close) return close_conn(std::move(conn));
    conn->buffer.erase(0, conn->consumed);  // what is left: the start of the next request
    conn->consumed = 0;
    conn->rescan();
    if (!conn->buffer.empty() && conn->head_complete()) continue;  // pipelined: the next head is here
    conn->awaiting_first_byte = conn->buffer.empty();
    conn->deadline = Clock::now() + (conn->awaiting_first_byte ? options_.keep_alive_idle : options_.head_timeout);
    return hand_to_front(std::move(conn));
  }
}

void HardenedServer::shutdown() {
  if (stopping_.exchange(true)) return;
  stop();  // the accept loop ends
  {
    std::lock_guard lock(incoming_mu_);
    for (auto& conn : incoming_) close_conn(std::move(conn));
    incoming_.clear();
  }
  const std::uint64_t one = 1;
  [[maybe_unused]] const auto w = ::write(wake_fd_, &one, sizeof one);
  { std::lock_guard lock(ready_mu_); }  // a worker between its check and its wait sees stopping_
  ready_cv_.notify_all();
  if (front_.joinable()) front_.join();
  for (auto& worker : workers_) {
    if (worker.joinable()) worker.join();
  }
  std::lock_guard lock(ready_mu_);
  for (auto& conn : ready_) close_conn(std::move(conn));
  ready_.clear();
}

}  // namespace riccati::service
