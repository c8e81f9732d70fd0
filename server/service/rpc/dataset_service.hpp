// DatasetService: uploads, reads and deletes the tenant's datasets through the
// DatasetManager.
#pragma once

#include <grpcpp/grpcpp.h>

#include "riccati/v1/datasets.grpc.pb.h"
#include "service/auth.hpp"
#include "service/datasets/dataset_manager.hpp"
#include "service/stream_slots.hpp"

namespace riccati::service {

// UploadDataset uses gRPC's callback API (a reactor per upload): an upload
// holds no thread while its client sends, and takes a place in StreamSlots.
class DatasetServiceImpl final : public v1::DatasetService::WithCallbackMethod_UploadDataset<v1::DatasetService::Service> {
 public:
  DatasetServiceImpl(const Authenticator& auth, DatasetManager& datasets, StreamSlots& slots)
      : auth_(auth), datasets_(datasets), slots_(slots) {}
  grpc::ServerReadReactor<v1::UploadDatasetRequest>* UploadDataset(grpc::CallbackServerContext*,
                                                                  v1::DatasetInfo*) override;
  grpc::Status GetDataset(grpc::ServerContext*, const v1::GetDatasetRequest*, v1::DatasetInfo*) override;
  grpc::Status ListDatasets(grpc::ServerContext*, const v1::ListDatasetsRequest*, v1::ListDatasetsResponse*) override;
  grpc::Status DeleteDataset(grpc::ServerContext*, const v1::DeleteDatasetRequest*,
                             v1::DeleteDatasetResponse*) override;
  grpc::Status GetDatasetData(grpc::ServerContext*, const v1::GetDatasetRequest*, v1::DatasetData*) override;

 private:
  class UploadReactor;
  const Authenticator& auth_;
  DatasetManager& datasets_;
  StreamSlots& slots_;
};

v1::DatasetInfo to_proto(const DatasetRecord& record);

}  // namespace riccati::service
