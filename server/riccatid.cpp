// riccatid: the riccati daemon.
//
//   riccatid [--config riccatid.yaml] [--listen 127.0.0.1:7531] [--data-dir DIR]
//            [--database sqlite|postgresql://...] [--models-dir DIR] ...
//
// Flags override the config file. SIGTERM or SIGINT: stop accepting calls,
// let running calls finish (a few seconds), leave running jobs stored to run
// again at the next start, exit 0. SIGHUP: read the models directory again
// (as ReloadModels); sessions and jobs keep the models they started with.
#include <CLI/CLI.hpp>
#include <absl/synchronization/mutex.h>
#include <grpc/grpc.h>
#include <csignal>
#include <cstdio>
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <limits>
#include <utility>
#include <vector>
#include <iostream>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include "service/daemon.hpp"

// Written whole or not at all (a temporary file renamed over it), so that a
// reader never sees it empty or half written.
static void write_port_file(const std::string& path, int port) {
  const std::string temporary = path + ".tmp";
  std::ofstream(temporary) << port << "\n";
  std::error_code ignored;
  std::filesystem::rename(temporary, path, ignored);
}

int main(int argc, char** argv) {
  using riccati::service::DaemonConfig;
  // Debian's Abseil is built with its debug checks, so every absl::Mutex
  // (gRPC's, several per message of a stream) would keep a process-wide
  // lock-order graph under one global lock: a few per cent of a stream's CPU,
  // and contention between the streams' threads (docs/benchmarks-log.md).
  absl::SetMutexDeadlockDetectionMode(absl::OnDeadlockCycle::kIgnore);
  // Signals are taken by one thread with sigwait, so every other thread
  // must block them: block before any starts. grpc_init() below starts
  // gRPC's threads, which inherit the mask; one started before it was set
  // could take a SIGTERM and die of it (exit 143, not a drain).
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGHUP);  // read the models directory again
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  // gRPC's library stays initialised to the end of the process: the last
  // grpc_shutdown (when the server is destroyed at stop) joins gRPC's
  // executor threads, and one of them polling with a 10 s timeout held
  // SIGTERM's exit that long (rarely, under load). By then the daemon has
  // drained, stopped its workers and stored what it holds.
  grpc_init();
  CLI::App app{"riccatid: the riccati estimation daemon"};
  std::string config_file, port_file;
  DaemonConfig flags;
  long idle_timeout_s = flags.session_idle_timeout.count();
  app.add_option("--config", config_file, "YAML config file (keys as the long flags, with _)");
  // Defaults are shown in --help (capture_default_str): the configuration
  // reference in docs/operations.md is generated from it
  // (scripts/gen-config-reference.sh).
  auto* listen = app.add_option("--listen", flags.listen, "Address to listen on (host:port; port 0: any free)")
                     ->capture_default_str();
  auto* data_dir = app.add_option("--data-dir", flags.data_dir, "Directory of the SQLite database")
                       ->capture_default_str();
  auto* database = app.add_option("--database", flags.database,
                                  "sqlite (default: riccati.db in the data directory) or a PostgreSQL URL, "
                                  "postgresql://user:password@host:port/dbname");
  auto* models_dir =
      app.add_option("--models-dir", flags.models_dir, "Directory of model plugins (default: ../lib/riccati/models "
                                                       "from the directory of riccatid)");
  auto* workers =
      app.add_option("--workers", flags.workers, "Job worker threads (0: one per core)")->capture_default_str();
  auto* idle_timeout = app.add_option("--session-idle-timeout", idle_timeout_s,
                                      "Seconds before an idle session expires (config key session_idle_timeout_s)")
                           ->check(CLI::Range(0L, std::numeric_limits<long>::max()).description("NONNEGATIVE"))
                           ->capture_default_str();
  auto* instance_id = app.add_option("--instance-id", flags.job_queue.instance_id,
                                     "Owner of the jobs this instance claims, unique among instances sharing a "
                                     "database (default: <hostname>-<random>)");
  long job_lease_s = 15, job_poll_ms = 500;
  auto* job_lease = app.add_option("--job-lease-seconds", job_lease_s,
                                   "A claimed job is taken over by another instance this long after its instance "
                                   "stopped renewing it (config key job_lease_s)")
                        ->check(CLI::Range(1L, 86400L))
                        ->capture_default_str();
  auto* job_poll = app.add_option("--job-poll-ms", job_poll_ms,
                                  "How often idle workers look for jobs submitted elsewhere (config key job_poll_ms)")
                       ->check(CLI::Range(10L, 60000L))
                       ->capture_default_str();
  long session_snapshot_s = 1;
  auto* session_snapshot =
      app.add_option("--session-snapshot-seconds", session_snapshot_s,
                     "A streaming session's snapshot is stored at most this often, for another instance to resume it "
                     "(0: after every message) (config key session_snapshot_s)")
          ->check(CLI::Range(0L, 3600L))
          ->capture_default_str();
  auto* metrics_listen = app.add_option("--metrics-listen", flags.metrics_listen,
                                        "Serve Prometheus metrics at http://HOST:PORT/metrics (default: off)");
  bool metrics_public = false;
  auto* metrics_public_flag =
      app.add_flag("--metrics-public", metrics_public,
                   "Serve metrics on a non-loopback --metrics-listen address: plain HTTP without authentication, for "
                   "a network that keeps it private (config key metrics_public)");
  auto* http_listen = app.add_option("--http-listen", flags.http_listen,
                                     "Serve the web workbench and its JSON API at http(s)://HOST:PORT/ (TLS with "
                                     "--tls-cert and --tls-key; default: off)");
  bool http_public = false;
  auto* http_public_flag =
      app.add_flag("--http-public", http_public,
                   "Serve the workbench in plain HTTP on a non-loopback --http-listen address, behind a proxy that "
                   "terminates TLS (config key http_public)");
  std::string http_allowed_hosts;
  auto* http_allowed_hosts_flag = app.add_option(
      "--http-allowed-hosts", http_allowed_hosts,
      "Host names the workbench answers to beside its listen address, localhost and loopback addresses (any IP "
      "address when it listens off loopback), comma-separated; pages of these names may also write to it (a page "
      "whose own name resolves to this address, DNS rebinding, is refused; \"*\": any) (config key "
      "http_allowed_hosts)");
  std::string http_port_file;
  app.add_option("--http-port-file", http_port_file, "Write the workbench's bound port to this file once listening");
  auto* log_level =
      app.add_option("--log-level", flags.log_level, "trace, debug, info, warn, error, off")->capture_default_str();
  app.add_option("--port-file", port_file, "Write the bound port to this file once listening");
  auto* tls_cert = app.add_option("--tls-cert", flags.security.tls_cert, "TLS certificate chain (PEM)");
  auto* tls_key = app.add_option("--tls-key", flags.security.tls_key, "TLS private key (PEM)");
  auto* tls_client_ca =
      app.add_option("--tls-client-ca", flags.security.tls_client_ca, "CA of client certificates: mutual TLS (PEM)");
  auto* tokens_file = app.add_option("--tokens-file", flags.security.tokens_file,
                                     "Bearer tokens: lines \"<tenant> sha256:<digest>\" (none: no authentication, "
                                     "loopback only)");
  bool hash_token = false;
  app.add_flag("--hash-token", hash_token,
               "Read a token on standard input and print its line for the tokens file (needs --tenant)");
  std::string tenant;
  app.add_option("--tenant", tenant, "With --hash-token: the tenant the token belongs to");
  // One flag per limit, from the same table as the config keys.
  std::vector<std::pair<const riccati::service::LimitSpec*, CLI::Option*>> limit_flags;
  const riccati::service::Limits default_limits;
  for (const auto& spec : riccati::service::kLimitSpecs) {
    std::string flag = std::string("--") + spec.key;
    std::replace(flag.begin(), flag.end(), '_', '-');
    limit_flags.emplace_back(&spec, app.add_option(flag, flags.limits.*(spec.value), spec.help)
                                        ->check(CLI::Range(std::int64_t{1}, std::numeric_limits<std::int64_t>::max())
                                                    .description("POSITIVE"))
                                        ->default_str(std::to_string(default_limits.*(spec.value)))
                                        ->group("Limits"));
  }
  CLI11_PARSE(app, argc, argv);

  if (hash_token) {
    std::string token;
    if (tenant.empty() || !std::getline(std::cin, token) || token.empty()) {
      std::fprintf(stderr, "riccatid: --hash-token reads a token on standard input and needs --tenant\n");
      return 2;
    }
    std::printf("%s %s\n", tenant.c_str(), riccati::service::token_digest(token).c_str());
    return 0;
  }

  DaemonConfig config;
  if (!config_file.empty()) {
    const auto status = riccati::service::load_config_file(config_file, &config);
    if (!status.is_ok()) {
      std::fprintf(stderr, "riccatid: %s\n", status.message().c_str());
      return 2;
    }
  }
  if (*listen) config.listen = flags.listen;
  if (*data_dir) config.data_dir = flags.data_dir;
  if (*database) config.database = flags.database;
  if (*models_dir) config.models_dir = flags.models_dir;
  if (*workers) config.workers = flags.workers;
  if (*log_level) config.log_level = flags.log_level;
  if (*metrics_listen) config.metrics_listen = flags.metrics_listen;
  if (*metrics_public_flag) config.metrics_public = metrics_public;
  if (*http_listen) config.http_listen = flags.http_listen;
  if (*http_public_flag) config.http_public = http_public;
  if (*http_allowed_hosts_flag) config.http_allowed_hosts = riccati::service::split_hosts(http_allowed_hosts);
  if (*tls_cert) config.security.tls_cert = flags.security.tls_cert;
  if (*tls_key) config.security.tls_key = flags.security.tls_key;
  if (*tls_client_ca) config.security.tls_client_ca = flags.security.tls_client_ca;
  if (*tokens_file) config.security.tokens_file = flags.security.tokens_file;
  if (*idle_timeout) config.session_idle_timeout = std::chrono::seconds(idle_timeout_s);
  if (*instance_id) config.job_queue.instance_id = flags.job_queue.instance_id;
  if (*job_lease) config.job_queue.lease = std::chrono::seconds(job_lease_s);
  if (*job_poll) config.job_queue.poll = std::chrono::milliseconds(job_poll_ms);
  if (*session_snapshot) config.session_snapshot_interval = std::chrono::seconds(session_snapshot_s);
  for (const auto& [spec, option] : limit_flags) {
    if (*option) config.limits.*(spec->value) = flags.limits.*(spec->value);
  }

  auto logger = spdlog::stderr_color_mt("riccatid");
  logger->set_pattern("%Y-%m-%dT%H:%M:%S.%e %^%l%$ %v");
  logger->set_level(spdlog::level::from_str(config.log_level));
  spdlog::set_default_logger(logger);

  // A write past a file size limit (ulimit -f, systemd's LimitFSIZE) would
  // kill the daemon with SIGXFSZ, logging nothing; ignored, the write fails
  // with EFBIG, which the store reports like a full disk.
  std::signal(SIGXFSZ, SIG_IGN);

  riccati::service::Daemon daemon(config);
  const auto started = daemon.start();
  if (!started.is_ok()) {
    spdlog::error("riccatid cannot start: {}", started.message());
    return 1;
  }
  // The HTTP port first: whoever waits for --port-file finds both once it is
  // there (tests and scripts wait on it alone).
  if (!http_port_file.empty() && daemon.http_port() != 0) write_port_file(http_port_file, daemon.http_port());
  if (!port_file.empty()) write_port_file(port_file, daemon.port());
  int signal_number = 0;
  for (sigwait(&signals, &signal_number); signal_number == SIGHUP; sigwait(&signals, &signal_number)) {
    const auto reloaded = daemon.reload_models();  // the catalog logs what it found
    if (!reloaded.is_ok()) spdlog::error("models not reloaded: {}", reloaded.status().message());
  }
  spdlog::info("signal received signal={}", signal_number == SIGTERM ? "SIGTERM" : "SIGINT");
  daemon.shutdown(std::chrono::seconds(5));
  return 0;
}
