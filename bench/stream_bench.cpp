// stream_bench: a load generator for filter sessions, run side by side with a
// bare gRPC echo service that answers the same messages without estimating.
//
//   build/bin/stream_bench                      # the three standard scenarios
//   build/bin/stream_bench --sessions 50 --rate 400 --batch 1 --seconds 5
//
// Both servers run in this process on loopback ports: riccatid's Daemon
// (SQLite in a temporary directory, the built-in plugins) and the echo. Each
// session is one client thread with its own stream; it sends a batch, waits
// for the answer (ping-pong) or keeps `--window` batches in flight
// (pipelined), and records every round trip. Figures: round-trip p50/p99
// and measurements per second, for riccati and for the echo, and their ratio.
#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>
#include <unistd.h>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <mutex>
#include <thread>
#include <vector>

#include "engine/dataset.hpp"
#include "riccati/v1/sessions.grpc.pb.h"
#include "service/daemon.hpp"

namespace {

using namespace riccati;
using Clock = std::chrono::steady_clock;

// Answers every batch with as many estimates, of the size riccati sends for
// the two-tank model, computing nothing.
class EchoSessions final : public v1::SessionService::Service {
 public:
  grpc::Status CreateSession(grpc::ServerContext*, const v1::CreateSessionRequest*, v1::SessionInfo* info) override {
    info->set_id("echo");
    return grpc::Status::OK;
  }
  grpc::Status Stream(grpc::ServerContext*,
                      grpc::ServerReaderWriter<v1::StreamResponse, v1::StreamRequest>* stream) override {
    v1::StreamRequest request;
    if (!stream->Read(&request)) return grpc::Status::OK;
    v1::Estimate estimate;
    for (int i = 0; i < 6; ++i) {
      estimate.add_state(0.1 * i);
      estimate.add_std(0.01 * i);
    }
    for (int i = 0; i < 2; ++i) {
      estimate.add_y_predicted(0.3);
      estimate.add_innovation(0.001);
    }
    estimate.set_nis(1.0);
    std::uint64_t sequence = 0;
    v1::StreamResponse response;
    while (stream->Read(&request)) {
      response.Clear();
      for (const auto& m : request.batch().measurements()) {
        auto* r = response.add_results();
        r->set_sequence(sequence++);
        *r->mutable_estimate() = estimate;
        r->mutable_estimate()->set_t(m.t());
      }
      if (!stream->Write(response)) break;
    }
    return grpc::Status::OK;
  }
};

struct Scenario {
  int sessions = 1;
  double rate = 0.0;  // measurements per second per session; 0 = as fast as possible
  int batch = 1;
  int window = 1;     // batches in flight per session (1 = ping-pong)
  double seconds = 3.0;
};

struct Figures {
  std::vector<double> round_trips_us;
  std::uint64_t measurements = 0;
  std::uint64_t errors = 0;
  double seconds = 0.0;
  double percentile(double p) const {
    if (round_trips_us.empty()) return 0.0;
    std::vector<double> v = round_trips_us;
    const std::size_t k = std::min(v.size() - 1, static_cast<std::size_t>(p * (v.size() - 1) + 0.5));
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
    return v[k];
  }
};

v1::CreateSessionRequest two_tank_session() {
  v1::CreateSessionRequest create;
  create.set_model("two_tank");
  for (double r : {1e-3, 1e-3}) create.mutable_filter()->mutable_r()->mutable_diagonal()->add_values(r);
  create.mutable_initial_state()->set_first_measurement(true);
  for (double v : {0.0, 0.0, 1.0, 1.0, 1e-6, 1e-6}) create.mutable_p0()->mutable_diagonal()->add_values(v);
  for (double v : {10.0, 5.0, 0.0791, 0.1342}) create.add_theta0(v);
  return create;
}

// One session's client: its own stream, paced batches, round trips recorded.
void run_session(const std::shared_ptr<grpc::Channel>& channel, const Dataset& data, const Scenario& sc,
                 Clock::time_point end, Figures* out, std::mutex* mu) {
  auto stub = v1::SessionService::NewStub(channel);
  v1::SessionInfo session;
  {
    grpc::ClientContext ctx;
    if (!stub->CreateSession(&ctx, two_tank_session(), &session).ok()) {
      std::lock_guard lock(*mu);
      ++out->errors;
      return;
    }
  }
  grpc::ClientContext ctx;
  auto stream = stub->Stream(&ctx);
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(session.id());
  stream->Write(open);

  std::deque<Clock::time_point> in_flight;
  std::vector<double> trips;
  std::uint64_t measurements = 0, errors = 0;
  Eigen::Index k = 0;
  double t = 0.0;
  const auto period = sc.rate > 0 ? std::chrono::duration<double>(sc.batch / sc.rate) : std::chrono::duration<double>(0);
  auto next_send = Clock::now();
  v1::StreamRequest request;
  v1::StreamResponse response;
  auto receive = [&] {
    if (!stream->Read(&response)) return false;
    trips.push_back(std::chrono::duration<double, std::micro>(Clock::now() - in_flight.front()).count());
    in_flight.pop_front();
    for (const auto& r : response.results()) {
      if (r.has_estimate()) {
        ++measurements;
      } else {
        ++errors;
      }
    }
    return true;
  };
  while (Clock::now() < end) {
    if (sc.rate > 0) {
      std::this_thread::sleep_until(next_send);
      next_send += std::chrono::duration_cast<Clock::duration>(period);
    }
    request.Clear();
    for (int b = 0; b < sc.batch; ++b) {
      auto* m = request.mutable_batch()->add_measurements();
      m->set_t(t);
      t += 1.0;
      m->add_u(data.u(0, k));
      m->add_u(data.u(1, k));
      m->add_y(data.y(0, k));
      m->add_y(data.y(1, k));
      k = (k + 1) % data.size();
    }
    in_flight.push_back(Clock::now());
    if (!stream->Write(request)) break;
    if (static_cast<int>(in_flight.size()) >= sc.window && !receive()) break;
  }
  while (!in_flight.empty() && receive()) {
  }
  stream->WritesDone();
  stream->Finish();
  std::lock_guard lock(*mu);
  out->round_trips_us.insert(out->round_trips_us.end(), trips.begin(), trips.end());
  out->measurements += measurements;
  out->errors += errors;
}

Figures run(const std::string& address, const Dataset& data, const Scenario& sc) {
  Figures figures;
  std::mutex mu;
  std::vector<std::thread> clients;
  // One channel per 32 sessions: gRPC multiplexes streams over connections.
  std::vector<std::shared_ptr<grpc::Channel>> channels;
  for (int c = 0; c < (sc.sessions + 31) / 32; ++c) {
    grpc::ChannelArguments args;
    args.SetInt("grpc.channel_id", c);  // distinct channels, not one shared subchannel
    channels.push_back(grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), args));
  }
  const auto start = Clock::now();
  const auto end = start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(sc.seconds));
  for (int s = 0; s < sc.sessions; ++s) {
    clients.emplace_back(run_session, channels[s / 32], std::cref(data), std::cref(sc), end, &figures, &mu);
  }
  for (auto& c : clients) c.join();
  figures.seconds = std::chrono::duration<double>(Clock::now() - start).count();
  return figures;
}

void report(const char* name, const Scenario& sc, const Figures& riccati, const Figures& echo) {
  const double r_rate = riccati.measurements / riccati.seconds, e_rate = echo.measurements / echo.seconds;
  std::printf("\n%s: %d session(s), %s, batch %d, window %d, %.0f s\n", name, sc.sessions,
              sc.rate > 0 ? (std::to_string(static_cast<int>(sc.rate)) + " Hz each").c_str() : "as fast as possible",
              sc.batch, sc.window, sc.seconds);
  std::printf("  %-8s %14s %12s %12s %8s\n", "", "meas/s", "p50 us", "p99 us", "errors");
  std::printf("  %-8s %14.0f %12.1f %12.1f %8llu\n", "riccati", r_rate, riccati.percentile(0.5),
              riccati.percentile(0.99), static_cast<unsigned long long>(riccati.errors));
  std::printf("  %-8s %14.0f %12.1f %12.1f %8llu\n", "echo", e_rate, echo.percentile(0.5), echo.percentile(0.99),
              static_cast<unsigned long long>(echo.errors));
  std::printf("  ratio riccati/echo: throughput %.2f, p50 %.2f, p99 %.2f\n", r_rate / e_rate,
              riccati.percentile(0.5) / echo.percentile(0.5), riccati.percentile(0.99) / echo.percentile(0.99));
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"stream_bench: filter sessions under load, beside a bare gRPC echo"};
  Scenario custom;
  const std::vector<CLI::Option*> options = {
      app.add_option("--sessions", custom.sessions, "Concurrent sessions"),
      app.add_option("--rate", custom.rate, "Measurements per second per session (0: as fast as possible)"),
      app.add_option("--batch", custom.batch, "Measurements per message"),
      app.add_option("--window", custom.window, "Messages in flight per session (1: ping-pong)"),
      app.add_option("--seconds", custom.seconds, "Duration of each run")};
  CLI11_PARSE(app, argc, argv);
  const bool custom_given = std::any_of(options.begin(), options.end(), [](CLI::Option* o) { return o->count() > 0; });

  const std::string data_dir =
      (std::filesystem::temp_directory_path() / ("riccati-bench-" + std::to_string(::getpid()))).string();
  service::DaemonConfig config;
  config.listen = "127.0.0.1:0";
  config.data_dir = data_dir;
  config.models_dir = RICCATI_TEST_PLUGIN_DIR;
  config.log_level = "warn";
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

  const Dataset data =
      read_csv_file(RICCATI_TEST_DATA_DIR "/two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}}).value();
  const std::string riccati_address = "127.0.0.1:" + std::to_string(daemon.port());
  const std::string echo_address = "127.0.0.1:" + std::to_string(echo_port);

  std::vector<std::pair<std::string, Scenario>> scenarios;
  if (custom_given) {
    scenarios.emplace_back("custom", custom);
  } else {
    scenarios.emplace_back("single-measurement round trip", Scenario{1, 0.0, 1, 1, 3.0});
    scenarios.emplace_back("batches of 64, ping-pong", Scenario{1, 0.0, 64, 1, 3.0});
    scenarios.emplace_back("batches of 64, pipelined", Scenario{1, 0.0, 64, 8, 3.0});
    scenarios.emplace_back("200 sessions at 400 Hz", Scenario{200, 400.0, 1, 1, 5.0});
  }
  for (const auto& [name, sc] : scenarios) {
    const Figures r = run(riccati_address, data, sc);
    const Figures e = run(echo_address, data, sc);
    report(name.c_str(), sc, r, e);
  }
  echo->Shutdown();
  daemon.shutdown(std::chrono::milliseconds(100));
  std::filesystem::remove_all(data_dir);
  return 0;
}
