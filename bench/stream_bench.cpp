// stream_bench: a load generator for filter sessions, run side by side with a
// bare gRPC echo service that answers the same messages without estimating.
//
//   build/bin/stream_bench                                    # the standard scenarios
//   build/bin/stream_bench --model manipulator --sessions 50 --rate 400 --seconds 10
//   build/bin/stream_bench --model manipulator --rate 400 --find-max
//
// Both servers run in this process on loopback ports: riccatid's Daemon
// (SQLite in a temporary directory, the built-in plugins) and the echo, both
// on gRPC's callback API. The client side is the callback API too, so that a
// few threads drive hundreds of sessions: one reactor per session and, for
// paced runs, one pacing thread that queues each session's next message at
// its scheduled time. Paced runs are open loop: a late answer does not delay
// the next message, so queueing shows in the latency instead of hiding in a
// slower send rate. A round trip is the time from a message's scheduled send
// to its answer; the first second (--warmup) is not recorded.
//
// Workloads: `two_tank` (EKF, RK4 with 10 substeps, two_tank.csv) and
// `manipulator` (the optimal filter with the weights of case C,
// flexible_manipulator.csv at its 400 Hz). The echo answers each
// measurement with a copy of the estimate riccati gives for the workload, so
// both move the same bytes.
#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <mutex>
#include <thread>
#include <vector>

#include "engine/data/dataset.hpp"
#include "riccati/v1/sessions.grpc.pb.h"
#include "service/daemon.hpp"
#include "support/requests.hpp"

namespace {

using namespace riccati;
using Clock = std::chrono::steady_clock;

// What the sessions estimate and the data they replay.
struct Workload {
  std::string name;
  v1::CreateSessionRequest session;
  Dataset data;
  double lap_seconds = 0.0;  // added to the time stamps each time the data wraps around

  // Appends sample `index` (counted from the start, across laps) to the request.
  void add(v1::StreamRequest& request, std::int64_t index) const {
    const Eigen::Index k = static_cast<Eigen::Index>(index % data.size());
    const double lap = static_cast<double>(index / data.size());
    testing::add_sample(request, data, k, data.t[k] + lap * lap_seconds);
  }
};

Workload make_workload(const std::string& name) {
  Workload w;
  w.name = name;
  if (name == "two_tank") {
    w.session = testing::two_tank_session();
    w.data = read_csv_file(RICCATI_TEST_DATA_DIR "/two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}}).value();
  } else {
    w.session = testing::manipulator_case_c_session();
    w.data = read_csv_file(RICCATI_TEST_DATA_DIR "/flexible_manipulator.csv", ColumnMapping{"t", {"T"}, {"s1", "s2"}})
                 .value();
  }
  const Eigen::Index n = w.data.size();
  w.lap_seconds = w.data.t[n - 1] - w.data.t[0] + (w.data.t[n - 1] - w.data.t[0]) / static_cast<double>(n - 1);
  return w;
}

// The echo: reads a batch, answers each measurement with the template
// estimate (its time set), computing nothing; one message in flight, as
// riccatid's own stream.
class EchoStream final : public grpc::ServerBidiReactor<v1::StreamRequest, v1::StreamResponse> {
 public:
  explicit EchoStream(const v1::Estimate& estimate) : estimate_(estimate) { StartRead(&request_); }
  void OnReadDone(bool ok) override {
    if (!ok) return Finish(grpc::Status::OK);
    if (request_.has_open()) return StartRead(&request_);
    response_.Clear();
    for (const auto& m : request_.batch().measurements()) {
      auto* r = response_.add_results();
      r->set_sequence(sequence_++);
      *r->mutable_estimate() = estimate_;
      r->mutable_estimate()->set_t(m.t());
    }
    StartWrite(&response_);
  }
  void OnWriteDone(bool ok) override {
    if (!ok) return Finish(grpc::Status::OK);
    StartRead(&request_);
  }
  void OnDone() override { delete this; }

 private:
  const v1::Estimate& estimate_;
  v1::StreamRequest request_;
  v1::StreamResponse response_;
  std::uint64_t sequence_ = 0;
};

class EchoSessions final : public v1::SessionService::CallbackService {
 public:
  void set_estimate(v1::Estimate estimate) { estimate_ = std::move(estimate); }
  grpc::ServerUnaryReactor* CreateSession(grpc::CallbackServerContext* context, const v1::CreateSessionRequest*,
                                          v1::SessionInfo* info) override {
    info->set_id("echo");
    auto* reactor = context->DefaultReactor();
    reactor->Finish(grpc::Status::OK);
    return reactor;
  }
  grpc::ServerUnaryReactor* CloseSession(grpc::CallbackServerContext* context, const v1::CloseSessionRequest*,
                                         v1::CloseSessionResponse*) override {
    auto* reactor = context->DefaultReactor();
    reactor->Finish(grpc::Status::OK);
    return reactor;
  }
  grpc::ServerBidiReactor<v1::StreamRequest, v1::StreamResponse>* Stream(grpc::CallbackServerContext*) override {
    return new EchoStream(estimate_);
  }

 private:
  v1::Estimate estimate_;
};

struct Scenario {
  int sessions = 1;
  double rate = 0.0;  // measurements per second per session; 0 = as fast as answers come (closed loop)
  int batch = 1;
  int window = 1;     // closed loop: messages in flight per session (1 = ping-pong)
  double seconds = 5.0;
  double warmup = 1.0;
};

struct Figures {
  std::vector<double> round_trips_us;
  std::uint64_t measurements = 0;  // estimates received for messages in the recorded window
  std::uint64_t errors = 0;        // measurement errors and streams that ended badly
  double seconds = 0.0;            // the recorded window
  double percentile(double p) const {
    if (round_trips_us.empty()) return 0.0;
    std::vector<double> v = round_trips_us;
    const std::size_t k = std::min(v.size() - 1, static_cast<std::size_t>(p * static_cast<double>(v.size() - 1) + 0.5));
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
    return v[k];
  }
  double rate() const { return seconds > 0 ? static_cast<double>(measurements) / seconds : 0.0; }
};

// One session's stream. Messages are queued by send() (the pacer's thread,
// or this reactor's own OnReadDone in closed loop) and written one at a time;
// answers come in order, one per message, so the oldest scheduled time is
// the one an answer belongs to.
class SessionClient final : public grpc::ClientBidiReactor<v1::StreamRequest, v1::StreamResponse> {
 public:
  SessionClient(const Workload& workload, const Scenario& scenario, Clock::time_point record_from,
                Clock::time_point record_until)
      : workload_(workload), scenario_(scenario), record_from_(record_from), record_until_(record_until) {}

  void start(v1::SessionService::Stub& stub, const std::string& session_id) {
    stub.async()->Stream(&context_, this);
    current_.mutable_open()->set_session_id(session_id);
    writing_ = true;
    AddHold();  // released by finish(): the pacer writes from outside the reactions
    StartWrite(&current_);
    StartRead(&response_);
    StartCall();
    if (scenario_.rate <= 0) {
      for (int i = 0; i < scenario_.window; ++i) send(Clock::now());
    }
  }

  // Queues the next message, due at `when`.
  void send(Clock::time_point when) {
    {
      std::lock_guard lock(mu_);
      if (closing_) return;
      v1::StreamRequest& request = queue_.emplace_back();
      for (int b = 0; b < scenario_.batch; ++b) workload_.add(request, next_sample_++);
      scheduled_.push_back(when);
      if (writing_) return;
      writing_ = true;
      current_ = std::move(queue_.front());
      queue_.pop_front();
    }
    StartWrite(&current_);
  }

  // No more messages: the stream ends when the queue is written.
  void finish() {
    bool close_now = false;
    {
      std::lock_guard lock(mu_);
      closing_ = true;
      close_now = !writing_ && !writes_done_;
      writes_done_ = writes_done_ || close_now;
    }
    if (close_now) close();
  }

  void cancel() { context_.TryCancel(); }

  // True once the stream has ended (OnDone), false at `deadline` if not.
  bool wait_until(Clock::time_point deadline) {
    std::unique_lock lock(mu_);
    return done_cv_.wait_until(lock, deadline, [&] { return done_; });
  }

  // Call after wait().
  void add_to(Figures& figures) const {
    figures.round_trips_us.insert(figures.round_trips_us.end(), trips_us_.begin(), trips_us_.end());
    figures.measurements += measurements_;
    figures.errors += errors_ + (status_.ok() ? 0 : 1);
  }
  const grpc::Status& status() const { return status_; }

  void OnWriteDone(bool ok) override {
    bool write_next = false, close_now = false;
    {
      std::lock_guard lock(mu_);
      if (ok && !queue_.empty()) {
        current_ = std::move(queue_.front());
        queue_.pop_front();
        write_next = true;
      } else {
        writing_ = false;
        if (!ok) closing_ = true;
        close_now = closing_ && !writes_done_;
        writes_done_ = writes_done_ || close_now;
      }
    }
    if (write_next) return StartWrite(&current_);
    if (close_now) close();
  }

  void OnReadDone(bool ok) override {
    if (!ok) return;  // the stream ended: OnDone follows
    const Clock::time_point now = Clock::now();
    bool more = false;
    {
      std::lock_guard lock(mu_);
      const Clock::time_point due = scheduled_.front();
      scheduled_.pop_front();
      if (due >= record_from_ && due < record_until_) {
        trips_us_.push_back(std::chrono::duration<double, std::micro>(now - due).count());
        for (const auto& r : response_.results()) {
          if (r.has_estimate()) ++measurements_;
          else ++errors_;
        }
      }
      more = scenario_.rate <= 0 && !closing_;
    }
    if (more) send(now);
    StartRead(&response_);
  }

  void OnDone(const grpc::Status& status) override {
    std::lock_guard lock(mu_);
    status_ = status;
    done_ = true;
    done_cv_.notify_all();
  }

 private:
  void close() {
    StartWritesDone();
    RemoveHold();
  }

  const Workload& workload_;
  const Scenario& scenario_;
  const Clock::time_point record_from_, record_until_;
  grpc::ClientContext context_;
  std::mutex mu_;
  std::condition_variable done_cv_;
  std::deque<v1::StreamRequest> queue_;         // waiting for the write in flight
  std::deque<Clock::time_point> scheduled_;     // due times of the messages not yet answered
  v1::StreamRequest current_;                   // the write in flight
  v1::StreamResponse response_;
  std::int64_t next_sample_ = 0;
  bool writing_ = false, closing_ = false, writes_done_ = false, done_ = false;
  std::vector<double> trips_us_;
  std::uint64_t measurements_ = 0, errors_ = 0;
  grpc::Status status_;
};

// Sends every session's messages at `rate`, the sessions' schedules spread
// evenly over one period so that they do not all arrive at once.
void pace(std::vector<std::unique_ptr<SessionClient>>& clients, const Scenario& sc, Clock::time_point start,
          Clock::time_point end) {
  const auto period = std::chrono::duration<double>(sc.batch / sc.rate);
  const auto slot = std::chrono::duration_cast<Clock::duration>(period / static_cast<double>(clients.size()));
  Clock::time_point due = start;
  for (std::size_t i = 0; due < end; ++i, due += slot) {
    if (Clock::now() < due) std::this_thread::sleep_until(due);
    clients[i % clients.size()]->send(due);
  }
}

Figures run(const std::string& address, const Workload& workload, const Scenario& sc) {
  // One channel (connection) per 32 sessions; gRPC multiplexes streams over each.
  std::vector<std::shared_ptr<grpc::Channel>> channels;
  std::vector<std::unique_ptr<v1::SessionService::Stub>> stubs;
  for (int c = 0; c < (sc.sessions + 31) / 32; ++c) {
    grpc::ChannelArguments args;
    args.SetInt("grpc.channel_id", c);  // distinct channels, not one shared subchannel
    channels.push_back(grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), args));
    stubs.push_back(v1::SessionService::NewStub(channels.back()));
  }
  std::vector<std::string> ids;
  Figures figures;
  for (int s = 0; s < sc.sessions; ++s) {
    grpc::ClientContext ctx;
    v1::SessionInfo info;
    const grpc::Status created = stubs[s / 32]->CreateSession(&ctx, workload.session, &info);
    if (!created.ok()) {
      std::fprintf(stderr, "stream_bench: CreateSession: %s\n", created.error_message().c_str());
      ++figures.errors;
      return figures;
    }
    ids.push_back(info.id());
  }

  const auto start = Clock::now() + std::chrono::milliseconds(50);
  const auto record_from = start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(sc.warmup));
  const auto end = start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(sc.seconds));
  std::vector<std::unique_ptr<SessionClient>> clients;
  for (int s = 0; s < sc.sessions; ++s) {
    clients.push_back(std::make_unique<SessionClient>(workload, sc, record_from, end));
    clients.back()->start(*stubs[s / 32], ids[s]);
  }
  if (sc.rate > 0) {
    pace(clients, sc, start, end);
  } else {
    std::this_thread::sleep_until(end);
  }
  for (auto& c : clients) c->finish();
  // What is still queued is answered; a server that cannot is cut off.
  const auto give_up = Clock::now() + std::chrono::seconds(30);
  bool all_done = true;
  for (auto& c : clients) all_done = c->wait_until(give_up) && all_done;
  if (!all_done) {
    for (auto& c : clients) c->cancel();
    for (auto& c : clients) c->wait_until(Clock::time_point::max());
  }
  bool told = false;
  for (const auto& c : clients) {
    c->add_to(figures);
    if (!c->status().ok() && !told) {
      std::fprintf(stderr, "stream_bench: a stream ended with %d: %s\n", c->status().error_code(),
                   c->status().error_message().c_str());
      told = true;
    }
  }
  figures.seconds = std::chrono::duration<double>(end - record_from).count();
  for (std::size_t s = 0; s < ids.size(); ++s) {
    grpc::ClientContext ctx;
    v1::CloseSessionRequest close;
    close.set_id(ids[s]);
    v1::CloseSessionResponse closed;
    (void)stubs[s / 32]->CloseSession(&ctx, close, &closed);
  }
  return figures;
}

// The first estimate riccati gives for the workload: the echo's answer.
v1::Estimate first_estimate(const std::string& address, const Workload& workload) {
  auto stub = v1::SessionService::NewStub(grpc::CreateChannel(address, grpc::InsecureChannelCredentials()));
  grpc::ClientContext create_ctx;
  v1::SessionInfo info;
  if (!stub->CreateSession(&create_ctx, workload.session, &info).ok()) return {};
  grpc::ClientContext ctx;
  auto stream = stub->Stream(&ctx);
  v1::StreamRequest request;
  request.mutable_open()->set_session_id(info.id());
  stream->Write(request);
  request.Clear();
  workload.add(request, 0);
  stream->Write(request);
  v1::StreamResponse response;
  stream->Read(&response);
  stream->WritesDone();
  (void)stream->Finish();
  grpc::ClientContext close_ctx;
  v1::CloseSessionRequest close;
  close.set_id(info.id());
  v1::CloseSessionResponse closed;
  (void)stub->CloseSession(&close_ctx, close, &closed);
  return response.results_size() > 0 ? response.results(0).estimate() : v1::Estimate{};
}

std::string describe(const Scenario& sc) {
  char text[160];
  if (sc.rate > 0) {
    std::snprintf(text, sizeof text, "%d session(s) at %.0f Hz, batch %d, %.0f s (%.0f recorded)", sc.sessions, sc.rate,
                  sc.batch, sc.seconds, sc.seconds - sc.warmup);
  } else {
    std::snprintf(text, sizeof text, "%d session(s) as fast as answers come, batch %d, %d in flight, %.0f s", sc.sessions,
                  sc.batch, sc.window, sc.seconds);
  }
  return text;
}

void print_header() {
  std::printf("  %-8s %12s %12s %10s %10s %10s %8s\n", "", "offered/s", "meas/s", "p50 us", "p99 us", "max us",
              "errors");
}

void print_row(const char* who, const Scenario& sc, const Figures& f) {
  const double offered = sc.rate > 0 ? sc.rate * sc.sessions : 0.0;
  std::printf("  %-8s %12.0f %12.0f %10.1f %10.1f %10.1f %8llu\n", who, offered, f.rate(), f.percentile(0.5),
              f.percentile(0.99), f.percentile(1.0), static_cast<unsigned long long>(f.errors));
}

// Sustained: every measurement offered answered, without error, p99 within one sample period.
bool sustained(const Scenario& sc, const Figures& f) {
  const double offered = sc.rate * sc.sessions;
  return f.errors == 0 && f.rate() >= 0.99 * offered && f.percentile(0.99) < 1e6 / sc.rate;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"stream_bench: filter sessions under load, beside a bare gRPC echo"};
  Scenario custom;
  std::string model = "two_tank";
  bool find_max = false, no_echo = false;
  int max_sessions = 1000;
  const std::vector<CLI::Option*> options = {
      app.add_option("--sessions", custom.sessions, "Concurrent sessions"),
      app.add_option("--rate", custom.rate, "Measurements per second per session (0: closed loop, as fast as answers come)"),
      app.add_option("--batch", custom.batch, "Measurements per message"),
      app.add_option("--window", custom.window, "Closed loop: messages in flight per session (1: ping-pong)"),
      app.add_option("--seconds", custom.seconds, "Duration of each run, warm-up included"),
      app.add_option("--warmup", custom.warmup, "Seconds at the start of each run that are not recorded"),
      app.add_option("--model", model, "Workload: two_tank (EKF) or manipulator (optimal filter, case C)")
          ->check(CLI::IsMember({"two_tank", "manipulator"})),
      app.add_flag("--find-max", find_max,
                   "Raise the session count until a paced run is no longer sustained (all answered, no error, "
                   "p99 under one sample period); needs --rate"),
      app.add_option("--max-sessions", max_sessions, "--find-max: stop there"),
      app.add_flag("--no-echo", no_echo, "Leave out the echo runs")};
  CLI11_PARSE(app, argc, argv);
  const bool custom_given = std::any_of(options.begin(), options.end(), [](CLI::Option* o) { return o->count() > 0; });
  if (find_max && custom.rate <= 0) {
    std::fprintf(stderr, "stream_bench: --find-max needs --rate\n");
    return 2;
  }

  const std::string data_dir =
      (std::filesystem::temp_directory_path() / ("riccati-bench-" + std::to_string(::getpid()))).string();
  service::DaemonConfig config;
  config.listen = "127.0.0.1:0";
  config.data_dir = data_dir;
  config.models_dir = RICCATI_TEST_PLUGIN_DIR;
  config.log_level = "warn";
  config.limits.max_sessions = config.limits.max_tenant_sessions = 100'000;
  spdlog::set_level(spdlog::level::warn);
  service::Daemon daemon(config);
  if (auto s = daemon.start(); !s.is_ok()) {
    std::fprintf(stderr, "stream_bench: %s\n", s.message().c_str());
    return 1;
  }
  EchoSessions echo_service;
  int echo_port = 0;
  grpc::ServerBuilder builder;
  builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &echo_port);
  builder.RegisterService(&echo_service);
  auto echo = builder.BuildAndStart();
  const std::string riccati_address = "127.0.0.1:" + std::to_string(daemon.port());
  const std::string echo_address = "127.0.0.1:" + std::to_string(echo_port);

  std::vector<std::tuple<std::string, std::string, Scenario>> scenarios;  // title, model, scenario
  if (custom_given) {
    scenarios.emplace_back("custom", model, custom);
  } else {
    scenarios.emplace_back("single-measurement round trip", "two_tank", Scenario{1, 0.0, 1, 1, 4.0, 1.0});
    scenarios.emplace_back("batches of 64, ping-pong", "two_tank", Scenario{1, 0.0, 64, 1, 4.0, 1.0});
    scenarios.emplace_back("batches of 64, pipelined", "two_tank", Scenario{1, 0.0, 64, 8, 4.0, 1.0});
    scenarios.emplace_back("manipulator sessions at 400 Hz", "manipulator", Scenario{50, 400.0, 1, 1, 6.0, 1.0});
  }
  for (const auto& [title, model_name, sc] : scenarios) {
    const Workload workload = make_workload(model_name);
    echo_service.set_estimate(first_estimate(riccati_address, workload));
    if (find_max) {
      std::printf("\n%s: find the most %s sessions at %.0f Hz with p99 under %.0f us\n", title.c_str(),
                  model_name.c_str(), sc.rate, 1e6 / sc.rate);
      print_header();
      int best = 0;
      for (int n : {10, 20, 40, 60, 80, 100, 120, 140, 160, 200, 240, 280, 320, 400, 500, 600, 800, 1000}) {
        if (n > max_sessions) break;
        Scenario level = sc;
        level.sessions = n;
        const Figures r = run(riccati_address, workload, level);
        char who[32];
        std::snprintf(who, sizeof who, "%d", n);
        print_row(who, level, r);
        std::fflush(stdout);
        if (!sustained(level, r)) break;
        best = n;
      }
      std::printf("  sustained: %d sessions (%.0f measurements/s)\n", best, best * sc.rate);
      if (!no_echo && best > 0) {
        Scenario level = sc;
        level.sessions = best;
        std::printf("  the echo at %d sessions:\n", best);
        print_row("echo", level, run(echo_address, workload, level));
      }
      continue;
    }
    std::printf("\n%s (%s): %s\n", title.c_str(), model_name.c_str(), describe(sc).c_str());
    print_header();
    const Figures r = run(riccati_address, workload, sc);
    print_row("riccati", sc, r);
    if (!no_echo) {
      const Figures e = run(echo_address, workload, sc);
      print_row("echo", sc, e);
      std::printf("  ratio riccati/echo: throughput %.2f, p50 %.2f, p99 %.2f\n", r.rate() / e.rate(),
                  r.percentile(0.5) / e.percentile(0.5), r.percentile(0.99) / e.percentile(0.99));
    }
    if (sc.rate > 0) std::printf("  sustained (p99 < %.0f us, all answered): %s\n", 1e6 / sc.rate, sustained(sc, r) ? "yes" : "no");
  }
  echo->Shutdown();
  daemon.shutdown(std::chrono::milliseconds(100));
  std::filesystem::remove_all(data_dir);
  return 0;
}
