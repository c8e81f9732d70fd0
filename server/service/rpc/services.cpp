#include "service/rpc/services.hpp"

#include <optional>

#include <spdlog/spdlog.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include "engine/estimation/validation.hpp"
#include "service/auth.hpp"
#include "service/convert.hpp"

namespace riccati::service {

// ---- ModelService ---------------------------------------------------------

grpc::Status ModelServiceImpl::ListModels(grpc::ServerContext*, const v1::ListModelsRequest*,
                                          v1::ListModelsResponse* response) {
  for (const auto& m : models_.models()) *response->add_models() = to_proto(*m);
  return grpc::Status::OK;
}

grpc::Status ModelServiceImpl::GetModel(grpc::ServerContext*, const v1::GetModelRequest* request,
                                        v1::ModelInfo* response) {
  const ModelPtr m = models_.find(request->name());
  if (m == nullptr) return to_grpc(not_found("no model \"" + request->name() + "\" is loaded"));
  *response = to_proto(*m);
  return grpc::Status::OK;
}

grpc::Status ModelServiceImpl::Simulate(grpc::ServerContext*, const v1::SimulateRequest* request,
                                        v1::SimulateResponse* response) {
  const ModelPtr m = models_.find(request->model());
  if (m == nullptr) return to_grpc(not_found("no model \"" + request->model() + "\" is loaded"));
  auto run = [&]() -> Status {
    const Eigen::Index n = request->t_size();
    if (n < 2) return invalid_argument("t needs at least two sample times");
    RICCATI_ASSIGN_OR_RETURN(const Eigen::VectorXd t, from_values(request->t(), n, "t"));
    for (Eigen::Index k = 1; k < n; ++k) {
      if (!(t[k] > t[k - 1])) return invalid_argument("t is not strictly increasing at index " + std::to_string(k));
    }
    RICCATI_ASSIGN_OR_RETURN(const Eigen::MatrixXd u, from_matrix(request->u(), "u"));
    if (u.rows() != m->nu() || u.cols() != n) {
      return invalid_argument("u must be " + std::to_string(m->nu()) + " x " + std::to_string(n));
    }
    Eigen::VectorXd theta = m->theta_default();
    if (request->theta_size() != 0) {
      RICCATI_ASSIGN_OR_RETURN(theta, from_values(request->theta(), m->ntheta(), "theta"));
    }
    RICCATI_ASSIGN_OR_RETURN(const Eigen::VectorXd x0, from_values(request->x0(), m->nx(), "x0"));
    SimulationSettings settings;
    settings.hold = from_proto(request->hold());
    RICCATI_ASSIGN_OR_RETURN(settings.integrator, from_proto(request->integrator()));
    Eigen::MatrixXd x;
    RICCATI_ASSIGN_OR_RETURN(const Eigen::MatrixXd y, simulate(*m, t, u, x0, theta, settings, &x));
    *response->mutable_y() = to_matrix(y);
    *response->mutable_x() = to_matrix(x);
    return Status::ok();
  };
  return to_grpc(run());
}

// ---- DatasetService -------------------------------------------------------

grpc::Status DatasetServiceImpl::UploadDataset(grpc::ServerContext* context,
                                               grpc::ServerReader<v1::UploadDatasetRequest>* reader,
                                               v1::DatasetInfo* response) {
  v1::UploadDatasetRequest part;
  if (!reader->Read(&part) || !part.has_header()) {
    return to_grpc(invalid_argument("the first message of an upload must be its header"));
  }
  const v1::UploadHeader header = part.header();
  std::string bytes;
  while (reader->Read(&part)) {
    if (!part.has_chunk()) return to_grpc(invalid_argument("only one header per upload"));
    if (static_cast<std::int64_t>(bytes.size() + part.chunk().size()) > limits_.max_dataset_bytes) {
      return to_grpc(limit_reached("max_dataset_bytes", limits_.max_dataset_bytes,
                                   "the upload of " + header.name() + " is larger"));
    }
    bytes += part.chunk();
  }
  // Read() also ends when the client cancels or its deadline passes: what
  // arrived may be cut at a line boundary and parse, so store nothing.
  if (context->IsCancelled()) {
    return {grpc::StatusCode::CANCELLED, "upload of " + header.name() + " cancelled by the client: nothing stored"};
  }
  if (bytes.empty()) return to_grpc(invalid_argument("upload of " + header.name() + " is empty"));

  const std::string name = header.name().empty() ? "upload" : header.name();
  v1::DatasetFormat format = header.format();
  if (format == v1::DATASET_FORMAT_UNSPECIFIED) {
    const std::string ext = std::filesystem::path(name).extension().string();
    format = (ext == ".mat" || ext == ".MAT") ? v1::DATASET_FORMAT_MAT : v1::DATASET_FORMAT_CSV;
  }
  ColumnMapping mapping;
  if (!header.time_column().empty()) mapping.time = header.time_column();
  mapping.inputs.assign(header.input_columns().begin(), header.input_columns().end());
  mapping.outputs.assign(header.output_columns().begin(), header.output_columns().end());

  Result<Dataset> parsed = format == v1::DATASET_FORMAT_CSV
                               ? parse_csv(bytes, mapping, name)
                               : parse_mat(bytes, mapping, name, static_cast<std::uint64_t>(limits_.max_dataset_bytes));
  if (parsed.status().code() == StatusCode::kResourceExhausted) {
    return to_grpc(limit_reached("max_dataset_bytes", limits_.max_dataset_bytes, parsed.status().message()));
  }
  if (!parsed.is_ok()) return to_grpc(parsed.status());
  const Dataset& data = parsed.value();
  if (data.size() > limits_.max_dataset_samples) {
    return to_grpc(limit_reached("max_dataset_samples", limits_.max_dataset_samples,
                                 name + " has " + std::to_string(data.size()) + " samples"));
  }
  const std::string tenant = auth_.tenant(*context);
  {
    // Checked before storing, so concurrent uploads of one tenant may pass
    // it together: a soft limit, by at most one upload per connection.
    auto stored = store_.list_datasets(tenant);
    if (!stored.is_ok()) return to_grpc(stored.status());
    std::int64_t used = static_cast<std::int64_t>(bytes.size());
    for (const DatasetRecord& r : stored.value()) used += r.size_bytes;
    if (used > limits_.max_tenant_dataset_bytes) {
      return to_grpc(limit_reached("max_tenant_dataset_bytes", limits_.max_tenant_dataset_bytes,
                                   "this tenant's datasets would take " + std::to_string(used) +
                                       " bytes; delete some (DeleteDataset) first"));
    }
  }

  DatasetRecord record;
  record.id = new_id("ds");
  record.tenant = tenant;
  record.name = name;
  record.format = format == v1::DATASET_FORMAT_MAT ? "mat" : "csv";
  record.input_names = data.input_names;
  record.output_names = data.output_names;
  record.samples = data.size();
  record.t_start = data.t[0];
  record.t_end = data.t[data.size() - 1];
  record.size_bytes = static_cast<std::int64_t>(bytes.size());
  record.created_ms = now_ms();
  const Status stored = store_.put_dataset(record, data);
  if (!stored.is_ok()) return to_grpc(stored);
  spdlog::info("dataset stored id={} name={} samples={} tenant={}", record.id, record.name, record.samples,
               record.tenant);
  *response = to_proto(record);
  return grpc::Status::OK;
}

grpc::Status DatasetServiceImpl::GetDataset(grpc::ServerContext* context, const v1::GetDatasetRequest* request,
                                            v1::DatasetInfo* response) {
  auto record = store_.get_dataset(auth_.tenant(*context), request->id());
  if (!record.is_ok()) return to_grpc(record.status());
  *response = to_proto(record.value());
  return grpc::Status::OK;
}

grpc::Status DatasetServiceImpl::ListDatasets(grpc::ServerContext* context, const v1::ListDatasetsRequest*,
                                              v1::ListDatasetsResponse* response) {
  auto records = store_.list_datasets(auth_.tenant(*context));
  if (!records.is_ok()) return to_grpc(records.status());
  for (const auto& r : records.value()) *response->add_datasets() = to_proto(r);
  return grpc::Status::OK;
}

grpc::Status DatasetServiceImpl::DeleteDataset(grpc::ServerContext* context, const v1::DeleteDatasetRequest* request,
                                               v1::DeleteDatasetResponse*) {
  return to_grpc(store_.delete_dataset(auth_.tenant(*context), request->id()));
}

grpc::Status DatasetServiceImpl::GetDatasetData(grpc::ServerContext* context, const v1::GetDatasetRequest* request,
                                                v1::DatasetData* response) {
  const std::string tenant = auth_.tenant(*context);
  auto record = store_.get_dataset(tenant, request->id());
  if (!record.is_ok()) return to_grpc(record.status());
  auto data = store_.load_dataset(tenant, request->id());
  if (!data.is_ok()) return to_grpc(data.status());
  *response->mutable_info() = to_proto(record.value());
  copy_values(data.value().t, response->mutable_t());
  *response->mutable_u() = to_matrix(data.value().u);
  *response->mutable_y() = to_matrix(data.value().y);
  return grpc::Status::OK;
}

// ---- JobService -----------------------------------------------------------

v1::Job to_proto(const JobRecord& job) {
  v1::Job out;
  out.set_id(job.id);
  out.set_state(to_proto(job.state));
  if (job.kind == "identification") {
    out.mutable_identification()->ParseFromString(job.spec);
  } else if (job.kind == "validation") {
    out.mutable_validation()->ParseFromString(job.spec);
  }
  v1::JobProgress* p = out.mutable_progress();
  p->set_pass(static_cast<uint32_t>(job.pass));
  p->set_passes(static_cast<uint32_t>(job.passes));
  p->set_sample(static_cast<uint64_t>(job.sample));
  p->set_samples(static_cast<uint64_t>(job.samples));
  for (double v : job.theta) p->add_theta(v);
  if (job.error_code != 0) {
    out.mutable_error()->set_code(job.error_code);
    out.mutable_error()->set_message(job.error_message);
  }
  set_timestamp(job.created_ms, out.mutable_created());
  if (job.started_ms != 0) set_timestamp(job.started_ms, out.mutable_started());
  if (job.finished_ms != 0) set_timestamp(job.finished_ms, out.mutable_finished());
  return out;
}

grpc::Status JobServiceImpl::SubmitIdentification(grpc::ServerContext* context, const v1::IdentificationSpec* spec,
                                                   v1::Job* response) {
  auto job = jobs_.submit_identification(auth_.tenant(*context), *spec);
  if (!job.is_ok()) return to_grpc(job.status());
  *response = to_proto(job.value());
  return grpc::Status::OK;
}

grpc::Status JobServiceImpl::SubmitValidation(grpc::ServerContext* context, const v1::ValidationSpec* spec,
                                              v1::Job* response) {
  auto job = jobs_.submit_validation(auth_.tenant(*context), *spec);
  if (!job.is_ok()) return to_grpc(job.status());
  *response = to_proto(job.value());
  return grpc::Status::OK;
}

grpc::Status JobServiceImpl::WatchJob(grpc::ServerContext* context, const v1::WatchJobRequest* request,
                                      grpc::ServerWriter<v1::Job>* writer) {
  const std::string tenant = auth_.tenant(*context);
  std::uint64_t version = 0;
  for (;;) {
    // Short waits, so a client that went away or a deadline is noticed.
    const auto until = std::chrono::steady_clock::now() + std::chrono::milliseconds(500);
    auto job = jobs_.wait_for_change(tenant, request->id(), &version, until);
    if (!job.is_ok()) {
      spdlog::debug("watch ended job={} status=\"{}\"", request->id(), job.status().to_string());
      return to_grpc(job.status());
    }
    if (context->IsCancelled()) return {grpc::StatusCode::CANCELLED, "watch cancelled by the client"};
    if (!writer->Write(to_proto(job.value()))) return {grpc::StatusCode::CANCELLED, "client went away"};
    if (is_terminal(job.value().state)) return grpc::Status::OK;
  }
}

grpc::Status JobServiceImpl::GetJob(grpc::ServerContext* context, const v1::GetJobRequest* request,
                                    v1::Job* response) {
  auto job = jobs_.get(auth_.tenant(*context), request->id());
  if (!job.is_ok()) return to_grpc(job.status());
  *response = to_proto(job.value());
  return grpc::Status::OK;
}

grpc::Status JobServiceImpl::ListJobs(grpc::ServerContext* context, const v1::ListJobsRequest*,
                                      v1::ListJobsResponse* response) {
  auto jobs = jobs_.list(auth_.tenant(*context));
  if (!jobs.is_ok()) return to_grpc(jobs.status());
  for (const JobRecord& job : jobs.value()) *response->add_jobs() = to_proto(job);
  return grpc::Status::OK;
}

grpc::Status JobServiceImpl::CancelJob(grpc::ServerContext* context, const v1::CancelJobRequest* request,
                                       v1::Job* response) {
  auto job = jobs_.cancel(auth_.tenant(*context), request->id());
  if (!job.is_ok()) return to_grpc(job.status());
  *response = to_proto(job.value());
  return grpc::Status::OK;
}

grpc::Status JobServiceImpl::GetResult(grpc::ServerContext* context, const v1::GetResultRequest* request,
                                       v1::JobResult* response) {
  auto encoded = jobs_.result(auth_.tenant(*context), request->job_id());
  if (!encoded.is_ok()) return to_grpc(encoded.status());
  if (!response->ParseFromString(encoded.value())) {
    return to_grpc(internal_error("stored result of job " + request->job_id() + " is unreadable"));
  }
  return grpc::Status::OK;
}

// ---- SessionService -------------------------------------------------------

grpc::Status SessionServiceImpl::CreateSession(grpc::ServerContext* context, const v1::CreateSessionRequest* request,
                                               v1::SessionInfo* response) {
  auto session = sessions_.create(auth_.tenant(*context), *request);
  if (!session.is_ok()) return to_grpc(session.status());
  *response = session.value()->info();
  return grpc::Status::OK;
}

grpc::Status SessionServiceImpl::GetSession(grpc::ServerContext* context, const v1::GetSessionRequest* request,
                                            v1::SessionInfo* response) {
  auto session = sessions_.get(auth_.tenant(*context), request->id());
  if (!session.is_ok()) return to_grpc(session.status());
  *response = session.value()->info();
  return grpc::Status::OK;
}

grpc::Status SessionServiceImpl::ListSessions(grpc::ServerContext* context, const v1::ListSessionsRequest*,
                                              v1::ListSessionsResponse* response) {
  Result<std::vector<v1::SessionInfo>> listed = sessions_.list(auth_.tenant(*context));
  if (!listed.is_ok()) return to_grpc(listed.status());
  for (v1::SessionInfo& info : listed.value()) *response->add_sessions() = std::move(info);
  return grpc::Status::OK;
}

grpc::Status SessionServiceImpl::CloseSession(grpc::ServerContext* context, const v1::CloseSessionRequest* request,
                                              v1::CloseSessionResponse*) {
  return to_grpc(sessions_.close(auth_.tenant(*context), request->id()));
}

class SessionServiceImpl::StreamReactor final : public grpc::ServerBidiReactor<v1::StreamRequest, v1::StreamResponse> {
 public:
  StreamReactor(SessionServiceImpl& service, grpc::CallbackServerContext* context)
      : service_(service), tenant_(service.auth_.tenant(*context)) {
    {
      std::lock_guard lock(service_.streams_mu_);
      if (!service_.draining_) service_.streams_.insert(this);
      registered_ = !service_.draining_;
    }
    spdlog::debug("stream opened registered={}", registered_);
    if (!registered_) {
      finish({grpc::StatusCode::UNAVAILABLE,
              "riccatid is shutting down; open the stream again on another instance, or on this one after it "
              "restarts"});
      return;
    }
    StartRead(&request_);
  }

  void OnReadDone(bool ok) override {
    if (!ok) return finish(grpc::Status::OK);  // the client is done sending (or gone)
    if (session_ == nullptr) return open();
    if (!request_.has_batch()) return finish(to_grpc(invalid_argument("after StreamOpen, only measurement batches")));
    const auto& measurements = request_.batch().measurements();
    if (measurements.size() > service_.limits_.max_batch) {
      return finish(to_grpc(limit_reached("max_batch", service_.limits_.max_batch,
                                          "a message holds " + std::to_string(measurements.size()) + " measurements")));
    }
    response_.Clear();
    for (const auto& m : measurements) {
      const auto began = std::chrono::steady_clock::now();
      v1::MeasurementResult* result = response_.add_results();
      diverged_ = session_->process(m, full_covariance_, result);
      service_.metrics_.measurement(result->has_estimate(), std::chrono::steady_clock::now() - began);
      if (!diverged_.is_ok()) break;
    }
    service_.sessions_.after_batch(*session_);  // hands a snapshot to the writer when one is due
    std::lock_guard lock(mu_);
    if (finished_) return;  // drained meanwhile: the status is on its way
    writing_ = true;
    StartWrite(&response_);
  }

  void OnWriteDone(bool ok) override {
    std::optional<grpc::Status> pending;
    {
      std::lock_guard lock(mu_);
      writing_ = false;
      pending.swap(pending_finish_);
    }
    if (pending) return finish(*pending);
    if (!ok) return finish(grpc::Status::OK);  // the client went away
    if (!diverged_.is_ok()) return finish(to_grpc(diverged_));
    StartRead(&request_);
  }

  void OnCancel() override { finish({grpc::StatusCode::CANCELLED, "stream cancelled"}); }

  void OnDone() override {
    spdlog::debug("stream done session={}", session_ != nullptr ? session_->id() : "");
    if (registered_) {
      std::lock_guard lock(service_.streams_mu_);
      service_.streams_.erase(this);
      service_.streams_done_.notify_all();
    }
    delete this;
  }

  void drain() {
    finish({grpc::StatusCode::UNAVAILABLE,
            "riccatid is shutting down; the session is stored: open the stream again, on this or another instance "
            "(GetSession gives its time t: send the measurements after t)"});
  }

 private:
  void open() {
    if (!request_.has_open()) return finish(to_grpc(invalid_argument("the first message of a stream must be StreamOpen")));
    full_covariance_ = request_.open().full_covariance();
    auto found = service_.sessions_.get(tenant_, request_.open().session_id());
    if (!found.is_ok()) return finish(to_grpc(found.status()));
    const Status attached = found.value()->attach();
    if (!attached.is_ok()) return finish(to_grpc(attached));
    {
      std::lock_guard lock(mu_);
      if (finished_) {  // drained meanwhile
        found.value()->detach();
        return;
      }
      session_ = found.value();
    }
    StartRead(&request_);
  }

  // Finishes once; while a write is in flight, when it completes.
  void finish(const grpc::Status& status) {
    std::lock_guard lock(mu_);
    if (finished_) return;
    if (writing_) {
      if (!pending_finish_) pending_finish_ = status;
      return;
    }
    finished_ = true;
    // Detached (and its snapshot handed to the writer) before the client
    // hears the status, so that a client that reconnects at once finds the
    // session free.
    if (session_ != nullptr) {
      session_->detach();
      service_.sessions_.save(*session_);
    }
    Finish(status);
  }

  SessionServiceImpl& service_;
  const std::string tenant_;
  bool registered_ = false;
  std::shared_ptr<Session> session_;
  bool full_covariance_ = false;
  v1::StreamRequest request_;
  v1::StreamResponse response_;
  Status diverged_;
  std::mutex mu_;  // finish() may come from drain() on another thread
  bool writing_ = false;
  bool finished_ = false;
  std::optional<grpc::Status> pending_finish_;
};

grpc::ServerBidiReactor<v1::StreamRequest, v1::StreamResponse>* SessionServiceImpl::Stream(
    grpc::CallbackServerContext* context) {
  return new StreamReactor(*this, context);
}

void SessionServiceImpl::drain(std::chrono::steady_clock::time_point deadline) {
  std::unique_lock lock(streams_mu_);
  draining_ = true;
  // Finish() never runs OnDone on this thread (gRPC completes it on its
  // own), so holding streams_mu_ here cannot deadlock with OnDone.
  for (StreamReactor* stream : streams_) stream->drain();
  streams_done_.wait_until(lock, deadline, [&] { return streams_.empty(); });
  spdlog::info("streams drained open={}", streams_.size());
}

SessionServiceImpl::~SessionServiceImpl() = default;

}  // namespace riccati::service
