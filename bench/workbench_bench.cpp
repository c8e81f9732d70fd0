// workbench_bench: what the web workbench's JSON API and event streams cost
// beside gRPC, against a riccatid started as a process of its own with its
// HTTP face on loopback (issue 18's targets):
//
//   build/bin/workbench_bench                 # both scenarios
//   build/bin/workbench_bench --calls 200 --seconds 20
//
// 1. GetResult of the two-tank 10-pass identification (Hensen's settings):
//    the same result fetched over gRPC (decoded by the stub) and as JSON from
//    GET /api/v1/jobs/{id}/result (the body received, and the body parsed back
//    into the proto with protobuf's JSON parser, as a client must), one
//    connection each, alternating in blocks; the median of each. riccatid
//    writes a result's JSON as the job ends and keeps it (results do not
//    change), so the first GET after the end event, as the workbench makes
//    it, only sends it; it is reported apart. The body is received twice over: by
//    cpp-httplib's client (which reads 4 KiB a poll) and by a plain socket
//    client reading as a browser or curl does (256 KiB a read).
// 2. The live view of a 400 Hz session: a manipulator session (the optimal
//    filter, case C) fed one measurement per message at 400 Hz over gRPC while
//    GET /api/v1/sessions/{id}/events is read; the lag of each event is the
//    time from the gRPC answer of the measurement whose estimate it carries to
//    the event's arrival. The server sends at most 10 events a second (what a
//    screen draws), so a lag up to ~100 ms is by design; falling behind shows
//    as a lag that grows through the run.
#include <CLI/CLI.hpp>
#include <absl/synchronization/mutex.h>
#include <google/protobuf/util/json_util.h>
#include <grpcpp/grpcpp.h>
#include <nlohmann/json.hpp>

#include <malloc.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>
#include <thread>
#include <vector>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include "bench_process.hpp"
#include "engine/data/dataset.hpp"
#include "riccati/v1/datasets.grpc.pb.h"
#include "riccati/v1/jobs.grpc.pb.h"
#include "riccati/v1/sessions.grpc.pb.h"
#include "support/requests.hpp"

// After Eigen: something httplib.h includes defines a macro that breaks Eigen's headers.
#include <httplib.h>

namespace {

using namespace riccati;
using Clock = std::chrono::steady_clock;

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0.0;
  const std::size_t k = std::min(v.size() - 1, static_cast<std::size_t>(p * static_cast<double>(v.size() - 1) + 0.5));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return v[k];
}

double micros(Clock::duration d) { return std::chrono::duration<double, std::micro>(d).count(); }

std::string read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream out;
  out << in.rdbuf();
  return out.str();
}

// Uploads two_tank.csv and runs Hensen's 10-pass identification; its job id.
std::string identify_two_tank(const std::shared_ptr<grpc::Channel>& channel) {
  auto datasets = v1::DatasetService::NewStub(channel);
  auto jobs = v1::JobService::NewStub(channel);
  v1::DatasetInfo dataset;
  {
    grpc::ClientContext ctx;
    auto writer = datasets->UploadDataset(&ctx, &dataset);
    v1::UploadDatasetRequest header;
    header.mutable_header()->set_name("two_tank.csv");
    for (const char* i : {"F1", "F2"}) header.mutable_header()->add_input_columns(i);
    for (const char* o : {"h1", "h2"}) header.mutable_header()->add_output_columns(o);
    writer->Write(header);
    v1::UploadDatasetRequest chunk;
    chunk.set_chunk(read_file(RICCATI_TEST_DATA_DIR "/two_tank.csv"));
    writer->Write(chunk);
    writer->WritesDone();
    if (const grpc::Status s = writer->Finish(); !s.ok()) {
      std::fprintf(stderr, "workbench_bench: upload: %s\n", s.error_message().c_str());
      return "";
    }
  }
  v1::Job job;
  {
    grpc::ClientContext ctx;
    if (const grpc::Status s = jobs->SubmitIdentification(&ctx, testing::hensen_spec(dataset.id(), 10), &job); !s.ok()) {
      std::fprintf(stderr, "workbench_bench: submit: %s\n", s.error_message().c_str());
      return "";
    }
  }
  grpc::ClientContext ctx;
  v1::WatchJobRequest watch;
  watch.set_id(job.id());
  auto reader = jobs->WatchJob(&ctx, watch);
  v1::Job last;
  while (reader->Read(&last)) {
  }
  (void)reader->Finish();
  if (last.state() != v1::JOB_STATE_SUCCEEDED) {
    std::fprintf(stderr, "workbench_bench: the identification ended %s\n", last.ShortDebugString().c_str());
    return "";
  }
  return job.id();
}

// GET over one kept-alive connection with plain reads: the body's bytes, or
// empty on any failure. Enough HTTP/1.1 for riccatid's answers (a
// Content-Length, no chunks).
class PlainHttpClient {
 public:
  explicit PlainHttpClient(int port) : port_(port) {}
  ~PlainHttpClient() { disconnect(); }
  PlainHttpClient(const PlainHttpClient&) = delete;
  PlainHttpClient& operator=(const PlainHttpClient&) = delete;

  // The server ends a connection after a few requests (Keep-Alive: max=5):
  // then, as a browser does, a new one.
  std::string get(const std::string& path) {
    for (int attempt = 0; attempt < 2; ++attempt) {
      if (fd_ < 0 && !connect()) return "";
      std::string body;
      if (exchange(path, &body)) return body;
      disconnect();
    }
    return "";
  }

 private:
  bool connect() {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_port = htons(static_cast<std::uint16_t>(port_));
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (fd_ >= 0 && ::connect(fd_, reinterpret_cast<const sockaddr*>(&address), sizeof address) == 0) return true;
    disconnect();
    return false;
  }
  void disconnect() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
    pending_.clear();
  }
  bool exchange(const std::string& path, std::string* body) {
    const std::string request = "GET " + path + " HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: keep-alive\r\n\r\n";
    if (::send(fd_, request.data(), request.size(), MSG_NOSIGNAL) != static_cast<ssize_t>(request.size())) return false;
    std::size_t header_end = std::string::npos;
    while ((header_end = pending_.find("\r\n\r\n")) == std::string::npos) {
      if (!read_more()) return false;
    }
    const std::string headers = pending_.substr(0, header_end);
    const std::size_t at = headers.find("Content-Length: ");
    if (at == std::string::npos || headers.compare(0, 12, "HTTP/1.1 200") != 0) return false;
    const std::size_t length = std::stoul(headers.substr(at + 16));
    pending_.erase(0, header_end + 4);
    while (pending_.size() < length) {
      if (!read_more()) return false;
    }
    *body = pending_.substr(0, length);
    pending_.erase(0, length);
    if (headers.find("Connection: close") != std::string::npos) disconnect();
    return true;
  }
  bool read_more() {
    const ssize_t n = ::recv(fd_, buffer_.data(), buffer_.size(), 0);
    if (n <= 0) return false;
    pending_.append(buffer_.data(), static_cast<std::size_t>(n));
    return true;
  }

  const int port_;
  int fd_ = -1;
  std::string pending_;
  std::vector<char> buffer_ = std::vector<char>(256 * 1024);
};

int get_result(const std::shared_ptr<grpc::Channel>& channel, int http_port, int calls) {
  const std::string job_id = identify_two_tank(channel);
  if (job_id.empty()) return 1;
  auto jobs = v1::JobService::NewStub(channel);
  httplib::Client http("127.0.0.1", http_port);
  http.set_keep_alive(true);
  const std::string path = "/api/v1/jobs/" + job_id + "/result";

  PlainHttpClient plain(http_port);
  // The first GET right after the job's end was watched, on a connection
  // already open (as a page's is), so that what it measures is riccatid's
  // work and not the connection's setup.
  double first_us = 0.0;
  if (plain.get("/api/v1/jobs/" + job_id).empty()) {
    std::fprintf(stderr, "workbench_bench: GET /api/v1/jobs/%s failed\n", job_id.c_str());
    return 1;
  }
  {
    const auto began = Clock::now();
    const std::string body = plain.get(path);
    first_us = micros(Clock::now() - began);
    if (body.empty()) {
      std::fprintf(stderr, "workbench_bench: the first GET %s failed\n", path.c_str());
      return 1;
    }
  }
  std::vector<double> grpc_us, json_us, json_parse_us, plain_us;
  std::size_t grpc_bytes = 0, json_bytes = 0;
  constexpr int kBlock = 10;
  for (int done = 0; done < calls; done += kBlock) {
    for (int i = 0; i < kBlock; ++i) {
      const auto began = Clock::now();
      grpc::ClientContext ctx;
      v1::GetResultRequest request;
      request.set_job_id(job_id);
      v1::JobResult result;
      const grpc::Status s = jobs->GetResult(&ctx, request, &result);
      grpc_us.push_back(micros(Clock::now() - began));
      if (!s.ok()) {
        std::fprintf(stderr, "workbench_bench: GetResult: %s\n", s.error_message().c_str());
        return 1;
      }
      grpc_bytes = result.ByteSizeLong();
    }
    for (int i = 0; i < kBlock; ++i) {
      const auto began = Clock::now();
      const auto res = http.Get(path);
      const auto received = Clock::now();
      if (!res || res->status != 200) {
        std::fprintf(stderr, "workbench_bench: GET %s: %s\n", path.c_str(),
                     res ? std::to_string(res->status).c_str() : httplib::to_string(res.error()).c_str());
        return 1;
      }
      v1::JobResult result;
      if (!google::protobuf::util::JsonStringToMessage(res->body, &result).ok()) {
        std::fprintf(stderr, "workbench_bench: the JSON result does not parse\n");
        return 1;
      }
      json_us.push_back(micros(received - began));
      json_parse_us.push_back(micros(Clock::now() - began));
      json_bytes = res->body.size();
    }
    for (int i = 0; i < kBlock; ++i) {
      const auto began = Clock::now();
      const std::string body = plain.get(path);
      plain_us.push_back(micros(Clock::now() - began));
      if (body.size() != json_bytes) {
        std::fprintf(stderr, "workbench_bench: the plain client got %zu bytes, not %zu\n", body.size(), json_bytes);
        return 1;
      }
    }
  }
  const double g = percentile(grpc_us, 0.5), j = percentile(json_us, 0.5), jp = percentile(json_parse_us, 0.5),
               p = percentile(plain_us, 0.5);
  std::printf("\nGetResult of the two-tank 10-pass identification, %zu calls each (medians):\n", grpc_us.size());
  std::printf("  gRPC (decoded)                         %9.0f us  %8zu bytes\n", g, grpc_bytes);
  std::printf("  JSON API, first GET after the end (plain) %6.0f us  %8s        %.2fx gRPC\n", first_us, "",
              first_us / g);
  std::printf("  JSON API (httplib client, received)    %9.0f us  %8zu bytes  %.2fx gRPC\n", j, json_bytes, j / g);
  std::printf("  JSON API (plain client, received)      %9.0f us  %8s        %.2fx gRPC\n", p, "", p / g);
  std::printf("  JSON API (httplib client, parsed)      %9.0f us  %8s        %.2fx gRPC\n", jp, "", jp / g);
  std::printf("  target: JSON under 2x gRPC (plain client): %s\n", p < 2 * g ? "met" : "NOT met");
  return 0;
}

int live_view(const std::shared_ptr<grpc::Channel>& channel, int http_port, double seconds, double rate) {
  auto sessions = v1::SessionService::NewStub(channel);
  const Dataset data =
      read_csv_file(RICCATI_TEST_DATA_DIR "/flexible_manipulator.csv", ColumnMapping{"t", {"T"}, {"s1", "s2"}}).value();
  v1::SessionInfo info;
  {
    grpc::ClientContext ctx;
    if (const grpc::Status s = sessions->CreateSession(&ctx, testing::manipulator_case_c_session(), &info); !s.ok()) {
      std::fprintf(stderr, "workbench_bench: CreateSession: %s\n", s.error_message().c_str());
      return 1;
    }
  }
  std::mutex mu;
  std::map<double, Clock::time_point> answered;  // estimate time -> when gRPC answered it
  const Clock::time_point start = Clock::now();
  std::atomic<bool> done{false};
  std::vector<std::pair<double, double>> lags;  // (arrival since start s, lag us)
  int unmatched = 0;

  // The browser's side: the session's event stream.
  std::thread viewer([&] {
    httplib::Client http("127.0.0.1", http_port);
    http.set_read_timeout(std::chrono::seconds(5));
    std::string buffer;
    http.Get("/api/v1/sessions/" + info.id() + "/events", [&](const char* bytes, std::size_t n) {
      const Clock::time_point arrived = Clock::now();
      buffer.append(bytes, n);
      for (std::size_t end; (end = buffer.find("\n\n")) != std::string::npos; buffer.erase(0, end + 2)) {
        const std::string event = buffer.substr(0, end);
        const std::size_t data_at = event.find("data: ");
        if (event.rfind("event: session", 0) != 0 || data_at == std::string::npos) continue;
        const nlohmann::json body = nlohmann::json::parse(event.substr(data_at + 6), nullptr, false);
        if (!body.is_object() || !body.contains("estimate")) continue;
        const double t = body["estimate"].value("t", -1.0);
        std::lock_guard lock(mu);
        const auto it = answered.find(t);
        if (it == answered.end()) {
          ++unmatched;  // answered later than shown? (not expected: an estimate is shown after its answer)
          continue;
        }
        lags.emplace_back(std::chrono::duration<double>(arrived - start).count(), micros(arrived - it->second));
      }
      return !done.load();
    });
  });

  // The rig's side: one measurement per message at `rate`, each answer awaited.
  grpc::ClientContext ctx;
  auto stream = sessions->Stream(&ctx);
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(info.id());
  stream->Write(open);
  const auto period = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / rate));
  const auto end = start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds));
  v1::StreamRequest request;
  v1::StreamResponse response;
  Clock::time_point due = start;
  for (Eigen::Index k = 0; due < end && k < data.size(); ++k, due += period) {
    std::this_thread::sleep_until(due);
    request.Clear();
    testing::add_sample(request, data, k);
    if (!stream->Write(request) || !stream->Read(&response)) break;
    const Clock::time_point now = Clock::now();
    std::lock_guard lock(mu);
    for (const auto& r : response.results()) {
      if (r.has_estimate()) answered.emplace(r.estimate().t(), now);
    }
  }
  stream->WritesDone();
  (void)stream->Finish();
  std::this_thread::sleep_for(std::chrono::milliseconds(300));  // the last events
  done = true;
  viewer.join();

  std::vector<double> all, first_half, second_half;
  for (const auto& [at, lag] : lags) {
    all.push_back(lag);
    (at < seconds / 2 ? first_half : second_half).push_back(lag);
  }
  std::printf("\nLive view of a %.0f Hz manipulator session, %.0f s: %zu events (%.1f a second), %zu measurements\n",
              rate, seconds, all.size(), static_cast<double>(all.size()) / seconds, answered.size());
  std::printf("  lag from the gRPC answer to its event: p50 %.1f ms, p99 %.1f ms, max %.1f ms\n",
              percentile(all, 0.5) / 1e3, percentile(all, 0.99) / 1e3, percentile(all, 1.0) / 1e3);
  std::printf("  median lag, first half %.1f ms, second half %.1f ms (keeping up: no growth)\n",
              percentile(first_half, 0.5) / 1e3, percentile(second_half, 0.5) / 1e3);
  if (unmatched > 0) std::printf("  %d events carried an estimate not (yet) answered on gRPC\n", unmatched);
  return all.empty() ? 1 : 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"workbench_bench: the JSON API and the live view beside gRPC"};
  std::string riccatid = RICCATI_DAEMON_BIN;
  int calls = 100;
  double seconds = 20.0, rate = 400.0;
  app.add_option("--riccatid", riccatid, "The riccatid binary")->capture_default_str();
  app.add_option("--calls", calls, "GetResult calls on each transport")->capture_default_str();
  app.add_option("--seconds", seconds, "Length of the live-view run")->capture_default_str();
  app.add_option("--rate", rate, "The live session's measurements per second")->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  absl::SetMutexDeadlockDetectionMode(absl::OnDeadlockCycle::kIgnore);  // as riccatid does
  // This process's heap is made ready for bodies of megabytes before
  // anything is timed: otherwise the first large body of the run pays for
  // fresh pages (glibc maps large blocks anew until a first free raises its
  // threshold), about 2 ms that are the client's, not riccatid's.
  mallopt(M_MMAP_THRESHOLD, 256 << 20);
  mallopt(M_TRIM_THRESHOLD, 512 << 20);
  {
    std::vector<char> warm(64 << 20);
    std::memset(warm.data(), 1, warm.size());
    asm volatile("" : : "r"(warm.data()) : "memory");
  }

  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("riccati-workbench-bench-" + std::to_string(::getpid()));
  int status = 1;
  {
    bench::ServerProcess daemon({riccatid, "--listen", "127.0.0.1:0", "--http-listen", "127.0.0.1:0", "--data-dir",
                                 dir.string(), "--models-dir", RICCATI_TEST_PLUGIN_DIR, "--log-level", "warn"},
                                dir, /*http_port=*/true);
    if (!daemon.running() || daemon.http_port() <= 0) {
      std::fprintf(stderr, "workbench_bench: %s did not start\n", riccatid.c_str());
    } else {
      grpc::ChannelArguments args;
      args.SetMaxReceiveMessageSize(-1);
      const auto channel = grpc::CreateCustomChannel(daemon.address(), grpc::InsecureChannelCredentials(), args);
      status = get_result(channel, daemon.http_port(), calls);
      if (status == 0) status = live_view(channel, daemon.http_port(), seconds, rate);
    }
  }
  std::filesystem::remove_all(dir);
  return status;
}

