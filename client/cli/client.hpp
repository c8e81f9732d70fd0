// The connection to riccatid as the commands use it: one channel, a stub per
// service, contexts with the token and the deadline, and the exit codes that
// scripts can rely on.
#pragma once

#include <grpcpp/grpcpp.h>

#include <memory>
#include <string>

#include "connection.hpp"
#include "riccati/v1/datasets.grpc.pb.h"
#include "riccati/v1/jobs.grpc.pb.h"
#include "riccati/v1/models.grpc.pb.h"
#include "riccati/v1/sessions.grpc.pb.h"

namespace riccati::cli {

enum ExitCode : int {
  kExitOk = 0,
  kExitFailed = 1,       // the operation failed: a job failed or was cancelled, input was refused
  kExitUsage = 2,        // bad flags, an unreadable local file
  kExitUnreachable = 3,  // riccatid could not be reached (UNAVAILABLE, DEADLINE_EXCEEDED)
  kExitNotFound = 4,     // no such model, dataset, job or session
  kExitInterrupted = 130,  // Ctrl-C (SIGINT) while waiting for a job, which was then cancelled: 128 + SIGINT
};

int exit_code_for(grpc::StatusCode code);

// What a failed call says: gRPC's message, or, when riccatid could not be
// reached, "cannot reach riccatid at HOST:PORT (connection refused); is it running?".
std::string unreachable_message(const std::string& server, const grpc::Status& status);

struct Client {
  Client(const Connection& connection, double timeout_s, bool json);

  std::shared_ptr<grpc::Channel> channel;
  std::unique_ptr<v1::ModelService::Stub> models;
  std::unique_ptr<v1::DatasetService::Stub> datasets;
  std::unique_ptr<v1::JobService::Stub> jobs;
  std::unique_ptr<v1::SessionService::Stub> sessions;
  double timeout_s;
  bool json;

  // A context with the token and the unary deadline.
  std::unique_ptr<grpc::ClientContext> context() const;
  // A context with the token and no deadline: uploads, watches, streams.
  std::unique_ptr<grpc::ClientContext> stream_context() const;
  // Prints "riccati: <what>: <message>" and returns the exit code for it.
  int fail(const std::string& what, const grpc::Status& status) const;

  grpc::Status get_model(const std::string& name, v1::ModelInfo* out) const;

 private:
  std::string server_;
  std::string token_;
};

}  // namespace riccati::cli
