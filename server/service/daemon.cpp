#include "service/daemon.hpp"

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/health_check_service_interface.h>
#include <spdlog/spdlog.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <filesystem>
#include <limits>
#include <thread>

#include "service/files.hpp"
#include "store/postgres_store.hpp"

namespace riccati::service {

namespace {

const LimitSpec* find_limit(const std::string& key) {
  for (const LimitSpec& spec : kLimitSpecs) {
    if (key == spec.key) return &spec;
  }
  return nullptr;
}

}  // namespace

std::vector<std::string> split_hosts(const std::string& text) {
  std::vector<std::string> out;
  std::size_t at = 0;
  while (at < text.size()) {
    std::size_t end = text.find(',', at);
    if (end == std::string::npos) end = text.size();
    std::string name = text.substr(at, end - at);
    name.erase(0, name.find_first_not_of(" \t"));
    name.erase(name.find_last_not_of(" \t") + 1);
    if (!name.empty()) out.push_back(name);
    at = end + 1;
  }
  return out;
}

Status load_config_file(const std::string& path, DaemonConfig* c) {
  RICCATI_ASSIGN_OR_RETURN(const std::string text, read_regular_file(path, "config", kMaxConfigFileBytes));
  try {
    const YAML::Node root = YAML::Load(text);
    if (!root.IsMap()) return invalid_argument("config " + path + ": expected a map of settings");
    for (const auto& entry : root) {
      const std::string key = entry.first.as<std::string>();
      const YAML::Node& v = entry.second;
      if (key == "listen") {
        c->listen = v.as<std::string>();
      } else if (key == "data_dir") {
        c->data_dir = v.as<std::string>();
      } else if (key == "database") {
        c->database = v.as<std::string>();
      } else if (key == "models_dir") {
        c->models_dir = v.as<std::string>();
      } else if (key == "workers") {
        c->workers = v.as<int>();
      } else if (key == "session_idle_timeout_s") {
        c->session_idle_timeout = std::chrono::seconds(v.as<long>());
      } else if (key == "instance_id") {
        c->job_queue.instance_id = v.as<std::string>();
      } else if (key == "job_lease_s") {
        c->job_queue.lease = std::chrono::seconds(v.as<long>());
        if (c->job_queue.lease < std::chrono::seconds(1)) {
          return invalid_argument("config " + path + ": job_lease_s must be at least 1");
        }
      } else if (key == "session_snapshot_s") {
        c->session_snapshot_interval = std::chrono::seconds(v.as<long>());
        if (c->session_snapshot_interval < std::chrono::seconds(0)) {
          return invalid_argument("config " + path + ": session_snapshot_s must be at least 0");
        }
      } else if (key == "job_poll_ms") {
        c->job_queue.poll = std::chrono::milliseconds(v.as<long>());
        if (c->job_queue.poll < std::chrono::milliseconds(10)) {
          return invalid_argument("config " + path + ": job_poll_ms must be at least 10");
        }
      } else if (const LimitSpec* limit = find_limit(key)) {
        c->limits.*(limit->value) = v.as<std::int64_t>();
        if (c->limits.*(limit->value) < 1) {
          return invalid_argument("config " + path + ": " + key + " must be at least 1");
        }
      } else if (key == "tls_cert") {
        c->security.tls_cert = v.as<std::string>();
      } else if (key == "tls_key") {
        c->security.tls_key = v.as<std::string>();
      } else if (key == "tls_client_ca") {
        c->security.tls_client_ca = v.as<std::string>();
      } else if (key == "tokens_file") {
        c->security.tokens_file = v.as<std::string>();
      } else if (key == "metrics_listen") {
        c->metrics_listen = v.as<std::string>();
      } else if (key == "metrics_public") {
        c->metrics_public = v.as<bool>();
      } else if (key == "http_listen") {
        c->http_listen = v.as<std::string>();
      } else if (key == "http_public") {
        c->http_public = v.as<bool>();
      } else if (key == "http_allowed_hosts") {
        c->http_allowed_hosts = v.IsSequence() ? v.as<std::vector<std::string>>() : split_hosts(v.as<std::string>());
      } else if (key == "log_level") {
        c->log_level = v.as<std::string>();
      } else {
        return invalid_argument("config " + path + ": unknown key \"" + key + "\" (line " +
                                std::to_string(entry.first.Mark().line + 1) + ")");
      }
    }
  } catch (const YAML::Exception& e) {
    return invalid_argument("config " + path + ": " + e.what());
  }
  return Status::ok();
}

namespace {

// The store the config names: SQLite in the data directory by default, or
// PostgreSQL. Logged without the database's password.
Result<std::unique_ptr<Store>> open_store(const DaemonConfig& config) {
  const std::string& database = config.database;
  if (database.empty() || database == "sqlite") {
    const std::string path = config.data_dir + "/riccati.db";
    RICCATI_ASSIGN_OR_RETURN(std::unique_ptr<Store> store, open_sqlite_store(path));
    spdlog::info("store opened kind=sqlite path={}", path);
    return store;
  }
  if (database.rfind("postgresql://", 0) == 0 || database.rfind("postgres://", 0) == 0) {
    RICCATI_ASSIGN_OR_RETURN(std::unique_ptr<Store> store, open_postgres_store(database));
    spdlog::info("store opened kind=postgresql database={}", redact_database_url(database));
    return store;
  }
  return invalid_argument("database \"" + redact_database_url(database) +
                          "\": expected sqlite (the default) or a postgresql:// URL");
}

}  // namespace

Daemon::Daemon(DaemonConfig config) : config_(std::move(config)) {}

Daemon::~Daemon() { shutdown(std::chrono::milliseconds(0)); }

Status Daemon::start() {
  std::error_code ec;
  std::filesystem::create_directories(config_.data_dir, ec);
  if (ec) return failed_precondition("cannot create data directory " + config_.data_dir + ": " + ec.message());
  const std::string models_dir = config_.models_dir.empty() ? default_models_dir() : config_.models_dir;
  RICCATI_ASSIGN_OR_RETURN(ModelRegistry models, ModelRegistry::load_directory(models_dir));
  log_models(models);
  const std::size_t models_loaded = models.models().size();

  RICCATI_ASSIGN_OR_RETURN(store_, open_store(config_));
  catalog_ = std::make_unique<ModelCatalog>(std::move(models), *store_, config_.limits, models_dir);

  const int workers = config_.workers > 0 ? config_.workers
                                          : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  JobQueueOptions queue = config_.job_queue;
  queue.exclusive_store = config_.database.empty() || config_.database == "sqlite";
  jobs_ = std::make_unique<JobManager>(*store_, *catalog_, workers, config_.limits, queue, &metrics_);
  RICCATI_RETURN_IF_ERROR(jobs_->start());
  SessionStoreOptions stored_sessions;
  stored_sessions.instance_id = jobs_->instance_id();
  stored_sessions.lease = queue.lease;
  stored_sessions.snapshot_interval = config_.session_snapshot_interval;
  stored_sessions.exclusive_store = queue.exclusive_store;
  stored_sessions.metrics = &metrics_;
  sessions_ = std::make_unique<SessionManager>(*catalog_, config_.session_idle_timeout, config_.limits, store_.get(),
                                               stored_sessions);
  RICCATI_RETURN_IF_ERROR(sessions_->start());

  RICCATI_ASSIGN_OR_RETURN(auth_, Authenticator::create(config_.security.tokens_file));
  model_service_ = std::make_unique<ModelServiceImpl>(*auth_, *catalog_, config_.limits);
  datasets_ = std::make_unique<DatasetManager>(*store_, config_.limits);
  stream_slots_ = std::make_unique<StreamSlots>(config_.limits);
  dataset_service_ = std::make_unique<DatasetServiceImpl>(*auth_, *datasets_, *stream_slots_);
  job_service_ = std::make_unique<JobServiceImpl>(*auth_, *jobs_, *stream_slots_);
  session_service_ =
      std::make_unique<SessionServiceImpl>(*auth_, *sessions_, config_.limits, metrics_, *stream_slots_);

  std::string security;
  RICCATI_ASSIGN_OR_RETURN(const std::shared_ptr<grpc::ServerCredentials> credentials,
                           server_credentials(config_.security, config_.listen, auth_, &security));
  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  builder.AddListeningPort(config_.listen, credentials, &port_);
  builder.SetMaxReceiveMessageSize(
      static_cast<int>(std::min<std::int64_t>(config_.limits.max_message_bytes, std::numeric_limits<int>::max())));
  builder.RegisterService(model_service_.get());
  builder.RegisterService(dataset_service_.get());
  builder.RegisterService(job_service_.get());
  builder.RegisterService(session_service_.get());
  std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>> interceptors;
  interceptors.push_back(metrics_.interceptor_factory());
  builder.experimental().SetInterceptorCreators(std::move(interceptors));
  server_ = builder.BuildAndStart();
  if (server_ == nullptr || port_ == 0) {
    return {StatusCode::kUnavailable, "cannot listen on " + config_.listen + " (address in use or invalid?)"};
  }
  // grpc.health.v1: the daemon as a whole ("") and each riccati.v1 service
  // under its full name are SERVING from now until shutdown.
  if (grpc::HealthCheckServiceInterface* health = server_->GetHealthCheckService(); health != nullptr) {
    for (const char* service : {v1::ModelService::service_full_name(), v1::DatasetService::service_full_name(),
                                v1::JobService::service_full_name(), v1::SessionService::service_full_name()}) {
      health->SetServingStatus(service, true);
    }
  }
  spdlog::info("riccatid listening address={} port={} security=\"{}\" workers={} models={}", config_.listen, port_,
               security, workers, models_loaded);
  if (!config_.metrics_listen.empty()) {
    if (!config_.metrics_public && !is_loopback(config_.metrics_listen)) {
      return failed_precondition("metrics_listen " + config_.metrics_listen +
                                 " is not a loopback address: /metrics is plain HTTP without authentication, so it is "
                                 "served off loopback only with metrics_public: true (--metrics-public), on a network "
                                 "that keeps it private");
    }
    metrics_.set_sessions_open([this] { return sessions_->size(); });
    metrics_.set_uploads_in_flight([this] { return datasets_->uploads_in_flight(); });
    metrics_.set_store(store_.get());
    RICCATI_ASSIGN_OR_RETURN(metrics_port_, metrics_.serve(config_.metrics_listen));
    spdlog::info("metrics listening address={} port={} path=/metrics", config_.metrics_listen, metrics_port_);
  }
  if (!config_.http_listen.empty()) {
    http_ = std::make_unique<HttpApi>(*auth_, *catalog_, *datasets_, *jobs_, *sessions_, *stream_slots_,
                                      config_.limits);
    std::string http_security;
    RICCATI_ASSIGN_OR_RETURN(http_port_, http_->serve({config_.http_listen, config_.http_public, config_.http_allowed_hosts}, config_.security,
                                                      &http_security));
    spdlog::info("workbench listening address={} port={} security=\"{}\"", config_.http_listen, http_port_,
                 http_security);
  }
  if (config_.security.tls_cert.empty()) {
    spdlog::warn("plain TCP on loopback, for development: give tls_cert and tls_key to serve other hosts");
  }
  return Status::ok();
}

void Daemon::shutdown(std::chrono::milliseconds grace) {
  if (server_ != nullptr) {
    spdlog::info("riccatid shutting down grace_ms={}", grace.count());
    const auto deadline = std::chrono::steady_clock::now() + grace;
    // Health checks answer NOT_SERVING from now on (every service), so load
    // balancers stop sending calls while the grace period runs.
    if (grpc::HealthCheckServiceInterface* health = server_->GetHealthCheckService(); health != nullptr) {
      health->Shutdown();
    }
    // Streams and watches would otherwise hold the server until the grace
    // ends: end them now with UNAVAILABLE. Their sessions' snapshots are
    // stored and released, for any instance to resume. Workers stop between
    // samples; a running job keeps its per-pass checkpoint and resumes at
    // the next start.
    if (http_ != nullptr) http_->stop();  // its event streams end at once
    model_service_->drain();  // simulations stop within a sample
    dataset_service_->drain();  // uploads still sending stop (nothing of them stored)
    session_service_->drain(deadline);
    job_service_->drain(deadline);
    sessions_->shutdown();
    if (jobs_ != nullptr) jobs_->shutdown();
    server_->Shutdown(std::chrono::system_clock::now() +
                      std::chrono::duration_cast<std::chrono::system_clock::duration>(
                          std::max(deadline - std::chrono::steady_clock::now(), std::chrono::steady_clock::duration{})));
    server_.reset();
  }
  metrics_.stop_serving();
  if (jobs_ != nullptr) jobs_->shutdown();
}

Result<ReloadReport> Daemon::reload_models() {
  if (catalog_ == nullptr) return failed_precondition("riccatid has not started");
  return catalog_->reload();
}

void Daemon::wait() {
  if (server_ != nullptr) server_->Wait();
}

}  // namespace riccati::service
