#include "commands.hpp"

#include "csv/csv.hpp"
#include "live_view.hpp"

#include <google/protobuf/util/json_util.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <sstream>
#include <thread>

namespace riccati::cli {

namespace {

constexpr std::size_t kChunkBytes = 64 * 1024;

std::string to_json(const google::protobuf::Message& m) {
  std::string out;
  google::protobuf::util::JsonPrintOptions options;
  options.add_whitespace = true;
  options.preserve_proto_field_names = true;
  (void)google::protobuf::util::MessageToJsonString(m, &out, options);
  return out;
}

std::string format(const char* fmt, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, fmt, v);
  return buf;
}

const char* state_name(v1::JobState s) {
  switch (s) {
    case v1::JOB_STATE_QUEUED: return "queued";
    case v1::JOB_STATE_RUNNING: return "running";
    case v1::JOB_STATE_SUCCEEDED: return "succeeded";
    case v1::JOB_STATE_FAILED: return "failed";
    case v1::JOB_STATE_CANCELLED: return "cancelled";
    default: return "unknown";
  }
}

bool is_local_file(const std::string& s) {
  std::error_code ec;
  return std::filesystem::is_regular_file(s, ec);
}

double element(const v1::Matrix& m, uint32_t i, uint32_t j) { return m.values(static_cast<int>(i + j * m.rows())); }

std::string job_line(const v1::Job& j) {
  std::string kind = j.has_identification() ? "identification" : "validation";
  std::string model = j.has_identification() ? j.identification().model() : j.validation().model();
  std::string progress;
  if (j.progress().passes() > 0) {
    progress = "pass " + std::to_string(j.progress().pass()) + "/" + std::to_string(j.progress().passes());
  }
  char line[256];
  std::snprintf(line, sizeof line, "%-22s %-15s %-10s %-20s %s", j.id().c_str(), kind.c_str(), state_name(j.state()),
                model.c_str(), progress.c_str());
  return line;
}

// Parameters from a finished identification job id, a YAML file with
// `theta: [...]`, or a list of numbers.
bool resolve_parameters(Client& c, const std::string& params, v1::ValidationSpec* spec, std::vector<double>* theta,
                        std::string* error) {
  if (params.rfind("job-", 0) == 0) {
    if (spec != nullptr) {
      spec->set_identification_job_id(params);
      return true;
    }
    auto ctx = c.context();
    v1::GetResultRequest request;
    request.set_job_id(params);
    v1::JobResult r;
    const grpc::Status s = c.jobs->GetResult(ctx.get(), request, &r);
    if (!s.ok()) {
      *error = "job " + params + ": " + s.error_message();
      return false;
    }
    theta->assign(r.identification().theta_mean().begin(), r.identification().theta_mean().end());
    return true;
  }
  if (is_local_file(params)) {
    try {
      const YAML::Node root = YAML::LoadFile(params);
      theta->clear();
      for (const auto& v : root["theta"]) theta->push_back(v.as<double>());
    } catch (const YAML::Exception& e) {
      *error = params + ": " + e.what() + " (expected a YAML file with theta: [...])";
      return false;
    }
  } else if (!parse_list(params, theta, error)) {
    *error = "--params: " + *error + " (give a job id, a YAML file or a list of numbers)";
    return false;
  }
  if (spec != nullptr) {
    for (double v : *theta) spec->mutable_theta()->add_values(v);
  }
  return true;
}

// Uploads `data` when it is a local file; otherwise it is a dataset id.
int dataset_for(Client& c, const std::string& data, const std::vector<std::string>& inputs,
                const std::vector<std::string>& outputs, const std::string& time, std::string* id) {
  if (!is_local_file(data)) {
    *id = data;
    return kExitOk;
  }
  UploadOptions upload{data, std::filesystem::path(data).filename().string(), time, inputs, outputs};
  const int rc = data_upload(c, upload, id);
  if (rc == kExitOk) std::fprintf(stderr, "uploaded %s as dataset %s\n", data.c_str(), id->c_str());
  return rc;
}

v1::ModelInfo* cached_model(Client& c, const std::string& name, grpc::Status* status) {
  static v1::ModelInfo info;
  auto ctx = c.context();
  v1::GetModelRequest request;
  request.set_name(name);
  *status = c.models->GetModel(ctx.get(), request, &info);
  return status->ok() ? &info : nullptr;
}

// Watches a job, with a progress bar on stderr when it is a terminal.
int watch_until_done(Client& c, const std::string& id, v1::Job* last) {
  auto ctx = c.stream_context();
  v1::WatchJobRequest request;
  request.set_id(id);
  auto reader = c.jobs->WatchJob(ctx.get(), request);
  const bool tty = isatty(STDERR_FILENO) != 0 && !c.json;
  uint32_t last_pass_printed = 0;
  while (reader->Read(last)) {
    const auto& p = last->progress();
    if (tty && p.samples() > 0 && p.passes() > 0) {
      const double done = ((p.pass() > 0 ? p.pass() - 1 : 0) + double(p.sample()) / double(p.samples())) / p.passes();
      const int width = 30;
      const int filled = static_cast<int>(done * width);
      std::string theta;
      for (double v : p.theta()) theta += format(" %.5g", v);
      std::fprintf(stderr, "\r[%-*s] pass %u/%u sample %llu/%llu theta%s   ", width, std::string(filled, '#').c_str(),
                   p.pass(), p.passes(), static_cast<unsigned long long>(p.sample()),
                   static_cast<unsigned long long>(p.samples()), theta.c_str());
    } else if (!tty && !c.json && p.pass() != last_pass_printed && p.sample() == p.samples() && p.pass() > 0) {
      std::fprintf(stderr, "pass %u/%u done\n", p.pass(), p.passes());
      last_pass_printed = p.pass();
    }
  }
  if (tty) std::fprintf(stderr, "\n");
  const grpc::Status s = reader->Finish();
  if (!s.ok()) return c.fail("watching job " + id, s);
  if (last->state() != v1::JOB_STATE_SUCCEEDED) {
    std::fprintf(stderr, "riccati: job %s %s: %s\n", id.c_str(), state_name(last->state()),
                 last->error().message().c_str());
    return kExitFailed;
  }
  return kExitOk;
}

}  // namespace

int exit_code_for(grpc::StatusCode code) {
  switch (code) {
    case grpc::StatusCode::OK: return kExitOk;
    case grpc::StatusCode::UNAVAILABLE:
    case grpc::StatusCode::DEADLINE_EXCEEDED: return kExitUnreachable;
    case grpc::StatusCode::NOT_FOUND: return kExitNotFound;
    default: return kExitFailed;
  }
}

Client::Client(const Connection& connection, double timeout, bool json_output)
    : timeout_s(timeout), json(json_output), token_(connection.token) {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(-1);  // results of long identifications are large
  connection.apply(&args);
  channel = grpc::CreateCustomChannel(connection.server, connection.credentials(), args);
  models = v1::ModelService::NewStub(channel);
  datasets = v1::DatasetService::NewStub(channel);
  jobs = v1::JobService::NewStub(channel);
  sessions = v1::SessionService::NewStub(channel);
  health = grpc::health::v1::Health::NewStub(channel);
}

std::unique_ptr<grpc::ClientContext> Client::context() const {
  auto ctx = stream_context();
  ctx->set_deadline(std::chrono::system_clock::now() +
                    std::chrono::milliseconds(static_cast<long long>(timeout_s * 1000)));
  return ctx;
}

std::unique_ptr<grpc::ClientContext> Client::stream_context() const {
  auto ctx = std::make_unique<grpc::ClientContext>();
  if (!token_.empty()) ctx->AddMetadata("authorization", "Bearer " + token_);
  return ctx;
}

int Client::fail(const std::string& what, const grpc::Status& status) const {
  std::fprintf(stderr, "riccati: %s: %s\n", what.c_str(), status.error_message().c_str());
  return exit_code_for(status.error_code());
}

std::string parameter_table(const v1::IdentificationResult& r, const std::vector<double>& initial,
                            const std::vector<double>& truth) {
  const int n = r.param_names_size();
  const bool with_truth = static_cast<int>(truth.size()) == n;
  const bool with_initial = static_cast<int>(initial.size()) == n;
  std::string out;
  char line[256];
  std::snprintf(line, sizeof line, "%-10s %12s %14s %12s %12s", "parameter", "initial", "estimate", "std", "final");
  out += line;
  if (with_truth) {
    std::snprintf(line, sizeof line, " %12s %9s", "true", "error %");
    out += line;
  }
  out += "\n";
  for (int i = 0; i < n; ++i) {
    std::snprintf(line, sizeof line, "%-10s %12s %14.8g %12.4g %12.6g", r.param_names(i).c_str(),
                  with_initial ? format("%.6g", initial[i]).c_str() : "-", r.theta_mean(i), r.theta_std(i),
                  r.theta(i));
    out += line;
    if (with_truth) {
      std::snprintf(line, sizeof line, " %12.6g %9.3f", truth[i], 100.0 * (r.theta_mean(i) - truth[i]) / truth[i]);
      out += line;
    }
    out += "\n";
  }
  out += "(estimate: mean over the last pass, as the 1999 toolbox reports; std: at the end)\n";
  return out;
}

std::string fit_table(const v1::ValidationResult& r) {
  std::string out;
  char line[256];
  std::snprintf(line, sizeof line, "%-12s %12s %10s %10s %12s\n", "output", "RMSE", "fit %", "VAF %", "RRSE");
  out += line;
  for (const auto& f : r.fits()) {
    std::snprintf(line, sizeof line, "%-12s %12.4g %10.3f %10.3f %12.4g\n", f.name().c_str(), f.rmse(),
                  f.fit_percent(), f.vaf_percent(), f.rrse());
    out += line;
  }
  return out;
}

int health(Client& c, const std::string& service) {
  using grpc::health::v1::HealthCheckResponse;
  auto ctx = c.context();
  grpc::health::v1::HealthCheckRequest request;
  request.set_service(service);
  HealthCheckResponse response;
  const grpc::Status s = c.health->Check(ctx.get(), request, &response);
  const std::string what = service.empty() ? "health" : "health of service \"" + service + "\"";
  std::string status;
  int code = kExitOk;
  if (s.ok()) {
    status = HealthCheckResponse::ServingStatus_Name(response.status());
    if (response.status() != HealthCheckResponse::SERVING) code = kExitFailed;
  } else if (s.error_code() == grpc::StatusCode::NOT_FOUND) {
    // Check answers NOT_FOUND for a service it does not know (Watch would
    // send SERVICE_UNKNOWN): print it as Watch would.
    status = HealthCheckResponse::ServingStatus_Name(HealthCheckResponse::SERVICE_UNKNOWN);
    code = kExitNotFound;
  } else {
    return c.fail(what, s);
  }
  if (c.json) {
    std::printf("{\n  \"service\": \"%s\",\n  \"status\": \"%s\"\n}\n", service.c_str(), status.c_str());
  } else {
    std::printf("%s\n", status.c_str());
  }
  if (code != kExitOk) std::fprintf(stderr, "riccati: %s: %s\n", what.c_str(), status.c_str());
  return code;
}

int models_list(Client& c) {
  auto ctx = c.context();
  v1::ListModelsResponse list;
  const grpc::Status s = c.models->ListModels(ctx.get(), {}, &list);
  if (!s.ok()) return c.fail("listing models", s);
  if (c.json) {
    std::printf("%s\n", to_json(list).c_str());
    return kExitOk;
  }
  std::printf("%-22s %4s %7s %4s %4s  %s\n", "model", "nx", "ntheta", "nu", "ny", "description");
  for (const auto& m : list.models()) {
    std::printf("%-22s %4d %7d %4d %4d  %s\n", m.name().c_str(), m.state_names_size(), m.param_names_size(),
                m.input_names_size(), m.output_names_size(), m.description().c_str());
  }
  return kExitOk;
}

int models_show(Client& c, const std::string& name) {
  grpc::Status s;
  const v1::ModelInfo* info = cached_model(c, name, &s);
  if (info == nullptr) return c.fail("model " + name, s);
  if (c.json) {
    std::printf("%s\n", to_json(*info).c_str());
    return kExitOk;
  }
  auto names = [](const auto& list) {
    std::string out;
    for (const auto& n : list) out += (out.empty() ? "" : ", ") + n;
    return out;
  };
  std::printf("%s %s: %s\n", info->name().c_str(), info->version().c_str(), info->description().c_str());
  std::printf("  states:  %s\n  inputs:  %s\n  outputs: %s\n", names(info->state_names()).c_str(),
              names(info->input_names()).c_str(), names(info->output_names()).c_str());
  std::printf("  Jacobians: f %s, g %s\n", info->exact_f_jacobian() ? "exact" : "finite differences",
              info->exact_g_jacobian() ? "exact" : "finite differences");
  std::printf("  %-10s %12s %12s %12s\n", "parameter", "default", "lower", "upper");
  for (int i = 0; i < info->param_names_size(); ++i) {
    std::printf("  %-10s %12.6g %12.6g %12.6g\n", info->param_names(i).c_str(), info->theta_default(i),
                info->theta_lower(i), info->theta_upper(i));
  }
  return kExitOk;
}

int data_upload(Client& c, const UploadOptions& o, std::string* dataset_id) {
  std::ifstream in(o.file, std::ios::binary);
  if (!in) {
    std::fprintf(stderr, "riccati: cannot open %s\n", o.file.c_str());
    return kExitUsage;
  }
  auto ctx = c.stream_context();
  v1::DatasetInfo info;
  auto writer = c.datasets->UploadDataset(ctx.get(), &info);
  v1::UploadDatasetRequest header;
  auto* h = header.mutable_header();
  h->set_name(o.name.empty() ? std::filesystem::path(o.file).filename().string() : o.name);
  h->set_time_column(o.time);
  for (const auto& i : o.inputs) h->add_input_columns(i);
  for (const auto& n : o.outputs) h->add_output_columns(n);
  bool open = writer->Write(header);
  std::string buffer(kChunkBytes, '\0');
  while (open && in) {
    in.read(buffer.data(), static_cast<std::streamsize>(buffer.size()));
    const auto got = in.gcount();
    if (got <= 0) break;
    v1::UploadDatasetRequest chunk;
    chunk.set_chunk(buffer.data(), static_cast<std::size_t>(got));
    open = writer->Write(chunk);
  }
  writer->WritesDone();
  const grpc::Status s = writer->Finish();
  if (!s.ok()) return c.fail("uploading " + o.file, s);
  if (dataset_id != nullptr) {
    *dataset_id = info.id();
    return kExitOk;
  }
  if (c.json) {
    std::printf("%s\n", to_json(info).c_str());
  } else {
    std::printf("%s\n", info.id().c_str());
  }
  return kExitOk;
}

int data_list(Client& c) {
  auto ctx = c.context();
  v1::ListDatasetsResponse list;
  const grpc::Status s = c.datasets->ListDatasets(ctx.get(), {}, &list);
  if (!s.ok()) return c.fail("listing datasets", s);
  if (c.json) {
    std::printf("%s\n", to_json(list).c_str());
    return kExitOk;
  }
  std::printf("%-22s %-24s %8s %12s %12s\n", "id", "name", "samples", "t start", "t end");
  for (const auto& d : list.datasets()) {
    std::printf("%-22s %-24s %8llu %12.6g %12.6g\n", d.id().c_str(), d.name().c_str(),
                static_cast<unsigned long long>(d.samples()), d.t_start(), d.t_end());
  }
  return kExitOk;
}

int data_show(Client& c, const std::string& id) {
  auto ctx = c.context();
  v1::GetDatasetRequest request;
  request.set_id(id);
  v1::DatasetInfo info;
  const grpc::Status s = c.datasets->GetDataset(ctx.get(), request, &info);
  if (!s.ok()) return c.fail("dataset " + id, s);
  if (c.json) {
    std::printf("%s\n", to_json(info).c_str());
    return kExitOk;
  }
  std::string inputs, outputs;
  for (const auto& n : info.input_names()) inputs += (inputs.empty() ? "" : ", ") + n;
  for (const auto& n : info.output_names()) outputs += (outputs.empty() ? "" : ", ") + n;
  std::printf("%s  %s\n  samples: %llu, t from %.6g to %.6g s\n  inputs:  %s\n  outputs: %s\n  size: %llu bytes\n",
              info.id().c_str(), info.name().c_str(), static_cast<unsigned long long>(info.samples()), info.t_start(),
              info.t_end(), inputs.c_str(), outputs.c_str(), static_cast<unsigned long long>(info.size_bytes()));
  return kExitOk;
}

int data_delete(Client& c, const std::string& id) {
  auto ctx = c.context();
  v1::DeleteDatasetRequest request;
  request.set_id(id);
  v1::DeleteDatasetResponse response;
  const grpc::Status s = c.datasets->DeleteDataset(ctx.get(), request, &response);
  if (!s.ok()) return c.fail("deleting dataset " + id, s);
  return kExitOk;
}

int identify(Client& c, const RunSettings& settings, bool wait) {
  if (!settings.model || !settings.data) {
    std::fprintf(stderr, "riccati: identify needs --model and --data (or model: and data: in --config)\n");
    return kExitUsage;
  }
  std::string dataset;
  if (const int rc = dataset_for(c, *settings.data, settings.inputs, settings.outputs, "t", &dataset); rc != kExitOk) {
    return rc;
  }
  const v1::IdentificationSpec spec = to_identification_spec(settings, dataset);
  v1::Job job;
  {
    auto ctx = c.context();
    const grpc::Status s = c.jobs->SubmitIdentification(ctx.get(), spec, &job);
    if (!s.ok()) return c.fail("submitting the identification", s);
  }
  if (!wait) {
    std::printf("%s\n", c.json ? to_json(job).c_str() : job.id().c_str());
    return kExitOk;
  }
  std::fprintf(stderr, "job %s\n", job.id().c_str());
  v1::Job last;
  if (const int rc = watch_until_done(c, job.id(), &last); rc != kExitOk) return rc;
  return result(c, job.id(), c.json ? "json" : "table", "", settings.truth.value_or(std::vector<double>{}));
}

int jobs_list(Client& c) {
  auto ctx = c.context();
  v1::ListJobsResponse list;
  const grpc::Status s = c.jobs->ListJobs(ctx.get(), {}, &list);
  if (!s.ok()) return c.fail("listing jobs", s);
  if (c.json) {
    std::printf("%s\n", to_json(list).c_str());
    return kExitOk;
  }
  std::printf("%-22s %-15s %-10s %-20s %s\n", "id", "kind", "state", "model", "progress");
  for (const auto& j : list.jobs()) std::printf("%s\n", job_line(j).c_str());
  return kExitOk;
}

int job_show(Client& c, const std::string& id) {
  auto ctx = c.context();
  v1::GetJobRequest request;
  request.set_id(id);
  v1::Job job;
  const grpc::Status s = c.jobs->GetJob(ctx.get(), request, &job);
  if (!s.ok()) return c.fail("job " + id, s);
  if (c.json) {
    std::printf("%s\n", to_json(job).c_str());
  } else {
    std::printf("%s\n", job_line(job).c_str());
    if (job.has_error()) std::printf("  error: %s\n", job.error().message().c_str());
  }
  return kExitOk;
}

int job_watch(Client& c, const std::string& id) {
  v1::Job last;
  const int rc = watch_until_done(c, id, &last);
  if (c.json) std::printf("%s\n", to_json(last).c_str());
  return rc;
}

int job_cancel(Client& c, const std::string& id) {
  auto ctx = c.context();
  v1::CancelJobRequest request;
  request.set_id(id);
  v1::Job job;
  const grpc::Status s = c.jobs->CancelJob(ctx.get(), request, &job);
  if (!s.ok()) return c.fail("cancelling job " + id, s);
  std::printf("%s\n", c.json ? to_json(job).c_str() : job_line(job).c_str());
  return kExitOk;
}

int result(Client& c, const std::string& id, const std::string& format_name, const std::string& output,
           const std::vector<double>& truth) {
  v1::JobResult r;
  v1::Job job;
  {
    auto ctx = c.context();
    v1::GetResultRequest request;
    request.set_job_id(id);
    const grpc::Status s = c.jobs->GetResult(ctx.get(), request, &r);
    if (!s.ok()) return c.fail("result of job " + id, s);
  }
  {
    auto ctx = c.context();
    v1::GetJobRequest request;
    request.set_id(id);
    (void)c.jobs->GetJob(ctx.get(), request, &job);
  }
  std::string text;
  if (format_name == "json") {
    text = to_json(r) + "\n";
  } else if (format_name == "csv") {
    std::ostringstream csv;
    csv.precision(17);
    if (r.has_identification()) {
      const auto& id_r = r.identification();
      const auto& last = id_r.passes(id_r.passes_size() - 1);
      csv << "t";
      for (uint32_t i = 0; i < id_r.x_trace().rows(); ++i) csv << ",x" << i + 1;
      for (const auto& n : id_r.param_names()) csv << "," << n;
      for (uint32_t i = 0; i < id_r.y_model().rows(); ++i) csv << ",y_model" << i + 1;
      for (uint32_t i = 0; i < id_r.innovations().rows(); ++i) csv << ",innovation" << i + 1;
      csv << "\n";
      for (int k = 0; k < id_r.t_size(); ++k) {
        csv << id_r.t(k);
        for (uint32_t i = 0; i < id_r.x_trace().rows(); ++i) csv << "," << element(id_r.x_trace(), i, k);
        for (uint32_t i = 0; i < last.theta_trace().rows(); ++i) csv << "," << element(last.theta_trace(), i, k);
        for (uint32_t i = 0; i < id_r.y_model().rows(); ++i) csv << "," << element(id_r.y_model(), i, k);
        for (uint32_t i = 0; i < id_r.innovations().rows(); ++i) csv << "," << element(id_r.innovations(), i, k);
        csv << "\n";
      }
    } else {
      const auto& v = r.validation();
      csv << "t";
      for (const auto& f : v.fits()) csv << "," << f.name() << "_measured";
      for (const auto& f : v.fits()) csv << "," << f.name() << "_simulated";
      csv << "\n";
      for (int k = 0; k < v.t_size(); ++k) {
        csv << v.t(k);
        for (uint32_t i = 0; i < v.y_measured().rows(); ++i) csv << "," << element(v.y_measured(), i, k);
        for (uint32_t i = 0; i < v.y_simulated().rows(); ++i) csv << "," << element(v.y_simulated(), i, k);
        csv << "\n";
      }
    }
    text = csv.str();
  } else if (format_name == "table") {
    if (r.has_identification()) {
      const auto& spec = job.identification();
      std::vector<double> initial(spec.theta0().begin(), spec.theta0().end());
      text = parameter_table(r.identification(), initial, truth);
      const auto& last = r.identification().passes(r.identification().passes_size() - 1);
      std::string rms;
      for (double v : last.innovation_rms()) rms += format(" %.3g", v);
      text += "innovation RMS (last pass):" + rms + "; mean NIS " + format("%.3g", last.nis_mean()) + "\n";
    } else {
      text = fit_table(r.validation());
    }
  } else {
    std::fprintf(stderr, "riccati: unknown format \"%s\" (table, json or csv)\n", format_name.c_str());
    return kExitUsage;
  }
  if (output.empty()) {
    std::fputs(text.c_str(), stdout);
  } else {
    std::ofstream out(output);
    out << text;
    if (!out) {
      std::fprintf(stderr, "riccati: cannot write %s\n", output.c_str());
      return kExitUsage;
    }
  }
  return kExitOk;
}

int validate(Client& c, const ValidateOptions& o) {
  const RunSettings& s = o.settings;
  std::string dataset;
  if (const int rc = dataset_for(c, s.data.value_or(""), s.inputs, s.outputs, "t", &dataset); rc != kExitOk) return rc;
  v1::ValidationSpec spec = to_validation_spec(s, dataset);
  std::string error;
  std::vector<double> theta;
  if (!resolve_parameters(c, o.params, &spec, &theta, &error)) {
    std::fprintf(stderr, "riccati: %s\n", error.c_str());
    return kExitUsage;
  }
  v1::Job job;
  {
    auto ctx = c.context();
    const grpc::Status status = c.jobs->SubmitValidation(ctx.get(), spec, &job);
    if (!status.ok()) return c.fail("submitting the validation", status);
  }
  v1::Job last;
  if (const int rc = watch_until_done(c, job.id(), &last); rc != kExitOk) return rc;
  return result(c, job.id(), c.json ? "json" : "table", "", {});
}

int stream(Client& c, const StreamOptions& o) {
  const RunSettings& s = o.settings;
  if (!s.model) {
    std::fprintf(stderr, "riccati: stream needs --model\n");
    return kExitUsage;
  }
  // Each row: t, then the inputs, then the outputs.
  std::vector<std::string> columns{o.time};
  columns.insert(columns.end(), s.inputs.begin(), s.inputs.end());
  columns.insert(columns.end(), s.outputs.begin(), s.outputs.end());
  csv::Table table;
  if (auto error = csv::read_file(o.file, columns, &table)) {
    std::fprintf(stderr, "riccati: %s (stream reads CSV files)\n", error->c_str());
    return kExitUsage;
  }
  grpc::Status status;
  const v1::ModelInfo* info = cached_model(c, *s.model, &status);
  if (info == nullptr) return c.fail("model " + *s.model, status);
  const v1::CreateSessionRequest create = to_session_request(s);
  v1::SessionInfo session;
  {
    auto ctx = c.context();
    status = c.sessions->CreateSession(ctx.get(), create, &session);
    if (!status.ok()) return c.fail("creating the session", status);
  }
  std::fprintf(stderr, "session %s\n", session.id().c_str());

  std::FILE* out = stdout;
  if (!o.output.empty()) {
    out = std::fopen(o.output.c_str(), "w");
    if (out == nullptr) {
      std::fprintf(stderr, "riccati: cannot write %s\n", o.output.c_str());
      return kExitUsage;
    }
  }
  const int nz = info->state_names_size() + info->param_names_size();
  const bool optimal = create.filter().kind() == v1::FILTER_KIND_OPTIMAL;
  std::fprintf(out, "t");
  for (const auto& n : info->state_names()) std::fprintf(out, ",%s", n.c_str());
  for (const auto& n : info->param_names()) std::fprintf(out, ",%s", n.c_str());
  for (const auto& n : info->state_names()) std::fprintf(out, ",std_%s", n.c_str());
  for (const auto& n : info->param_names()) std::fprintf(out, ",std_%s", n.c_str());
  for (const auto& n : info->output_names()) std::fprintf(out, ",innovation_%s", n.c_str());
  std::fprintf(out, ",nis");
  if (optimal) {
    // The estimated inputs and accelerations (named after the positions),
    // then the residuals of the equations of motion, inputs and outputs.
    const int ndof = static_cast<int>(info->ndof());
    for (const auto& n : info->input_names()) std::fprintf(out, ",est_%s", n.c_str());
    for (int i = 0; i < ndof; ++i) std::fprintf(out, ",acc_%s", info->state_names(i).c_str());
    for (int i = 0; i < ndof; ++i) std::fprintf(out, ",res_motion%d", i + 1);
    for (const auto& n : info->input_names()) std::fprintf(out, ",res_%s", n.c_str());
    for (const auto& n : info->output_names()) std::fprintf(out, ",res_%s", n.c_str());
  }
  std::fprintf(out, "\n");
  const bool live = o.live == "always" ||
                    (o.live == "auto" && isatty(STDERR_FILENO) != 0 && (out != stdout || isatty(STDOUT_FILENO) == 0));
  std::unique_ptr<LiveView> view = live ? std::make_unique<LiveView>(*info, stderr) : nullptr;

  auto ctx = c.stream_context();
  auto rpc = c.sessions->Stream(ctx.get());
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(session.id());
  open.mutable_open()->set_full_covariance(o.full_covariance);
  rpc->Write(open);

  using Clock = std::chrono::steady_clock;
  std::mutex mu;
  std::vector<Clock::time_point> sent;  // per batch
  std::vector<double> trips_us;
  std::atomic<std::size_t> estimates{0}, refused{0};
  const auto start = Clock::now();
  // The reader: prints results as they arrive.
  std::thread reader([&] {
    v1::StreamResponse response;
    std::size_t batch = 0;
    while (rpc->Read(&response)) {
      const auto now = Clock::now();
      double trip_us = -1.0;
      {
        std::lock_guard lock(mu);
        if (batch < sent.size()) {
          trip_us = std::chrono::duration<double, std::micro>(now - sent[batch]).count();
          trips_us.push_back(trip_us);
        }
      }
      ++batch;
      for (const auto& r : response.results()) {
        if (r.has_error()) {
          ++refused;
          std::fprintf(stderr, "measurement %llu refused: %s\n", static_cast<unsigned long long>(r.sequence()),
                       r.error().message().c_str());
          continue;
        }
        ++estimates;
        const auto& e = r.estimate();
        std::fprintf(out, "%.17g", e.t());
        for (int i = 0; i < nz; ++i) std::fprintf(out, ",%.17g", e.state(i));
        for (int i = 0; i < nz; ++i) std::fprintf(out, ",%.17g", e.std(i));
        for (double v : e.innovation()) std::fprintf(out, ",%.17g", v);
        std::fprintf(out, ",%.17g", e.nis());
        for (double v : e.estimated_inputs()) std::fprintf(out, ",%.17g", v);
        for (double v : e.residuals()) std::fprintf(out, ",%.17g", v);
        std::fprintf(out, "\n");
        if (view) view->add(e, trip_us);
      }
    }
  });
  // The writer: paces batches at the rate (measurements per second).
  const int batch = std::max(1, o.batch);
  auto next = start;
  const auto period = o.rate > 0 ? std::chrono::duration<double>(batch / o.rate) : std::chrono::duration<double>(0);
  for (std::size_t k = 0; k < table.rows(); k += static_cast<std::size_t>(batch)) {
    if (o.rate > 0) {
      std::this_thread::sleep_until(next);
      next += std::chrono::duration_cast<Clock::duration>(period);
    }
    v1::StreamRequest request;
    for (std::size_t j = k; j < std::min(table.rows(), k + static_cast<std::size_t>(batch)); ++j) {
      const std::span<const double> row = table.row(j);
      const auto inputs_end = row.begin() + 1 + static_cast<std::ptrdiff_t>(s.inputs.size());
      auto* m = request.mutable_batch()->add_measurements();
      m->set_t(row[0]);
      m->mutable_u()->Add(row.begin() + 1, inputs_end);
      m->mutable_y()->Add(inputs_end, row.end());
    }
    {
      std::lock_guard lock(mu);
      sent.push_back(Clock::now());
    }
    if (!rpc->Write(request)) break;
  }
  rpc->WritesDone();
  reader.join();
  if (view) view->finish();
  const grpc::Status finished = rpc->Finish();
  const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
  if (out != stdout) std::fclose(out);
  std::sort(trips_us.begin(), trips_us.end());
  auto pct = [&](double p) {
    return trips_us.empty() ? 0.0 : trips_us[std::min(trips_us.size() - 1, static_cast<std::size_t>(p * trips_us.size()))];
  };
  std::fprintf(stderr, "%zu estimates, %zu refused, %.2f s (%.0f measurements/s), round trip p50 %.0f us, p99 %.0f us\n",
               estimates.load(), refused.load(), seconds, (estimates + refused) / seconds, pct(0.5), pct(0.99));
  if (!o.keep) {
    auto close_ctx = c.context();
    v1::CloseSessionRequest close;
    close.set_id(session.id());
    v1::CloseSessionResponse closed;
    (void)c.sessions->CloseSession(close_ctx.get(), close, &closed);
  }
  if (!finished.ok()) return c.fail("stream", finished);
  return refused > 0 ? kExitFailed : kExitOk;
}

int simulate(Client& c, const SimulateOptions& o) {
  const RunSettings& s = o.settings;
  const std::string model = s.model.value_or("");
  grpc::Status status;
  const v1::ModelInfo* found = cached_model(c, model, &status);
  if (found == nullptr) return c.fail("model " + model, status);
  const v1::ModelInfo& info = *found;  // the default input columns, x0's size and the outputs' names
  const std::vector<std::string> inputs =
      o.input_columns.empty() ? std::vector<std::string>(info.input_names().begin(), info.input_names().end())
                              : o.input_columns;
  std::vector<std::string> columns{o.time};
  columns.insert(columns.end(), inputs.begin(), inputs.end());
  csv::Table table;  // each row: t, then the inputs
  if (auto problem = csv::read_file(o.inputs_file, columns, &table)) {
    std::fprintf(stderr, "riccati: %s\n", problem->c_str());
    return kExitUsage;
  }

  v1::SimulateRequest request;
  request.set_model(model);
  std::string error;
  std::vector<double> theta;
  if (!o.params.empty() && !resolve_parameters(c, o.params, nullptr, &theta, &error)) {
    std::fprintf(stderr, "riccati: %s\n", error.c_str());
    return kExitUsage;
  }
  request.mutable_theta()->Add(theta.begin(), theta.end());
  std::vector<double> x0;
  if (!o.x0.empty() && !parse_list(o.x0, &x0, &error)) {
    std::fprintf(stderr, "riccati: --x0: %s\n", error.c_str());
    return kExitUsage;
  }
  if (x0.empty()) x0.assign(static_cast<std::size_t>(info.state_names_size()), 0.0);
  request.mutable_x0()->Add(x0.begin(), x0.end());
  request.mutable_u()->set_rows(static_cast<uint32_t>(inputs.size()));
  request.mutable_u()->set_cols(static_cast<uint32_t>(table.rows()));
  for (std::size_t k = 0; k < table.rows(); ++k) {
    request.add_t(table.row(k)[0]);
    request.mutable_u()->mutable_values()->Add(table.row(k).begin() + 1, table.row(k).end());  // column-major
  }
  if (s.hold) request.set_hold(static_cast<v1::HoldOrder>(*s.hold));
  if (auto integrator = to_integrator(s)) *request.mutable_integrator() = *integrator;

  v1::SimulateResponse response;
  {
    auto ctx = c.context();
    status = c.models->Simulate(ctx.get(), request, &response);
    if (!status.ok()) return c.fail("simulation", status);
  }
  std::FILE* out = o.output.empty() ? stdout : std::fopen(o.output.c_str(), "w");
  if (out == nullptr) {
    std::fprintf(stderr, "riccati: cannot write %s\n", o.output.c_str());
    return kExitUsage;
  }
  std::fprintf(out, "t");
  for (const auto& n : inputs) std::fprintf(out, ",%s", n.c_str());
  for (const auto& n : info.output_names()) std::fprintf(out, ",%s", n.c_str());
  std::fprintf(out, "\n");
  for (std::size_t k = 0; k < table.rows(); ++k) {
    std::fprintf(out, "%.17g", table.row(k)[0]);
    for (double v : table.row(k).subspan(1)) std::fprintf(out, ",%.17g", v);
    for (uint32_t i = 0; i < response.y().rows(); ++i) {
      std::fprintf(out, ",%.17g", element(response.y(), i, static_cast<uint32_t>(k)));
    }
    std::fprintf(out, "\n");
  }
  if (out != stdout) std::fclose(out);
  return kExitOk;
}

}  // namespace riccati::cli
