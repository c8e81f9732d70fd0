// ModelService: the loaded models and open-loop simulation.
#pragma once

#include <grpcpp/grpcpp.h>

#include "engine/models/plugin_loader.hpp"
#include "riccati/v1/models.grpc.pb.h"

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

v1::ModelInfo to_proto(const Model& model, const JacobianCheck& jacobians);

}  // namespace riccati::service
