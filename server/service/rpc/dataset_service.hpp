// DatasetService: uploads, reads and deletes the tenant's datasets through the
// DatasetManager.
#pragma once

#include <grpcpp/grpcpp.h>

#include <condition_variable>
#include <mutex>
#include <set>
#include <thread>

#include "riccati/v1/datasets.grpc.pb.h"
#include "service/auth.hpp"
#include "service/datasets/dataset_manager.hpp"
#include "service/stream_slots.hpp"

namespace riccati::service {

// UploadDataset uses gRPC's callback API (a reactor per upload): an upload
// holds no thread while its client sends, and takes a place in StreamSlots.
class DatasetServiceImpl final : public v1::DatasetService::WithCallbackMethod_UploadDataset<v1::DatasetService::Service> {
 public:
  DatasetServiceImpl(const Authenticator& auth, DatasetManager& datasets, StreamSlots& slots);
  ~DatasetServiceImpl() override;
  grpc::ServerReadReactor<v1::UploadDatasetRequest>* UploadDataset(grpc::CallbackServerContext*,
                                                                  v1::DatasetInfo*) override;
  grpc::Status GetDataset(grpc::ServerContext*, const v1::GetDatasetRequest*, v1::DatasetInfo*) override;
  grpc::Status ListDatasets(grpc::ServerContext*, const v1::ListDatasetsRequest*, v1::ListDatasetsResponse*) override;
  grpc::Status DeleteDataset(grpc::ServerContext*, const v1::DeleteDatasetRequest*,
                             v1::DeleteDatasetResponse*) override;
  grpc::Status GetDatasetData(grpc::ServerContext*, const v1::GetDatasetRequest*, v1::DatasetData*) override;
  // Shutdown: uploads still sending are ended now (nothing of them is
  // stored) rather than holding the server's stop to its grace period.
  void drain();

 private:
  class UploadReactor;
  // Ends the uploads that sent nothing for upload_idle_seconds: a thread
  // that looks every second. The registry's mutex is recursive because gRPC
  // may run an upload's reactions (OnDone leaves the registry) inside the
  // call that ends it.
  void watch_idle_uploads();
  const Authenticator& auth_;
  DatasetManager& datasets_;
  StreamSlots& slots_;
  std::recursive_mutex uploads_mu_;
  std::condition_variable_any uploads_changed_;
  std::set<UploadReactor*> uploads_;  // reading their bytes
  bool stopping_ = false;
  bool draining_ = false;
  std::thread idle_watch_;
};

v1::DatasetInfo to_proto(const DatasetRecord& record);
// What an upload's header asks for (gRPC's first message, the HTTP API's query).
DatasetUpload upload_from_header(const v1::UploadHeader& header);
// A dataset's values with its description (GetDatasetData).
Result<v1::DatasetData> dataset_data(DatasetManager& datasets, const std::string& tenant, const std::string& id);

}  // namespace riccati::service
