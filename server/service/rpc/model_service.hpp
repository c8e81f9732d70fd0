// ModelService: the loaded models and open-loop simulation.
#pragma once

#include <grpcpp/grpcpp.h>

#include <atomic>

#include "engine/models/plugin_loader.hpp"
#include "riccati/v1/models.grpc.pb.h"
#include "service/limits.hpp"

namespace riccati::service {

class ModelServiceImpl final : public v1::ModelService::Service {
 public:
  ModelServiceImpl(const ModelRegistry& models, const Limits& limits) : models_(models), limits_(limits) {}
  grpc::Status ListModels(grpc::ServerContext*, const v1::ListModelsRequest*, v1::ListModelsResponse*) override;
  grpc::Status GetModel(grpc::ServerContext*, const v1::GetModelRequest*, v1::ModelInfo*) override;
  grpc::Status Simulate(grpc::ServerContext*, const v1::SimulateRequest*, v1::SimulateResponse*) override;

 private:
  const ModelRegistry& models_;
  const Limits limits_;
  std::atomic<std::int64_t> simulations_{0};  // Simulate calls running now
};

v1::ModelInfo to_proto(const Model& model, const JacobianCheck& jacobians);

}  // namespace riccati::service
