// Metrics for operators, in Prometheus text format on an HTTP port of their
// own (--metrics-listen; prometheus-cpp keeps them, cpp-httplib serves them). What is counted, and where:
//
//   riccati_rpc_total{method,code}           every finished call (interceptor; the session
//                                            stream counts itself, see kSessionStreamMethod)
//   riccati_measurements_total{outcome}      estimated / refused (sessions)
//   riccati_measurement_seconds              filter step per measurement (histogram)
//   riccati_sessions_open                    at scrape time
//   riccati_uploads_in_flight                at scrape time (of max_uploads)
//   riccati_session_snapshots_total{outcome} stored / failed (sessions' snapshots in the store)
//   riccati_sessions_resumed_total           sessions this instance resumed from a snapshot
//   riccati_jobs{state}                      queued / running in the store, at scrape time
//   riccati_jobs_ended_total{kind,state}     jobs this instance ended
//   riccati_job_seconds{kind}                claim to end, on this instance (histogram)
//
// Counters only grow from the daemon's start, as Prometheus expects.
#pragma once

#include <grpcpp/support/server_interceptor.h>

#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <utility>

#include "engine/status.hpp"
#include "store/store.hpp"

namespace prometheus {
class Counter;
class Histogram;
class Registry;
template <typename T>
class Family;
}  // namespace prometheus

namespace riccati::service {

// "host:port", "[v6]:port": the host as cpp-httplib binds it (empty: all
// addresses) and the port; `what` names the address in errors.
Result<std::pair<std::string, int>> split_address(const std::string& address, const std::string& what);

class Metrics {
 public:
  Metrics();
  ~Metrics();
  Metrics(const Metrics&) = delete;
  Metrics& operator=(const Metrics&) = delete;

  // Values read when scraped.
  void set_sessions_open(std::function<std::size_t()> count);
  void set_uploads_in_flight(std::function<std::int64_t()> count);
  void set_store(Store* store);

  // Serves /metrics on `address` (host:port; port 0: any free port);
  // returns the bound port.
  Result<int> serve(const std::string& address);
  // Stops serving (before what the scrape reads goes away).
  void stop_serving();

  void measurement(bool estimated, std::chrono::steady_clock::duration step);
  void session_snapshot(bool stored);
  void session_resumed();
  void job_ended(JobKind kind, JobState state, std::chrono::steady_clock::duration took);
  void rpc_finished(const std::string& method, int code);

  // Counts every call the server finishes (add to the ServerBuilder), but
  // the session stream's: an interceptor on a call runs on each of its
  // messages, and on a stream of one measurement per message that cost 15 %
  // of riccatid's CPU per message and 15 % of its round trip
  // (docs/benchmarks-log.md). The stream calls rpc_finished() as it finishes.
  std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface> interceptor_factory();
  static constexpr const char* kSessionStreamMethod = "/riccati.v1.SessionService/Stream";

 private:
  class Scraped;
  struct Endpoint;
  std::shared_ptr<prometheus::Registry> registry_;
  std::shared_ptr<Scraped> scraped_;
  prometheus::Family<prometheus::Counter>* rpcs_;
  prometheus::Counter* estimated_;
  prometheus::Counter* refused_;
  prometheus::Histogram* step_seconds_;
  prometheus::Counter* snapshots_stored_;
  prometheus::Counter* snapshots_failed_;
  prometheus::Counter* sessions_resumed_;
  prometheus::Family<prometheus::Counter>* jobs_ended_;
  prometheus::Family<prometheus::Histogram>* job_seconds_;
  std::unique_ptr<Endpoint> endpoint_;
};

}  // namespace riccati::service
