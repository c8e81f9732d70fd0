#include "service/metrics.hpp"

#include <prometheus/counter.h>
#include <prometheus/family.h>
#include <prometheus/histogram.h>
#include <prometheus/registry.h>
#include <prometheus/text_serializer.h>

#include <httplib.h>

#include "service/http/hardened_server.hpp"

#include <mutex>
#include <sstream>
#include <thread>

namespace riccati::service {

namespace {

const char* code_name(int code) {
  static const char* const kNames[] = {"OK",
                                       "CANCELLED",
                                       "UNKNOWN",
                                       "INVALID_ARGUMENT",
                                       "DEADLINE_EXCEEDED",
                                       "NOT_FOUND",
                                       "ALREADY_EXISTS",
                                       "PERMISSION_DENIED",
                                       "RESOURCE_EXHAUSTED",
                                       "FAILED_PRECONDITION",
                                       "ABORTED",
                                       "OUT_OF_RANGE",
                                       "UNIMPLEMENTED",
                                       "INTERNAL",
                                       "UNAVAILABLE",
                                       "DATA_LOSS",
                                       "UNAUTHENTICATED"};
  return code >= 0 && code <= 16 ? kNames[code] : "UNKNOWN";
}

// Bucket bounds from `first`, each `factor` times the one before.
prometheus::Histogram::BucketBoundaries exponential(double first, double factor, int count) {
  prometheus::Histogram::BucketBoundaries out;
  for (double b = first; count-- > 0; b *= factor) out.push_back(b);
  return out;
}

class RpcInterceptor final : public grpc::experimental::Interceptor {
 public:
  RpcInterceptor(Metrics& metrics, std::string method) : metrics_(metrics), method_(std::move(method)) {}
  void Intercept(grpc::experimental::InterceptorBatchMethods* methods) override {
    if (methods->QueryInterceptionHookPoint(grpc::experimental::InterceptionHookPoints::PRE_SEND_STATUS)) {
      metrics_.rpc_finished(method_, methods->GetSendStatus().error_code());
    }
    methods->Proceed();
  }

 private:
  Metrics& metrics_;
  const std::string method_;
};

class RpcInterceptorFactory final : public grpc::experimental::ServerInterceptorFactoryInterface {
 public:
  explicit RpcInterceptorFactory(Metrics& metrics) : metrics_(metrics) {}
  grpc::experimental::Interceptor* CreateServerInterceptor(grpc::experimental::ServerRpcInfo* info) override {
    const std::string method = info->method() != nullptr ? info->method() : "";
    if (method == Metrics::kSessionStreamMethod) return nullptr;  // it counts itself
    return new RpcInterceptor(metrics_, method);
  }

 private:
  Metrics& metrics_;
};

}  // namespace

// The gauges read at scrape time: open sessions, uploads in flight, and the
// jobs the store has queued and running (every instance's, when the store
// is shared).
class Metrics::Scraped final : public prometheus::Collectable {
 public:
  std::vector<prometheus::MetricFamily> Collect() const override {
    std::lock_guard lock(mu_);
    std::vector<prometheus::MetricFamily> out;
    if (sessions_open_) {
      prometheus::MetricFamily sessions{"riccati_sessions_open", "Filter sessions open on this instance",
                                        prometheus::MetricType::Gauge, {}};
      prometheus::ClientMetric m;
      m.gauge.value = static_cast<double>(sessions_open_());
      sessions.metric.push_back(m);
      out.push_back(std::move(sessions));
    }
    if (uploads_in_flight_) {
      prometheus::MetricFamily uploads{"riccati_uploads_in_flight",
                                       "Dataset uploads holding a place on this instance (of max_uploads)",
                                       prometheus::MetricType::Gauge, {}};
      prometheus::ClientMetric m;
      m.gauge.value = static_cast<double>(uploads_in_flight_());
      uploads.metric.push_back(m);
      out.push_back(std::move(uploads));
    }
    if (store_ != nullptr) {
      auto unfinished = store_->count_unfinished_jobs("");
      if (unfinished.is_ok()) {
        prometheus::MetricFamily jobs{"riccati_jobs", "Jobs queued and running, in the store",
                                      prometheus::MetricType::Gauge, {}};
        for (auto [state, count] : {std::pair{JobState::kQueued, unfinished->queued},
                                    std::pair{JobState::kRunning, unfinished->running}}) {
          prometheus::ClientMetric m;
          m.label.push_back({"state", job_state_name(state)});
          m.gauge.value = static_cast<double>(count);
          jobs.metric.push_back(m);
        }
        out.push_back(std::move(jobs));
      }
      auto usage = store_->usage();
      if (usage.is_ok()) {
        prometheus::MetricFamily bytes{"riccati_store_bytes",
                                       "The store's size: the database on disk, and the datasets and results in it",
                                       prometheus::MetricType::Gauge, {}};
        for (const auto& [part, value] : {std::pair{"database", usage->database_bytes},
                                          std::pair{"datasets", usage->dataset_bytes},
                                          std::pair{"results", usage->result_bytes}}) {
          prometheus::ClientMetric m;
          m.label.push_back({"part", part});
          m.gauge.value = static_cast<double>(value);
          bytes.metric.push_back(m);
        }
        out.push_back(std::move(bytes));
      }
    }
    return out;
  }

  mutable std::mutex mu_;
  std::function<std::size_t()> sessions_open_;
  std::function<std::int64_t()> uploads_in_flight_;
  Store* store_ = nullptr;
};

Metrics::Metrics() : registry_(std::make_shared<prometheus::Registry>()), scraped_(std::make_shared<Scraped>()) {
  rpcs_ = &prometheus::BuildCounter()
               .Name("riccati_rpc_total")
               .Help("gRPC calls finished, by method and status code")
               .Register(*registry_);
  auto& measurements = prometheus::BuildCounter()
                           .Name("riccati_measurements_total")
                           .Help("Measurements streamed into sessions: estimated, or refused (bad sizes, NaN, time)")
                           .Register(*registry_);
  estimated_ = &measurements.Add({{"outcome", "estimated"}});
  refused_ = &measurements.Add({{"outcome", "refused"}});
  // 5 us to about 80 ms: a filter step of a small model to a stiff one.
  step_seconds_ = &prometheus::BuildHistogram()
                       .Name("riccati_measurement_seconds")
                       .Help("Time to process one streamed measurement (check, filter step, estimate)")
                       .Register(*registry_)
                       .Add({}, exponential(5e-6, 2.0, 15));
  auto& snapshots = prometheus::BuildCounter()
                        .Name("riccati_session_snapshots_total")
                        .Help("Session snapshots written to the store: stored, or failed (retried, or the session lost)")
                        .Register(*registry_);
  snapshots_stored_ = &snapshots.Add({{"outcome", "stored"}});
  snapshots_failed_ = &snapshots.Add({{"outcome", "failed"}});
  sessions_resumed_ = &prometheus::BuildCounter()
                           .Name("riccati_sessions_resumed_total")
                           .Help("Sessions this instance resumed from their snapshot (another instance's, or an earlier run's)")
                           .Register(*registry_)
                           .Add({});
  jobs_ended_ = &prometheus::BuildCounter()
                     .Name("riccati_jobs_ended_total")
                     .Help("Jobs this instance ended, by kind and final state")
                     .Register(*registry_);
  job_seconds_ = &prometheus::BuildHistogram()
                      .Name("riccati_job_seconds")
                      .Help("Run time of the jobs this instance ended (from its claim), by kind")
                      .Register(*registry_);
}

Metrics::~Metrics() { stop_serving(); }

void Metrics::set_sessions_open(std::function<std::size_t()> count) {
  std::lock_guard lock(scraped_->mu_);
  scraped_->sessions_open_ = std::move(count);
}

void Metrics::set_uploads_in_flight(std::function<std::int64_t()> count) {
  std::lock_guard lock(scraped_->mu_);
  scraped_->uploads_in_flight_ = std::move(count);
}

void Metrics::set_store(Store* store) {
  std::lock_guard lock(scraped_->mu_);
  scraped_->store_ = store;
}

// The endpoint: cpp-httplib on a small pool of its own threads (ordinary
// 8 MiB stacks: prometheus-cpp's embedded civetweb runs handlers on ~100 KiB
// stacks, which glibc's printf overflows once libquadmath, linked in with
// Ceres, has registered its printf hooks).
// HardenedServer: a scraper that never finishes its request's headers cannot
// hold the two workers.
struct Metrics::Endpoint {
  HardenedServer server{[] {
    HardenedOptions options;
    options.workers = 2;
    return options;
  }()};
  std::thread thread;
};

Result<std::pair<std::string, int>> split_address(const std::string& address, const std::string& what) {
  const auto colon = address.rfind(':');
  if (colon == std::string::npos || colon + 1 == address.size()) {
    return invalid_argument(what + " address '" + address + "' is not HOST:PORT");
  }
  std::string host = address.substr(0, colon);
  if (host.size() >= 2 && host.front() == '[' && host.back() == ']') host = host.substr(1, host.size() - 2);
  int port = 0;
  try {
    std::size_t used = 0;
    port = std::stoi(address.substr(colon + 1), &used);
    if (used != address.size() - colon - 1) throw std::invalid_argument("trailing characters");
  } catch (const std::exception&) {
    return invalid_argument(what + " address '" + address + "': the port is not a number");
  }
  if (port < 0 || port > 65535) return invalid_argument(what + " address '" + address + "': port out of range");
  return std::pair{host.empty() ? std::string("0.0.0.0") : host, port};
}

Result<int> Metrics::serve(const std::string& address) {
  RICCATI_ASSIGN_OR_RETURN(auto host_port, split_address(address, "metrics"));
  auto endpoint = std::make_unique<Endpoint>();
  endpoint->server.Get("/metrics", [this](const httplib::Request&, httplib::Response& response) {
    auto families = registry_->Collect();
    auto scraped = scraped_->Collect();
    families.insert(families.end(), std::make_move_iterator(scraped.begin()), std::make_move_iterator(scraped.end()));
    std::ostringstream text;
    prometheus::TextSerializer().Serialize(text, families);
    response.set_content(text.str(), "text/plain; version=0.0.4; charset=utf-8");
  });
  const auto& [host, port] = host_port;
  const int bound = endpoint->server.bind_port(host, port);
  if (bound < 0) return failed_precondition("cannot serve metrics on " + address + ": cannot bind (in use, or no such address)");
  endpoint->thread = std::thread([server = &endpoint->server] { server->listen_after_bind(); });
  endpoint_ = std::move(endpoint);
  return bound;
}

void Metrics::stop_serving() {
  if (!endpoint_) return;
  endpoint_->server.shutdown();
  endpoint_->thread.join();
  endpoint_.reset();
}

void Metrics::session_snapshot(bool stored) { (stored ? snapshots_stored_ : snapshots_failed_)->Increment(); }

void Metrics::session_resumed() { sessions_resumed_->Increment(); }

void Metrics::measurement(bool estimated, std::chrono::steady_clock::duration step) {
  (estimated ? estimated_ : refused_)->Increment();
  step_seconds_->Observe(std::chrono::duration<double>(step).count());
}

void Metrics::job_ended(JobKind kind, JobState state, std::chrono::steady_clock::duration took) {
  jobs_ended_->Add({{"kind", job_kind_name(kind)}, {"state", job_state_name(state)}}).Increment();
  // 10 ms to about 3 h.
  job_seconds_->Add({{"kind", job_kind_name(kind)}}, exponential(0.01, 4.0, 11)).Observe(std::chrono::duration<double>(took).count());
}

void Metrics::rpc_finished(const std::string& method, int code) {
  rpcs_->Add({{"method", method}, {"code", code_name(code)}}).Increment();
}

std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface> Metrics::interceptor_factory() {
  return std::make_unique<RpcInterceptorFactory>(*this);
}

}  // namespace riccati::service
