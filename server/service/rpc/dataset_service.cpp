#include "service/rpc/dataset_service.hpp"

#include "service/convert.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <vector>
#include <optional>
#include <thread>

namespace riccati::service {

DatasetUpload upload_from_header(const v1::UploadHeader& header) {
  DatasetUpload upload;
  upload.name = header.name();
  if (header.format() == v1::DATASET_FORMAT_CSV) upload.format = DatasetFormat::kCsv;
  if (header.format() == v1::DATASET_FORMAT_MAT) upload.format = DatasetFormat::kMat;
  if (!header.time_column().empty() || header.sample_time() != 0.0) upload.mapping.time = header.time_column();
  upload.mapping.sample_time = header.sample_time();
  upload.mapping.inputs.assign(header.input_columns().begin(), header.input_columns().end());
  upload.mapping.outputs.assign(header.output_columns().begin(), header.output_columns().end());
  upload.request_id = header.request_id();
  upload.true_parameters.insert(header.true_parameters().begin(), header.true_parameters().end());
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
  info.set_sha256(r.sha256);
  info.mutable_true_parameters()->insert(r.true_parameters.begin(), r.true_parameters.end());
  return info;
}

// Reads the chunks as they come (no thread is held while the client sends);
// the upload is parsed and stored on a thread of its own, one per upload in
// flight at most (max_uploads), so that the callback threads every stream
// shares are never held by a parse.
class DatasetServiceImpl::UploadReactor final : public grpc::ServerReadReactor<v1::UploadDatasetRequest> {
 public:
  UploadReactor(DatasetServiceImpl& service, grpc::CallbackServerContext* context, v1::DatasetInfo* response)
      : service_(service), context_(context), tenant_(service.auth_.tenant(*context)), response_(response) {
    Result<StreamSlot> slot = service_.slots_.acquire(tenant_, "upload");
    if (!slot.is_ok()) {
      end_with(to_grpc(slot.status()));
      return;
    }
    slot_ = std::move(slot.value());
    touched();
    {
      std::lock_guard lock(service_.uploads_mu_);
      if (service_.draining_) {
        end_with({grpc::StatusCode::UNAVAILABLE, "riccatid is shutting down: upload again later"});
        return;
      }
      service_.uploads_.insert(this);
      // Under the registry's lock: shutdown cannot end the call before its
      // first read is asked for.
      StartRead(&part_);
    }
    service_.uploads_changed_.notify_all();
  }

  void OnReadDone(bool ok) override {
    std::lock_guard lock(mu_);
    if (ended_) return;  // by the idle watch or shutdown: the read failed with it
    if (!ok) return end();
    touched();
    if (!ticket_) {
      if (!part_.has_header()) return end_with(to_grpc(invalid_argument("the first message of an upload must be its header")));
      if (!v1::DatasetFormat_IsValid(part_.header().format())) {
        return end_with(to_grpc(invalid_argument("format " + std::to_string(part_.header().format()) +
                                                 " is unknown (expected " +
                                                 api::enum_choice_list(*v1::DatasetFormat_descriptor()) +
                                                 ", or unspecified: from the name's extension)")));
      }
      upload_ = upload_from_header(part_.header());
      Result<UploadTicket> ticket = service_.datasets_.begin_upload(tenant_, upload_.name);
      if (!ticket.is_ok()) return end_with(to_grpc(ticket.status()));
      ticket_.emplace(std::move(ticket.value()));
      declared_ = static_cast<std::int64_t>(std::min<std::uint64_t>(part_.header().size_bytes(), INT64_MAX));
      if (declared_ > 0) {
        const Status room = ticket_->grow(declared_);
        if (!room.is_ok()) return end_with(to_grpc(room));
        upload_.bytes.reserve(static_cast<std::size_t>(declared_));
      }
      return StartRead(&part_);
    }
    if (part_.has_header()) return end_with(to_grpc(invalid_argument("only one header per upload")));
    if (!part_.has_chunk()) {
      return end_with(to_grpc(invalid_argument("a message of the upload of " + upload_.name +
                                             " is empty: after the header, every message carries a chunk")));
    }
    const auto bytes = static_cast<std::int64_t>(upload_.bytes.size() + part_.chunk().size());
    if (declared_ > 0 && bytes > declared_) {
      return end_with(to_grpc(invalid_argument("the upload of " + upload_.name + " sends more than the " +
                                             std::to_string(declared_) + " bytes its header declared (size_bytes)")));
    }
    if (declared_ == 0) {
      const Status room = ticket_->grow(bytes);
      if (!room.is_ok()) return end_with(to_grpc(room));
    }
    upload_.bytes += part_.chunk();
    StartRead(&part_);
  }

  void OnDone() override {
    leave_watch();
    if (storing_.joinable()) storing_.join();
    delete this;
  }

  static std::int64_t steady_ms() {
    return std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::steady_clock::now().time_since_epoch())
        .count();
  }

  // Called by the idle watch with its registry locked: ends an upload whose
  // client has sent nothing for `idle_ms`. Finished, not cancelled, so that
  // the client hears why; its pending read then fails.
  void end_if_idle(std::int64_t now_ms, std::int64_t idle_ms) {
    std::lock_guard lock(mu_);
    if (!reading_ || now_ms - last_read_ms_.load() < idle_ms) return;
    const std::int64_t idle_s = service_.datasets_.limits().upload_idle_seconds;
    end_with({grpc::StatusCode::DEADLINE_EXCEEDED,
              "the upload of " + upload_name() + " sent nothing for " + std::to_string(idle_s) +
                  " s (upload_idle_seconds, --upload-idle-seconds): nothing stored"});
  }
  // Shutdown (the registry locked). An upload being stored ends by itself.
  void end_for_drain() {
    std::lock_guard lock(mu_);
    if (!reading_) return;
    end_with({grpc::StatusCode::UNAVAILABLE,
              "riccatid is shutting down: the upload of " + upload_name() + " was stopped, nothing stored"});
  }

 private:
  // Ends the call once, with mu_ held (or from the constructor), whoever
  // ends it: a reaction, the storing thread, the idle watch or shutdown.
  // The upload's room and place are given back before the client hears the
  // status, so that a client that goes on at once finds them free.
  void end_with(const grpc::Status& status) {
    if (ended_) return;
    ended_ = true;
    reading_ = false;
    ticket_.reset();
    slot_ = StreamSlot();
    Finish(status);
  }

  std::string upload_name() const { return ticket_ ? upload_.name : std::string("a dataset (no header yet)"); }
  void touched() { last_read_ms_ = steady_ms(); }
  void leave_watch() {
    std::lock_guard lock(service_.uploads_mu_);
    service_.uploads_.erase(this);
  }

  // The client is done sending, or gone (mu_ held).
  void end() {
    reading_ = false;
    if (!ticket_) return end_with(to_grpc(invalid_argument("the first message of an upload must be its header")));
    // A read also ends when the client cancels or its deadline passes: what
    // arrived may be cut at a line boundary and parse, so store nothing.
    if (context_->IsCancelled()) {
      return end_with({grpc::StatusCode::CANCELLED, "upload of " + upload_.name + " cancelled by the client: nothing stored"});
    }
    if (declared_ > 0 && static_cast<std::int64_t>(upload_.bytes.size()) != declared_) {
      return end_with(to_grpc(invalid_argument("the upload of " + upload_.name + " ended after " +
                                             std::to_string(upload_.bytes.size()) + " of the " +
                                             std::to_string(declared_) + " bytes its header declared: nothing stored")));
    }
    // No longer reading: neither the idle watch nor shutdown touches it.
    storing_ = std::thread([this] {
      const Result<DatasetRecord> stored = service_.datasets_.upload(*ticket_, upload_);
      std::lock_guard lock(mu_);
      if (!stored.is_ok()) return end_with(to_grpc(stored.status()));
      *response_ = to_proto(stored.value());
      end_with(grpc::Status::OK);
    });
  }

  DatasetServiceImpl& service_;
  grpc::CallbackServerContext* const context_;
  const std::string tenant_;
  v1::DatasetInfo* const response_;
  StreamSlot slot_;
  v1::UploadDatasetRequest part_;
  DatasetUpload upload_;
  std::optional<UploadTicket> ticket_;
  std::int64_t declared_ = 0;  // the header's size_bytes: reserved at once
  std::thread storing_;
  std::atomic<std::int64_t> last_read_ms_{0};  // steady clock: the last message's arrival
  // The reactions, the storing thread, the idle watch and shutdown each end
  // the call; mu_ orders them (taken after the registry's mutex).
  std::mutex mu_;
  bool reading_ = true;  // until the client is done sending or the call ends
  bool ended_ = false;   // Finish called
};

void DatasetServiceImpl::drain() {
  std::lock_guard lock(uploads_mu_);
  draining_ = true;
  // A copy: an upload ended here may leave the set before the loop ends.
  const std::vector<UploadReactor*> reading(uploads_.begin(), uploads_.end());
  for (UploadReactor* upload : reading) {
    if (uploads_.count(upload) != 0) upload->end_for_drain();
  }
}

DatasetServiceImpl::DatasetServiceImpl(const Authenticator& auth, DatasetManager& datasets, StreamSlots& slots)
    : auth_(auth), datasets_(datasets), slots_(slots), idle_watch_([this] { watch_idle_uploads(); }) {}

DatasetServiceImpl::~DatasetServiceImpl() {
  {
    std::lock_guard lock(uploads_mu_);
    stopping_ = true;
  }
  uploads_changed_.notify_all();
  idle_watch_.join();
}

void DatasetServiceImpl::watch_idle_uploads() {
  const std::int64_t idle_ms = datasets_.limits().upload_idle_seconds * 1000;
  std::unique_lock lock(uploads_mu_);
  while (!stopping_) {
    if (uploads_.empty()) {
      uploads_changed_.wait(lock);
      continue;
    }
    uploads_changed_.wait_for(lock, std::chrono::seconds(1));
    // A copy: an upload ended here may leave the set before the loop ends.
    const std::vector<UploadReactor*> reading(uploads_.begin(), uploads_.end());
    const std::int64_t now = UploadReactor::steady_ms();
    for (UploadReactor* upload : reading) {
      if (uploads_.count(upload) != 0) upload->end_if_idle(now, idle_ms);
    }
  }
}

grpc::ServerReadReactor<v1::UploadDatasetRequest>* DatasetServiceImpl::UploadDataset(
    grpc::CallbackServerContext* context, v1::DatasetInfo* response) {
  return new UploadReactor(*this, context, response);
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
