// The gRPC services of riccati.v1: thin adapters. Each handler converts the
// request, calls the engine, the store or a manager, and maps the Status to a
// gRPC status; no estimation logic lives here.
#pragma once

#include <grpcpp/grpcpp.h>

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <set>

#include "engine/models/plugin_loader.hpp"
#include "riccati/v1/datasets.grpc.pb.h"
#include "riccati/v1/jobs.grpc.pb.h"
#include "riccati/v1/models.grpc.pb.h"
#include "riccati/v1/sessions.grpc.pb.h"
#include "service/auth.hpp"
#include "service/jobs/job_manager.hpp"
#include "service/limits.hpp"
#include "service/metrics.hpp"
#include "service/sessions/session_manager.hpp"
#include "store/store.hpp"

namespace riccati::service {


class ModelServiceImpl final : public v1::ModelService::Service {
 public:
  explicit ModelServiceImpl(const ModelRegistry& models) : models_(models) {}
  grpc::Status ListModels(grpc::ServerContext*, const v1::ListModelsRequest*, v1::ListModelsResponse*) override;
  grpc::Status GetModel(grpc::ServerContext*, const v1::GetModelRequest*, v1::ModelInfo*) override;
  grpc::Status Simulate(grpc::ServerContext*, const v1::SimulateRequest*, v1::SimulateResponse*) override;

 private:
  const ModelRegistry& models_;
};

class DatasetServiceImpl final : public v1::DatasetService::Service {
 public:
  DatasetServiceImpl(const Authenticator& auth, Store& store, Limits limits)
      : auth_(auth), store_(store), limits_(limits) {}
  grpc::Status UploadDataset(grpc::ServerContext*, grpc::ServerReader<v1::UploadDatasetRequest>*,
                             v1::DatasetInfo*) override;
  grpc::Status GetDataset(grpc::ServerContext*, const v1::GetDatasetRequest*, v1::DatasetInfo*) override;
  grpc::Status ListDatasets(grpc::ServerContext*, const v1::ListDatasetsRequest*, v1::ListDatasetsResponse*) override;
  grpc::Status DeleteDataset(grpc::ServerContext*, const v1::DeleteDatasetRequest*,
                             v1::DeleteDatasetResponse*) override;
  grpc::Status GetDatasetData(grpc::ServerContext*, const v1::GetDatasetRequest*, v1::DatasetData*) override;

 private:
  const Authenticator& auth_;
  Store& store_;
  const Limits limits_;
};

class JobServiceImpl final : public v1::JobService::Service {
 public:
  JobServiceImpl(const Authenticator& auth, JobManager& jobs) : auth_(auth), jobs_(jobs) {}
  grpc::Status SubmitIdentification(grpc::ServerContext*, const v1::IdentificationSpec*, v1::Job*) override;
  grpc::Status SubmitValidation(grpc::ServerContext*, const v1::ValidationSpec*, v1::Job*) override;
  grpc::Status WatchJob(grpc::ServerContext*, const v1::WatchJobRequest*, grpc::ServerWriter<v1::Job>*) override;
  grpc::Status GetJob(grpc::ServerContext*, const v1::GetJobRequest*, v1::Job*) override;
  grpc::Status ListJobs(grpc::ServerContext*, const v1::ListJobsRequest*, v1::ListJobsResponse*) override;
  grpc::Status CancelJob(grpc::ServerContext*, const v1::CancelJobRequest*, v1::Job*) override;
  grpc::Status GetResult(grpc::ServerContext*, const v1::GetResultRequest*, v1::JobResult*) override;

 private:
  const Authenticator& auth_;
  JobManager& jobs_;
};

// Stream uses gRPC's callback API (a reactor per stream): no thread is held
// by an idle stream, a response is written before the next message is read
// (back-pressure: a client that does not read its responses stops being
// read, so its memory on the server stays bounded), and drain() can end
// every stream at once with UNAVAILABLE when the daemon stops.
class SessionServiceImpl final : public v1::SessionService::WithCallbackMethod_Stream<v1::SessionService::Service> {
 public:
  SessionServiceImpl(const Authenticator& auth, SessionManager& sessions, Limits limits, Metrics& metrics)
      : auth_(auth), sessions_(sessions), limits_(limits), metrics_(metrics) {}
  ~SessionServiceImpl() override;
  grpc::Status CreateSession(grpc::ServerContext*, const v1::CreateSessionRequest*, v1::SessionInfo*) override;
  grpc::Status GetSession(grpc::ServerContext*, const v1::GetSessionRequest*, v1::SessionInfo*) override;
  grpc::Status ListSessions(grpc::ServerContext*, const v1::ListSessionsRequest*, v1::ListSessionsResponse*) override;
  grpc::Status CloseSession(grpc::ServerContext*, const v1::CloseSessionRequest*, v1::CloseSessionResponse*) override;
  grpc::ServerBidiReactor<v1::StreamRequest, v1::StreamResponse>* Stream(grpc::CallbackServerContext*) override;

  // Ends every open stream with UNAVAILABLE and refuses new ones; returns
  // once all have ended or `deadline` has passed.
  void drain(std::chrono::steady_clock::time_point deadline);

 private:
  class StreamReactor;
  const Authenticator& auth_;
  SessionManager& sessions_;
  const Limits limits_;
  Metrics& metrics_;
  std::mutex streams_mu_;
  std::condition_variable streams_done_;
  std::set<StreamReactor*> streams_;  // open streams, for drain()
  bool draining_ = false;
};

// The job as the API shows it (spec decoded from the store's bytes).
v1::Job to_proto(const JobRecord& job);

}  // namespace riccati::service
