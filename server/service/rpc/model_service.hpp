// ModelService: the models a tenant can use (ModelCatalog), text models
// uploaded and deleted, and open-loop simulation.
#pragma once

#include <grpcpp/grpcpp.h>

#include <atomic>

#include "engine/models/plugin_loader.hpp"
#include "service/auth.hpp"
#include "service/models/model_catalog.hpp"
#include "riccati/v1/models.grpc.pb.h"
#include "service/limits.hpp"

namespace riccati::service {

class ModelServiceImpl final : public v1::ModelService::Service {
 public:
  ModelServiceImpl(const Authenticator& auth, ModelCatalog& models, const Limits& limits)
      : auth_(auth), models_(models), limits_(limits) {}
  grpc::Status ListModels(grpc::ServerContext*, const v1::ListModelsRequest*, v1::ListModelsResponse*) override;
  grpc::Status GetModel(grpc::ServerContext*, const v1::GetModelRequest*, v1::ModelInfo*) override;
  grpc::Status CreateModel(grpc::ServerContext*, const v1::CreateModelRequest*, v1::ModelInfo*) override;
  grpc::Status DeleteModel(grpc::ServerContext*, const v1::DeleteModelRequest*, v1::DeleteModelResponse*) override;
  grpc::Status Simulate(grpc::ServerContext*, const v1::SimulateRequest*, v1::SimulateResponse*) override;
  grpc::Status ReloadModels(grpc::ServerContext*, const v1::ReloadModelsRequest*, v1::ReloadModelsResponse*) override;
  // Shutdown: running simulations stop within a sample (UNAVAILABLE), not
  // at the end of the grace period.
  void drain() { draining_ = true; }

 private:
  const Authenticator& auth_;
  ModelCatalog& models_;
  const Limits limits_;
  std::atomic<std::int64_t> simulations_{0};  // Simulate calls running now
  std::atomic<bool> draining_{false};
};

v1::ModelInfo to_proto(const Model& model, const JacobianCheck& jacobians);
v1::ModelInfo to_proto(const CatalogEntry& entry);
v1::ReloadModelsResponse to_proto(const ReloadReport& report);
// CreateModel's work, shared with the HTTP API: the size limit, then the catalog.
Result<CatalogEntry> create_model(ModelCatalog& models, const std::string& tenant, const v1::CreateModelRequest& request);

}  // namespace riccati::service
