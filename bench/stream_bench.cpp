// stream_bench: a load generator for filter sessions, run against riccatid
// and, side by side, a bare gRPC echo service (stream_echo) that answers the
// same messages without estimating.
//
//   build/bin/stream_bench                                    # the standard scenarios
//   build/bin/stream_bench --model manipulator --sessions 40 --rate 400 --seconds 60
//   build/bin/stream_bench --model manipulator --rate 400 --find-max
//   build/bin/stream_bench --model manipulator --sessions 20 --rate 400 --idle 10000
//   build/bin/stream_bench --baseline path/to/an/older/riccatid   # before and after, in one run
//   build/bin/stream_bench --model manipulator --rate 400 --find-max --server-cpus 1   # servers on one core
//
// riccatid (SQLite in a temporary directory, the built-in plugins, session
// snapshots every second as in production, limits raised for the bench) and
// the echo run as processes of their own on loopback ports; this process is
// only the load generator, and reports its own CPU (getrusage) beside the
// server's (/proc/<pid>/stat) for the recorded window. The client side is
// gRPC's callback API, so that a few threads drive hundreds of sessions: one
// reactor per session and, for paced runs, one pacing thread that queues
// each session's next message at its scheduled time. Paced runs are open
// loop: a late answer does not delay the next message, so queueing shows in
// the latency instead of hiding in a slower send rate. A round trip is the
// time from a message's scheduled send to its answer; the first second
// (--warmup) is not recorded. A stall is a stretch of time in which answers
// came more than 10 ms late (overlapping late answers of any session are one
// stall); those during which the pacer itself kept its schedule are counted
// apart (on a shared machine the generator is descheduled too).
//
// Workloads: `two_tank` (EKF, RK4 with 10 substeps, two_tank.csv) and
// `manipulator` (the optimal filter with the weights of case C,
// flexible_manipulator.csv at its 400 Hz). The echo answers each
// measurement with a copy of the estimate riccati gives for the workload, so
// both move the same bytes.
#include <CLI/CLI.hpp>
#include <absl/synchronization/mutex.h>
#include <grpcpp/grpcpp.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <thread>
#include <vector>

#include "bench_process.hpp"
#include "engine/data/dataset.hpp"
#include "engine/estimation/online_runner.hpp"
#include "engine/models/plugin_loader.hpp"
#include "hand_written_two_tank_ekf.hpp"
#include "riccati/v1/sessions.grpc.pb.h"
#include "service/run_settings.hpp"
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

struct Scenario {
  int sessions = 1;
  double rate = 0.0;  // measurements per second per session; 0 = as fast as answers come (closed loop)
  int batch = 1;
  int window = 1;     // closed loop: messages in flight per session (1 = ping-pong)
  double seconds = 5.0;
  double warmup = 1.0;
};

// A server under load: its address and, for a child process, its CPU.
struct Server {
  std::string name;
  const bench::ServerProcess* process;
};

constexpr double kStallUs = 10'000;  // an answer this late is part of a stall

struct Figures {
  std::vector<double> round_trips_us;
  std::vector<std::pair<double, double>> late;  // (due, answered) in us from the start, of answers later than kStallUs
  std::uint64_t measurements = 0;  // estimates received for messages in the recorded window
  std::uint64_t errors = 0;        // measurement errors and streams that ended badly
  double seconds = 0.0;            // the recorded window
  double client_cpu_s = 0.0;       // this process's CPU over the recorded window
  double server_cpu_s = 0.0;       // the server's
  double pacer_behind_us = 0.0;    // paced runs: the longest the pacer was late sending
  std::vector<std::pair<double, double>> pacer_late;  // (due, sent) in us from the start, of sends over 1 ms late
  double percentile(double p) const {
    if (round_trips_us.empty()) return 0.0;
    std::vector<double> v = round_trips_us;
    const std::size_t k = std::min(v.size() - 1, static_cast<std::size_t>(p * static_cast<double>(v.size() - 1) + 0.5));
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
    return v[k];
  }
  double rate() const { return seconds > 0 ? static_cast<double>(measurements) / seconds : 0.0; }
  // Stretches of time with late answers: overlapping ones are one stall.
  std::vector<std::pair<double, double>> stall_spans() const {
    std::vector<std::pair<double, double>> spans = late, merged;
    std::sort(spans.begin(), spans.end());
    for (const auto& [from, to] : spans) {
      if (merged.empty() || from > merged.back().second) {
        merged.emplace_back(from, to);
      } else {
        merged.back().second = std::max(merged.back().second, to);
      }
    }
    return merged;
  }
  int stalls() const { return static_cast<int>(stall_spans().size()); }
  // Stalls during which the pacer kept its schedule (never more than
  // kStallUs / 2 late from a little before the stall to its end): the load
  // generator was running, so these are more likely the server's.
  int stalls_pacer_on_time() const {
    int count = 0;
    for (const auto& [from, to] : stall_spans()) {
      const bool generator_late = std::any_of(pacer_late.begin(), pacer_late.end(), [&](const auto& p) {
        return p.first <= to && p.second >= from - kStallUs && p.second - p.first > kStallUs / 2;
      });
      if (!generator_late) ++count;
    }
    return count;
  }
  // CPU microseconds per measurement answered.
  double client_us() const { return measurements > 0 ? 1e6 * client_cpu_s / static_cast<double>(measurements) : 0.0; }
  double server_us() const { return measurements > 0 ? 1e6 * server_cpu_s / static_cast<double>(measurements) : 0.0; }
};

// One session's stream. Messages are queued by send() (the pacer's thread,
// or this reactor's own OnReadDone in closed loop) and written one at a time;
// answers come in order, one per message, so the oldest scheduled time is
// the one an answer belongs to.
class SessionClient final : public grpc::ClientBidiReactor<v1::StreamRequest, v1::StreamResponse> {
 public:
  SessionClient(const Workload& workload, const Scenario& scenario, Clock::time_point start,
                Clock::time_point record_from, Clock::time_point record_until)
      : workload_(workload),
        scenario_(scenario),
        start_(start),
        record_from_(record_from),
        record_until_(record_until) {}

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
    figures.late.insert(figures.late.end(), late_.begin(), late_.end());
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
        const double trip_us = std::chrono::duration<double, std::micro>(now - due).count();
        trips_us_.push_back(trip_us);
        if (trip_us > kStallUs) {
          const double due_us = std::chrono::duration<double, std::micro>(due - start_).count();
          late_.emplace_back(due_us, due_us + trip_us);
        }
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
  const Clock::time_point start_, record_from_, record_until_;
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
  std::vector<std::pair<double, double>> late_;
  std::uint64_t measurements_ = 0, errors_ = 0;
  grpc::Status status_;
};

// Sends every session's messages at `rate`, the sessions' schedules spread
// evenly over one period so that they do not all arrive at once. Returns the
// longest the pacer itself was behind its schedule (us): a stall of the load
// generator, not of the server, when it is as long as the longest round trip.
double pace(std::vector<std::unique_ptr<SessionClient>>& clients, const Scenario& sc, Clock::time_point start,
            Clock::time_point record_from, Clock::time_point end, std::vector<std::pair<double, double>>* late) {
  const auto period = std::chrono::duration<double>(sc.batch / sc.rate);
  const auto slot = std::chrono::duration_cast<Clock::duration>(period / static_cast<double>(clients.size()));
  Clock::time_point due = start;
  Clock::duration behind{0};
  for (std::size_t i = 0; due < end; ++i, due += slot) {
    const Clock::time_point now = Clock::now();
    if (now < due) {
      std::this_thread::sleep_until(due);
    } else if (due >= record_from) {
      behind = std::max(behind, now - due);
      if (now - due > std::chrono::milliseconds(1)) {
        late->emplace_back(std::chrono::duration<double, std::micro>(due - start).count(),
                           std::chrono::duration<double, std::micro>(now - start).count());
      }
    }
    clients[i % clients.size()]->send(due);
  }
  return std::chrono::duration<double, std::micro>(behind).count();
}

// Channels to a server: one connection per 32 sessions; gRPC multiplexes streams over each.
struct Connections {
  std::vector<std::shared_ptr<grpc::Channel>> channels;
  std::vector<std::unique_ptr<v1::SessionService::Stub>> stubs;
  Connections(const std::string& address, int sessions) {
    for (int c = 0; c < (sessions + 31) / 32; ++c) {
      grpc::ChannelArguments args;
      args.SetInt("grpc.channel_id", c);  // distinct channels, not one shared subchannel
      channels.push_back(grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), args));
      stubs.push_back(v1::SessionService::NewStub(channels.back()));
    }
  }
  v1::SessionService::Stub& stub(int session) { return *stubs[static_cast<std::size_t>(session / 32)]; }
};

// CPU seconds of this process and of the server, read at the two ends of the recorded window.
class CpuWindow {
 public:
  CpuWindow(const bench::ServerProcess& server, Clock::time_point from, Clock::time_point until)
      : thread_([this, &server, from, until] {
          std::this_thread::sleep_until(from);
          const double client0 = bench::own_cpu_seconds(), server0 = server.cpu_seconds();
          std::this_thread::sleep_until(until);
          client_ = bench::own_cpu_seconds() - client0;
          server_ = server.cpu_seconds() - server0;
        }) {}
  void into(Figures& figures) {
    thread_.join();
    figures.client_cpu_s = client_;
    figures.server_cpu_s = server_;
  }

 private:
  double client_ = 0.0, server_ = 0.0;
  std::thread thread_;
};

Figures run(const bench::ServerProcess& server, const Workload& workload, const Scenario& sc) {
  Connections connections(server.address(), sc.sessions);
  std::vector<std::string> ids;
  Figures figures;
  for (int s = 0; s < sc.sessions; ++s) {
    grpc::ClientContext ctx;
    v1::SessionInfo info;
    const grpc::Status created = connections.stub(s).CreateSession(&ctx, workload.session, &info);
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
  CpuWindow cpu(server, record_from, end);
  std::vector<std::unique_ptr<SessionClient>> clients;
  for (int s = 0; s < sc.sessions; ++s) {
    clients.push_back(std::make_unique<SessionClient>(workload, sc, start, record_from, end));
    clients.back()->start(connections.stub(s), ids[static_cast<std::size_t>(s)]);
  }
  if (sc.rate > 0) {
    figures.pacer_behind_us = pace(clients, sc, start, record_from, end, &figures.pacer_late);
  } else {
    std::this_thread::sleep_until(end);
  }
  for (auto& c : clients) c->finish();
  cpu.into(figures);
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
    (void)connections.stub(static_cast<int>(s)).CloseSession(&ctx, close, &closed);
  }
  return figures;
}

// Creates `count` sessions of `workload` that nobody streams into, from a few
// threads at once; returns how many were made.
int create_idle_sessions(const std::string& address, const Workload& workload, int count) {
  constexpr int kThreads = 4;
  std::atomic<int> next{0}, made{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&] {
      auto stub = v1::SessionService::NewStub(grpc::CreateChannel(address, grpc::InsecureChannelCredentials()));
      while (next++ < count) {
        grpc::ClientContext ctx;
        v1::SessionInfo info;
        const grpc::Status created = stub->CreateSession(&ctx, workload.session, &info);
        if (created.ok()) {
          ++made;
        } else if (made == 0) {
          std::fprintf(stderr, "stream_bench: CreateSession: %s\n", created.error_message().c_str());
        }
      }
    });
  }
  for (auto& t : threads) t.join();
  return made;
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

// Times `step(t, u, y)` over the workload's measurements (wrapping around,
// the time stamps a lap later each time) for `seconds`, nothing else running
// (the servers are idle between runs). Measurements per second; 0, with the
// reason on stderr, if a step fails.
template <typename Step>
double steps_per_second(const Workload& workload, double seconds, const char* what, Step&& step) {
  const Dataset& d = workload.data;
  const Clock::time_point start = Clock::now();
  const auto end = start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds));
  std::int64_t steps = 0;
  for (Clock::time_point now = start; now < end; now = Clock::now()) {
    for (int i = 0; i < 256; ++i, ++steps) {  // a clock read every 256 steps
      const Eigen::Index k = static_cast<Eigen::Index>(steps % d.size());
      const double t = d.t[k] + static_cast<double>(steps / d.size()) * workload.lap_seconds;
      const Status stepped = step(t, d.u.col(k).data(), d.y.col(k).data());
      if (!stepped.is_ok()) {
        std::fprintf(stderr, "stream_bench: %s: %s\n", what, stepped.to_string().c_str());
        return 0.0;
      }
    }
  }
  return static_cast<double>(steps) / std::chrono::duration<double>(Clock::now() - start).count();
}

// What the filter step alone allows: the session's filter, made from the
// same CreateSessionRequest as riccatid makes it (online_runner_from_proto),
// advanced over the workload's measurements in this process.
double filter_alone_rate(const Workload& workload, double seconds) {
  auto model = load_model_plugin(std::string(RICCATI_TEST_PLUGIN_DIR) + "/" + workload.session.model() + ".so");
  auto runner = model.is_ok() ? service::online_runner_from_proto(model.value(), workload.session)
                              : Result<OnlineRunner>(model.status());
  if (!runner.is_ok()) {
    std::fprintf(stderr, "stream_bench: the filter alone: %s\n", runner.status().to_string().c_str());
    return 0.0;
  }
  const auto nu = static_cast<std::size_t>(workload.data.u.rows()), ny = static_cast<std::size_t>(workload.data.y.rows());
  return steps_per_second(workload, seconds, "the filter alone", [&](double t, const double* u, const double* y) {
    return runner.value().advance(t, {u, nu}, {y, ny});
  });
}

// The most a single two-tank stream could carry with the hand-written CD-EKF
// of engine_bench (the engine's algorithm for this one model, no plugin, no
// checks) and a transport that cost nothing: the ceiling the batched
// scenario's ratios are judged against. The session's own start: x from the
// first measurement, the model's default theta, the request's P0 and R.
double hand_written_rate(const Workload& workload, double seconds) {
  auto model = load_model_plugin(std::string(RICCATI_TEST_PLUGIN_DIR) + "/two_tank.so");
  if (!model.is_ok()) {
    std::fprintf(stderr, "stream_bench: the hand-written filter: %s\n", model.status().to_string().c_str());
    return 0.0;
  }
  const auto& p0 = workload.session.p0().diagonal().values();
  const auto& r = workload.session.filter().r().diagonal().values();
  bench::HandWrittenTwoTankEkf ekf;
  ekf.R = Eigen::Vector2d(r[0], r[1]).asDiagonal();
  bool started = false;
  double t_last = 0.0, u_last[2] = {0.0, 0.0};
  return steps_per_second(workload, seconds, "the hand-written filter", [&](double t, const double* u, const double* y) {
    if (!started) {
      ekf.z << y[0], y[1], model.value()->theta_default();
      ekf.P = Eigen::Map<const bench::HandWrittenTwoTankEkf::Vec6>(p0.data()).asDiagonal();
      started = true;
    } else {
      ekf.predict_structured(t - t_last, u_last);
    }
    ekf.update(y);
    t_last = t;
    std::copy(u, u + 2, u_last);
    return Status::ok();
  });
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

// What a row prints of a run, or the medians of several.
struct Summary {
  double rate = 0.0, p50 = 0.0, p99 = 0.0, max = 0.0;
  double stalls = 0.0, stalls_pacer_on_time = 0.0, errors = 0.0;
  double client_cores = 0.0, client_us = 0.0, server_cores = 0.0, server_us = 0.0;
  double pacer_behind = 0.0;
};

Summary summarize(const Figures& f) {
  const auto cores = [&](double cpu_s) { return f.seconds > 0 ? cpu_s / f.seconds : 0.0; };
  return {f.rate(),
          f.percentile(0.5),
          f.percentile(0.99),
          f.percentile(1.0),
          static_cast<double>(f.stalls()),
          static_cast<double>(f.stalls_pacer_on_time()),
          static_cast<double>(f.errors),
          cores(f.client_cpu_s),
          f.client_us(),
          cores(f.server_cpu_s),
          f.server_us(),
          f.pacer_behind_us};
}

// The median of `v` (the mean of the middle two for an even count; 0 if empty).
double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  if (v.empty()) return 0.0;
  return v.size() % 2 == 1 ? v[v.size() / 2] : (v[v.size() / 2 - 1] + v[v.size() / 2]) / 2;
}

// Each figure's median over repeated runs, on its own.
Summary median_of(const std::vector<Figures>& runs) {
  std::vector<Summary> all;
  for (const Figures& f : runs) all.push_back(summarize(f));
  const auto median_field = [&](double Summary::*field) {
    std::vector<double> v;
    for (const Summary& s : all) v.push_back(s.*field);
    return median(std::move(v));
  };
  Summary m;
  for (double Summary::*field : {&Summary::rate, &Summary::p50, &Summary::p99, &Summary::max, &Summary::stalls, &Summary::stalls_pacer_on_time,
                                 &Summary::errors, &Summary::client_cores, &Summary::client_us, &Summary::server_cores,
                                 &Summary::server_us, &Summary::pacer_behind}) {
    m.*field = median_field(field);
  }
  return m;
}

void print_header() {
  // stalls: all / those with the pacer on time (see Figures::stalls_pacer_on_time).
  std::printf("  %-10s %10s %10s %9s %9s %10s %9s %6s %13s %13s %9s\n", "", "offered/s", "meas/s", "p50 us", "p99 us",
              "max us", "stalls", "errors", "client cpu", "server cpu", "pacer us");
}

void print_row(const std::string& who, const Scenario& sc, const Summary& s) {
  const double offered = sc.rate > 0 ? sc.rate * sc.sessions : 0.0;
  char stalls[32];
  std::snprintf(stalls, sizeof stalls, "%.0f/%.0f", s.stalls, s.stalls_pacer_on_time);
  std::printf("  %-10s %10.0f %10.0f %9.1f %9.1f %10.1f %9s %6.0f %4.2f %5.1fus %4.2f %5.1fus %9.0f\n",
              who.c_str(), offered, s.rate, s.p50, s.p99, s.max, stalls, s.errors, s.client_cores, s.client_us,
              s.server_cores, s.server_us, s.pacer_behind);
  std::fflush(stdout);
}

// Sustained: every measurement offered answered, without error, p99 within one sample period.
bool sustained(const Scenario& sc, const Summary& s) {
  const double offered = sc.rate * sc.sessions;
  return s.errors == 0 && s.rate >= 0.99 * offered && s.p99 < 1e6 / sc.rate;
}

// --find-max on one server: coarse levels of sessions (10, 20, ..., 1000)
// until one is not sustained, then fifths of the gap between the last level
// sustained and the first not (a ratio of 0.8 needs the count to a few
// sessions, not to ten).
class LevelSearch {
 public:
  explicit LevelSearch(int max_sessions) : max_(max_sessions) {}
  bool done() const { return done_ || next_level() > max_; }
  int next() const { return next_level(); }
  int best() const { return best_; }
  void record(bool sustained) {
    const int n = next_level();
    if (sustained) {
      best_ = n;
      if (step_ == 0) {
        done_ = ++coarse_ == kCoarse.size();
      } else {
        done_ = n + step_ >= failed_at_;
      }
      return;
    }
    if (step_ != 0) {  // refining: the first level not sustained ends it
      done_ = true;
      return;
    }
    failed_at_ = n;
    step_ = std::max(1, (failed_at_ - best_) / 5);
    done_ = best_ + step_ >= failed_at_;
  }

 private:
  static constexpr std::array<int, 22> kCoarse = {10,  20,  30,  40,  50,  60,  70,  80,  90,  100, 120,
                                                  140, 160, 200, 240, 280, 320, 400, 500, 600, 800, 1000};
  int next_level() const { return step_ == 0 ? kCoarse[std::min(coarse_, kCoarse.size() - 1)] : best_ + step_; }
  int max_;
  std::size_t coarse_ = 0;
  int best_ = 0, failed_at_ = 0, step_ = 0;  // step_ != 0: refining
  bool done_ = false;
};

// A riccatid for the bench: its own data directory, the built-in plugins,
// production's snapshot interval, and limits raised for the bench alone.
std::unique_ptr<bench::ServerProcess> start_riccatid(const std::string& binary, const std::filesystem::path& dir,
                                                     const std::vector<std::string>& extra_flags,
                                                     const std::vector<int>& cpus) {
  std::vector<std::string> argv = {binary,
                                   "--listen", "127.0.0.1:0",
                                   "--data-dir", dir.string(),
                                   "--models-dir", RICCATI_TEST_PLUGIN_DIR,
                                   "--log-level", "warn",
                                   "--max-sessions", "100000",
                                   "--max-tenant-sessions", "100000",
                                   "--max-streams", "100000",
                                   "--max-tenant-streams", "100000"};
  argv.insert(argv.end(), extra_flags.begin(), extra_flags.end());
  auto process = std::make_unique<bench::ServerProcess>(argv, dir, false, cpus);
  if (!process->running()) std::fprintf(stderr, "stream_bench: %s did not start\n", binary.c_str());
  return process;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"stream_bench: filter sessions under load, beside a bare gRPC echo"};
  Scenario custom;
  std::string model = "two_tank";
  std::string riccatid = RICCATI_DAEMON_BIN, baseline, echo_binary = RICCATI_ECHO_BIN;
  bool find_max = false, no_echo = false;
  int max_sessions = 1000, repeat = 1, idle = 0;
  std::vector<std::string> daemon_flags;
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
                   "On each server, raise the session count (10, 20, ..., then in fifths of the last step) until a paced run is no longer sustained (all "
                   "answered, no error, p99 under one sample period); needs --rate"),
      app.add_option("--max-sessions", max_sessions, "--find-max: stop there"),
      app.add_option("--idle", idle,
                     "Run each scenario on riccatid without, then with this many idle sessions (created, never "
                     "streamed), and report the daemon's memory per idle session")};
  app.add_option("--riccatid", riccatid, "The riccatid binary under test")->capture_default_str();
  app.add_option("--baseline", baseline,
                 "Another riccatid binary (an older build) run through the same scenarios, alternating with the "
                 "first, for before-and-after figures from one run");
  app.add_option("--echo", echo_binary, "The echo server binary")->capture_default_str();
  app.add_flag("--no-echo", no_echo, "Leave out the echo runs");
  app.add_option("--daemon-flag", daemon_flags,
                 "A flag for riccatid (and the baseline), e.g. --daemon-flag=--session-snapshot-seconds=0; repeatable")
      ->allow_extra_args(false);
  app.add_option("--repeat", repeat, "Runs of each scenario on each server, alternating; the medians are printed")
      ->check(CLI::PositiveNumber);
  std::vector<int> server_cpus;
  app.add_option("--server-cpus", server_cpus,
                 "Run every server on these CPUs alone (e.g. --server-cpus 1), so that the load generator, which "
                 "may still use any, does not take their time")
      ->delimiter(',')
      ->check(CLI::Range(0, CPU_SETSIZE - 1));  // CPU_SET is undefined past its set
  CLI11_PARSE(app, argc, argv);
  absl::SetMutexDeadlockDetectionMode(absl::OnDeadlockCycle::kIgnore);  // as riccatid does: Debian's Abseil has its debug checks on
  const bool custom_given = std::any_of(options.begin(), options.end(), [](CLI::Option* o) { return o->count() > 0; });
  if (find_max && custom.rate <= 0) {
    std::fprintf(stderr, "stream_bench: --find-max needs --rate\n");
    return 2;
  }

  const std::filesystem::path work =
      std::filesystem::temp_directory_path() / ("riccati-bench-" + std::to_string(::getpid()));
  std::vector<std::pair<std::string, std::unique_ptr<bench::ServerProcess>>> servers;  // name, process
  servers.emplace_back("riccati", start_riccatid(riccatid, work / "riccati", daemon_flags, server_cpus));
  if (!baseline.empty()) {
    servers.emplace_back("baseline", start_riccatid(baseline, work / "baseline", daemon_flags, server_cpus));
  }
  std::unique_ptr<bench::ServerProcess> echo;
  if (!no_echo && idle == 0) {
    echo = std::make_unique<bench::ServerProcess>(
        std::vector<std::string>{echo_binary, "--listen", "127.0.0.1:0", "--estimates-dir", work.string()},
        work / "echo", false, server_cpus);
    if (!echo->running()) std::fprintf(stderr, "stream_bench: %s did not start\n", echo_binary.c_str());
  }
  for (const auto& [name, process] : servers) {
    if (!process->running()) return 1;
  }
  if (echo != nullptr && !echo->running()) return 1;
  const bench::ServerProcess& ricc = *servers.front().second;
  std::printf("stream_bench: riccatid on %s%s, each a process of its own; the load generator in this one; %u cores\n",
              ricc.address().c_str(), echo != nullptr ? (", echo on " + echo->address()).c_str() : "",
              std::thread::hardware_concurrency());

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
    if (echo != nullptr) {
      std::ofstream out(work / (workload.session.model() + ".estimate"), std::ios::binary);
      first_estimate(ricc.address(), workload).SerializeToOstream(&out);
    }
    if (find_max) {
      // Each server on its own: the most sessions it sustains (at each level
      // the median of --repeat runs), and the ratio of riccati's to the echo's.
      std::printf("\n%s: find the most %s sessions at %.0f Hz with p99 under %.0f us\n", title.c_str(),
                  model_name.c_str(), sc.rate, 1e6 / sc.rate);
      print_header();
      std::vector<std::pair<std::string, const bench::ServerProcess*>> searched;
      for (const auto& [name, process] : servers) searched.emplace_back(name, process.get());
      if (echo != nullptr) searched.emplace_back("echo", echo.get());
      // The servers' searches take turns, a level each, so that a machine
      // that slows down for a while slows all of them alike.
      std::vector<LevelSearch> searches(searched.size(), LevelSearch(max_sessions));
      for (bool any = true; any;) {
        any = false;
        for (std::size_t s = 0; s < searched.size(); ++s) {
          if (searches[s].done()) continue;
          any = true;
          Scenario level = sc;
          level.sessions = searches[s].next();
          std::vector<Figures> runs;
          for (int rep = 0; rep < repeat; ++rep) runs.push_back(run(*searched[s].second, workload, level));
          const Summary r = median_of(runs);
          print_row(searched[s].first + " " + std::to_string(level.sessions), level, r);
          searches[s].record(sustained(level, r));
        }
      }
      std::vector<int> best;
      for (std::size_t s = 0; s < searched.size(); ++s) {
        best.push_back(searches[s].best());
        std::printf("  %s sustains %d sessions (%.0f measurements/s)\n", searched[s].first.c_str(), best[s],
                    best[s] * sc.rate);
      }
      if (echo != nullptr && best.back() > 0) {
        std::printf("  ratio riccati/echo: %.2f of the sessions\n", static_cast<double>(best.front()) / best.back());
      }
      continue;
    }
    std::printf("\n%s (%s): %s\n", title.c_str(), model_name.c_str(), describe(sc).c_str());
    print_header();
    if (idle > 0) {
      // The same live load without, then with `idle` sessions nobody streams into.
      const std::vector<std::string> phases = {"no idle", std::to_string(idle) + " idle"};
      std::vector<std::vector<Figures>> runs(2);
      const long long rss_before = ricc.rss_bytes();
      for (int rep = 0; rep < repeat; ++rep) {
        runs[0].push_back(run(ricc, workload, sc));
        print_row(phases[0], sc, summarize(runs[0].back()));
      }
      const int made = create_idle_sessions(ricc.address(), workload, idle);
      std::this_thread::sleep_for(std::chrono::seconds(2));  // the snapshot writer done with them
      const long long rss_after = ricc.rss_bytes();
      std::printf("  riccatid RSS %.1f MiB -> %.1f MiB with %d idle sessions: %.1f KiB per idle session\n",
                  static_cast<double>(rss_before) / (1 << 20), static_cast<double>(rss_after) / (1 << 20), made,
                  made > 0 ? static_cast<double>(rss_after - rss_before) / 1024.0 / made : 0.0);
      for (int rep = 0; rep < repeat; ++rep) {
        runs[1].push_back(run(ricc, workload, sc));
        print_row(phases[1], sc, summarize(runs[1].back()));
      }
      if (repeat > 1) {
        std::printf("  medians of %d runs:\n", repeat);
        for (int p = 0; p < 2; ++p) print_row(phases[static_cast<std::size_t>(p)], sc, median_of(runs[static_cast<std::size_t>(p)]));
      }
      continue;
    }
    std::vector<std::vector<Figures>> runs(servers.size() + 1);  // per server, the echo last
    std::vector<double> alone;  // closed loop, batched: the filter step alone, once a repeat
    std::vector<double> hand_written;  // the same with the hand-written filter (two_tank only)
    for (int rep = 0; rep < repeat; ++rep) {
      if (sc.rate <= 0 && sc.batch > 1) {  // one measurement a message is bound by the round trip instead
        alone.push_back(filter_alone_rate(workload, sc.seconds - sc.warmup));
        std::printf("  %-10s %10s %10.0f   (the session's filter in this process, no server)\n", "filter", "",
                    alone.back());
        if (workload.name == "two_tank") {
          hand_written.push_back(hand_written_rate(workload, sc.seconds - sc.warmup));
          std::printf("  %-10s %10s %10.0f   (engine_bench's hand-written CD-EKF in this process, no server)\n",
                      "by hand", "", hand_written.back());
        }
      }
      for (std::size_t s = 0; s < servers.size(); ++s) {
        runs[s].push_back(run(*servers[s].second, workload, sc));
        print_row(servers[s].first, sc, summarize(runs[s].back()));
      }
      if (echo != nullptr) {
        runs.back().push_back(run(*echo, workload, sc));
        print_row("echo", sc, summarize(runs.back().back()));
      }
    }
    std::vector<Summary> medians;
    for (const auto& r : runs) medians.push_back(median_of(r));
    if (repeat > 1) {
      std::printf("  medians of %d runs:\n", repeat);
      for (std::size_t s = 0; s < servers.size(); ++s) print_row(servers[s].first, sc, medians[s]);
      if (echo != nullptr) print_row("echo", sc, medians.back());
    }
    const Summary& r = medians.front();
    for (std::size_t s = 1; s < servers.size(); ++s) {
      const Summary& b = medians[s];
      std::printf("  ratio riccati/%s: throughput %.2f, p50 %.2f, p99 %.2f\n", servers[s].first.c_str(), r.rate / b.rate,
                  r.p50 / b.p50, r.p99 / b.p99);
    }
    if (echo != nullptr) {
      const Summary& e = medians.back();
      std::printf("  ratio riccati/echo: throughput %.2f, p50 %.2f, p99 %.2f\n", r.rate / e.rate, r.p50 / e.p50,
                  r.p99 / e.p99);
    }
    if (!alone.empty()) {
      const double a = median(alone);
      if (repeat > 1) std::printf("  filter alone, median: %.0f measurements/s\n", a);
      std::printf("  ratio riccati/filter alone: throughput %.2f\n", a > 0 ? r.rate / a : 0.0);
    }
    if (!hand_written.empty() && echo != nullptr) {
      // A single stream's steps run one after another, so this is the most
      // any server with a filter this fast could reach against the echo.
      const double h = median(hand_written);
      std::printf("  ratio hand-written filter alone/echo: throughput %.2f (the ceiling of riccati/echo)\n",
                  medians.back().rate > 0 ? h / medians.back().rate : 0.0);
    }
    if (sc.rate > 0) std::printf("  sustained (p99 < %.0f us, all answered): %s\n", 1e6 / sc.rate, sustained(sc, r) ? "yes" : "no");
  }
  servers.clear();
  echo.reset();
  std::filesystem::remove_all(work);
  return 0;
}
