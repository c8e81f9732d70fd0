// The daemon: models, store, job and session managers and the gRPC server,
// started and stopped together.
#pragma once

#include <grpcpp/grpcpp.h>

#include <chrono>
#include <memory>
#include <string>
#include <vector>

#include "engine/models/plugin_loader.hpp"
#include "service/auth.hpp"
#include "service/jobs/job_manager.hpp"
#include "service/metrics.hpp"
#include "service/datasets/dataset_manager.hpp"
#include "service/http/http_api.hpp"
#include "service/rpc/dataset_service.hpp"
#include "service/rpc/job_service.hpp"
#include "service/rpc/model_service.hpp"
#include "service/rpc/session_service.hpp"
#include "service/sessions/session_manager.hpp"
#include "service/stream_slots.hpp"
#include "store/store.hpp"

namespace riccati::service {

struct DaemonConfig {
  std::string listen = "127.0.0.1:7531";  // host:port; port 0 picks a free one
  std::string data_dir = "riccati-data";  // the SQLite database
  // The store: empty or "sqlite" for SQLite in data_dir/riccati.db, or a
  // PostgreSQL URL (postgresql://user:password@host:port/dbname?...).
  std::string database;
  std::string models_dir;                 // empty: next to the binary (default_models_dir())
  int workers = 0;                        // job worker threads; 0: one per core
  std::chrono::seconds session_idle_timeout{600};
  // The job queue (job_manager.hpp): instance id, lease and poll interval.
  // exclusive_store is set from `database` (SQLite: this instance's alone).
  JobQueueOptions job_queue;
  // How often a streaming session's snapshot is stored, at most (sessions
  // use the job queue's instance id and lease).
  std::chrono::milliseconds session_snapshot_interval{1000};
  Limits limits;
  SecurityConfig security;  // TLS and bearer tokens (auth.hpp)
  std::string metrics_listen;  // host:port of the Prometheus /metrics endpoint; empty: none
  // /metrics is plain HTTP without authentication: off loopback only when
  // asked for (a network that keeps it private: compose's, a cluster's).
  bool metrics_public = false;
  // host:port of the web workbench and its JSON API (service/http/http_api.hpp); empty: none.
  std::string http_listen;
  // Plain HTTP off loopback (behind a proxy that terminates TLS); without
  // it, off loopback needs TLS (tls_cert, tls_key).
  bool http_public = false;
  // Host names the workbench answers to beside its listen address, localhost
  // and IP literals (a DNS-rebinding page's name is refused); "*": any.
  std::vector<std::string> http_allowed_hosts;
  std::string log_level = "info";
};

// Reads a YAML config file into `config` (keys as in DaemonConfig; unknown
// keys are an error, so a typo is not silently ignored).
Status load_config_file(const std::string& path, DaemonConfig* config);

// "a.example, b.example" -> {"a.example", "b.example"} (http_allowed_hosts as one string).
std::vector<std::string> split_hosts(const std::string& text);

class Daemon {
 public:
  explicit Daemon(DaemonConfig config);
  ~Daemon();

  Status start();
  int port() const { return port_; }  // the bound port, after start()
  int metrics_port() const { return metrics_port_; }  // 0: no metrics endpoint
  int http_port() const { return http_port_; }        // 0: no workbench
  // Stops accepting calls, gives running calls `grace` to finish, then stops
  // the workers (running jobs stay queued in the store for the next start).
  void shutdown(std::chrono::milliseconds grace);
  // Reads the models directory again (SIGHUP; ReloadModels does the same).
  Result<ReloadReport> reload_models();
  void wait();

 private:
  DaemonConfig config_;
  Metrics metrics_;  // first in, last out: the server's interceptor counts into it
  std::unique_ptr<Store> store_;
  std::unique_ptr<ModelCatalog> catalog_;  // the models directory's models and the tenants' text models in store_
  std::unique_ptr<DatasetManager> datasets_;
  std::unique_ptr<JobManager> jobs_;
  std::unique_ptr<SessionManager> sessions_;
  std::shared_ptr<const Authenticator> auth_;
  std::unique_ptr<StreamSlots> stream_slots_;  // before the services whose calls hold its places
  std::unique_ptr<ModelServiceImpl> model_service_;
  std::unique_ptr<DatasetServiceImpl> dataset_service_;
  std::unique_ptr<JobServiceImpl> job_service_;
  std::unique_ptr<SessionServiceImpl> session_service_;
  std::unique_ptr<grpc::Server> server_;
  std::unique_ptr<HttpApi> http_;
  int port_ = 0;
  int metrics_port_ = 0;
  int http_port_ = 0;
};

}  // namespace riccati::service
