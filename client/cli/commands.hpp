// The `riccati` commands: each talks to riccatid through the API and prints
// a table (or JSON with --json). Every command returns a process exit code.
#pragma once

#include <grpcpp/grpcpp.h>

#include <memory>
#include <string>
#include <vector>

#include "grpc/health/v1/health.grpc.pb.h"
#include "riccati/v1/datasets.grpc.pb.h"
#include "riccati/v1/jobs.grpc.pb.h"
#include "riccati/v1/models.grpc.pb.h"
#include "riccati/v1/sessions.grpc.pb.h"
#include "connection.hpp"
#include "settings.hpp"

namespace riccati::cli {

// Exit codes scripts can rely on.
enum ExitCode : int {
  kExitOk = 0,
  kExitFailed = 1,       // the operation failed: a job failed or was cancelled, input was refused
  kExitUsage = 2,        // bad flags, an unreadable local file
  kExitUnreachable = 3,  // riccatid could not be reached (UNAVAILABLE, DEADLINE_EXCEEDED)
  kExitNotFound = 4,     // no such model, dataset, job or session
};

int exit_code_for(grpc::StatusCode code);

struct Client {
  Client(const Connection& connection, double timeout_s, bool json);

  std::shared_ptr<grpc::Channel> channel;
  std::unique_ptr<v1::ModelService::Stub> models;
  std::unique_ptr<v1::DatasetService::Stub> datasets;
  std::unique_ptr<v1::JobService::Stub> jobs;
  std::unique_ptr<v1::SessionService::Stub> sessions;
  std::unique_ptr<grpc::health::v1::Health::Stub> health;
  double timeout_s;
  bool json;

  // A context with the token and the unary deadline.
  std::unique_ptr<grpc::ClientContext> context() const;
  // A context with the token and no deadline: uploads, watches, streams.
  std::unique_ptr<grpc::ClientContext> stream_context() const;
  // Prints "riccati: <what>: <message>" and returns the exit code for it.
  int fail(const std::string& what, const grpc::Status& status) const;

 private:
  std::string token_;
};

// grpc.health.v1.Health/Check of `service` (empty: the daemon as a whole).
// Prints the serving status: SERVING exits 0; NOT_SERVING or UNKNOWN exit 1
// (the operation failed); a service the daemon does not know prints
// SERVICE_UNKNOWN and exits 4 (not found); riccatid unreachable exits 3. For
// container health checks and probes: no token is needed.
int health(Client& c, const std::string& service);

int models_list(Client& c);
int models_show(Client& c, const std::string& name);

struct UploadOptions {
  std::string file, name, time = "t";
  std::vector<std::string> inputs, outputs;
};
int data_upload(Client& c, const UploadOptions& o, std::string* dataset_id = nullptr);
int data_list(Client& c);
int data_show(Client& c, const std::string& id);
int data_delete(Client& c, const std::string& id);

int identify(Client& c, const RunSettings& s, bool wait);
int jobs_list(Client& c);
int job_show(Client& c, const std::string& id);
int job_watch(Client& c, const std::string& id);
int job_cancel(Client& c, const std::string& id);
int result(Client& c, const std::string& id, const std::string& format, const std::string& output,
           const std::vector<double>& truth);

// `riccati validate`: model, data, x0, hold and integrator in `settings`.
struct ValidateOptions {
  RunSettings settings;
  std::string params;
};
int validate(Client& c, const ValidateOptions& o);

struct StreamOptions {
  RunSettings settings;
  std::string file, output, time = "t";
  double rate = 0.0;
  int batch = 1;
  bool full_covariance = false;
  bool keep = false;
  std::string live = "auto";  // the live view on stderr: auto (on a terminal), always, never
};
int stream(Client& c, const StreamOptions& o);

// `riccati simulate`: model, hold and integrator in `settings`.
struct SimulateOptions {
  RunSettings settings;
  std::string params, inputs_file, time = "t", output, x0;
  std::vector<std::string> input_columns;
};
int simulate(Client& c, const SimulateOptions& o);

// Formatting, shared by the commands (and tested on its own).
std::string parameter_table(const v1::IdentificationResult& r, const std::vector<double>& initial,
                            const std::vector<double>& truth);
std::string fit_table(const v1::ValidationResult& r);

}  // namespace riccati::cli
