#include "service/rpc/dataset_service.hpp"

#include "service/convert.hpp"

namespace riccati::service {

DatasetUpload upload_from_header(const v1::UploadHeader& header) {
  DatasetUpload upload;
  upload.name = header.name();
  if (header.format() == v1::DATASET_FORMAT_CSV) upload.format = DatasetFormat::kCsv;
  if (header.format() == v1::DATASET_FORMAT_MAT) upload.format = DatasetFormat::kMat;
  if (!header.time_column().empty()) upload.mapping.time = header.time_column();
  upload.mapping.inputs.assign(header.input_columns().begin(), header.input_columns().end());
  upload.mapping.outputs.assign(header.output_columns().begin(), header.output_columns().end());
  return upload;
}

Result<v1::DatasetData> dataset_data(DatasetManager& datasets, const std::string& tenant, const std::string& id) {
  RICCATI_ASSIGN_OR_RETURN(const DatasetRecord record, datasets.get(tenant, id));
  RICCATI_ASSIGN_OR_RETURN(const Dataset data, datasets.load(tenant, id));
  v1::DatasetData out;
  *out.mutable_info() = to_proto(record);
  copy_values(data.t, out.mutable_t());
  *out.mutable_u() = to_matrix(data.u);
  *out.mutable_y() = to_matrix(data.y);
  return out;
}

v1::DatasetInfo to_proto(const DatasetRecord& r) {
  v1::DatasetInfo info;
  info.set_id(r.id);
  info.set_name(r.name);
  info.set_format(r.format == "mat" ? v1::DATASET_FORMAT_MAT : v1::DATASET_FORMAT_CSV);
  for (const auto& n : r.input_names) info.add_input_names(n);
  for (const auto& n : r.output_names) info.add_output_names(n);
  info.set_samples(static_cast<uint64_t>(r.samples));
  info.set_t_start(r.t_start);
  info.set_t_end(r.t_end);
  info.set_size_bytes(static_cast<uint64_t>(r.size_bytes));
  set_timestamp(r.created_ms, info.mutable_created());
  return info;
}

grpc::Status DatasetServiceImpl::UploadDataset(grpc::ServerContext* context,
                                               grpc::ServerReader<v1::UploadDatasetRequest>* reader,
                                               v1::DatasetInfo* response) {
  v1::UploadDatasetRequest part;
  if (!reader->Read(&part) || !part.has_header()) {
    return to_grpc(invalid_argument("the first message of an upload must be its header"));
  }
  DatasetUpload upload = upload_from_header(part.header());
  Result<UploadTicket> ticket = datasets_.begin_upload(auth_.tenant(*context), upload.name);
  if (!ticket.is_ok()) return to_grpc(ticket.status());
  while (reader->Read(&part)) {
    if (part.has_header()) return to_grpc(invalid_argument("only one header per upload"));
    if (!part.has_chunk()) {
      return to_grpc(invalid_argument("a message of the upload of " + upload.name +
                                      " is empty: after the header, every message carries a chunk"));
    }
    const Status room = ticket->grow(static_cast<std::int64_t>(upload.bytes.size() + part.chunk().size()));
    if (!room.is_ok()) return to_grpc(room);
    upload.bytes += part.chunk();
  }
  // Read() also ends when the client cancels or its deadline passes: what
  // arrived may be cut at a line boundary and parse, so store nothing.
  if (context->IsCancelled()) {
    return {grpc::StatusCode::CANCELLED, "upload of " + upload.name + " cancelled by the client: nothing stored"};
  }
  const Result<DatasetRecord> stored = datasets_.upload(ticket.value(), upload);
  if (!stored.is_ok()) return to_grpc(stored.status());
  *response = to_proto(stored.value());
  return grpc::Status::OK;
}

grpc::Status DatasetServiceImpl::GetDataset(grpc::ServerContext* context, const v1::GetDatasetRequest* request,
                                            v1::DatasetInfo* response) {
  const Result<DatasetRecord> record = datasets_.get(auth_.tenant(*context), request->id());
  if (!record.is_ok()) return to_grpc(record.status());
  *response = to_proto(record.value());
  return grpc::Status::OK;
}

grpc::Status DatasetServiceImpl::ListDatasets(grpc::ServerContext* context, const v1::ListDatasetsRequest*,
                                              v1::ListDatasetsResponse* response) {
  const Result<std::vector<DatasetRecord>> records = datasets_.list(auth_.tenant(*context));
  if (!records.is_ok()) return to_grpc(records.status());
  for (const auto& r : records.value()) *response->add_datasets() = to_proto(r);
  return grpc::Status::OK;
}

grpc::Status DatasetServiceImpl::DeleteDataset(grpc::ServerContext* context, const v1::DeleteDatasetRequest* request,
                                               v1::DeleteDatasetResponse*) {
  return to_grpc(datasets_.remove(auth_.tenant(*context), request->id()));
}

grpc::Status DatasetServiceImpl::GetDatasetData(grpc::ServerContext* context, const v1::GetDatasetRequest* request,
                                                v1::DatasetData* response) {
  Result<v1::DatasetData> data = dataset_data(datasets_, auth_.tenant(*context), request->id());
  if (!data.is_ok()) return to_grpc(data.status());
  *response = std::move(data.value());
  return grpc::Status::OK;
}

}  // namespace riccati::service
