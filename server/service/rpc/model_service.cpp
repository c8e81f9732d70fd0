#include "service/rpc/model_service.hpp"

#include <spdlog/spdlog.h>

#include <chrono>

#include "engine/estimation/validation.hpp"
#include "service/convert.hpp"
#include "service/run_settings.hpp"

namespace riccati::service {
namespace {

// What a SimulateRequest asks for, checked against the model.
struct Simulation {
  Eigen::VectorXd t, x0, theta;
  Eigen::MatrixXd u;
  SimulationSettings settings;
};

Result<Simulation> simulation_from_proto(const v1::SimulateRequest& request, const Model& model) {
  Simulation out;
  const Eigen::Index n = request.t_size();
  if (n < 2) return invalid_argument("t needs at least two sample times");
  RICCATI_ASSIGN_OR_RETURN(out.t, from_values(request.t(), n, "t"));
  for (Eigen::Index k = 1; k < n; ++k) {
    if (!(out.t[k] > out.t[k - 1])) return invalid_argument("t is not strictly increasing at index " + std::to_string(k));
  }
  RICCATI_ASSIGN_OR_RETURN(out.u, from_matrix(request.u(), "u"));
  if (out.u.rows() != model.nu() || out.u.cols() != n) {
    return invalid_argument("u must be " + std::to_string(model.nu()) + " x " + std::to_string(n));
  }
  out.theta = model.theta_default();
  if (request.theta_size() != 0) {
    RICCATI_ASSIGN_OR_RETURN(out.theta, from_values(request.theta(), model.ntheta(), "theta"));
  }
  RICCATI_ASSIGN_OR_RETURN(out.x0, from_values(request.x0(), model.nx(), "x0"));
  RICCATI_ASSIGN_OR_RETURN(out.settings.hold, from_proto(request.hold()));
  RICCATI_ASSIGN_OR_RETURN(out.settings.integrator, from_proto(request.integrator()));
  return out;
}

}  // namespace

v1::ModelInfo to_proto(const Model& model, const JacobianCheck& jacobians) {
  v1::ModelInfo info;
  info.set_name(model.name());
  info.set_version(model.version());
  info.set_description(model.description());
  for (const auto& n : model.state_names()) info.add_state_names(n);
  for (const auto& n : model.param_names()) info.add_param_names(n);
  for (const auto& n : model.input_names()) info.add_input_names(n);
  for (const auto& n : model.output_names()) info.add_output_names(n);
  for (const auto& u : model.state_units()) info.add_state_units(u);
  for (const auto& u : model.param_units()) info.add_param_units(u);
  for (const auto& u : model.input_units()) info.add_input_units(u);
  for (const auto& u : model.output_units()) info.add_output_units(u);
  copy_values(model.theta_default(), info.mutable_theta_default());
  copy_values(model.theta_lower(), info.mutable_theta_lower());
  copy_values(model.theta_upper(), info.mutable_theta_upper());
  info.set_exact_f_jacobian(model.has_f_jacobian());
  info.set_exact_g_jacobian(model.has_g_jacobian());
  info.set_ndof(static_cast<uint32_t>(model.ndof()));
  v1::JacobianCheck* check = info.mutable_jacobian_check();
  check->set_checked(jacobians.checked);
  check->set_agrees(jacobians.checked && jacobians.agrees());
  check->set_max_error(jacobians.max_error);
  check->set_detail(jacobians.detail);
  for (const std::string& d : jacobians.disagreements) check->add_disagreements(d);
  return info;
}

v1::ModelInfo to_proto(const CatalogEntry& entry) {
  v1::ModelInfo info = to_proto(*entry.model, entry.jacobian_check);
  if (entry.text != nullptr) {
    v1::TextModelInfo* text = info.mutable_text();
    text->set_revision(static_cast<uint64_t>(entry.revision));
    text->set_sha256(entry.sha256);
    text->set_source(entry.source);
    for (const auto& e : entry.text->equations) text->add_equations(e);
    for (const auto& r : entry.text->f_sparsity) text->add_f_sparsity(r);
    for (const auto& r : entry.text->g_sparsity) text->add_g_sparsity(r);
    text->set_tape_length(entry.text->tape_length);
    for (const std::int64_t r : entry.revisions) text->add_revisions(static_cast<uint64_t>(r));
  }
  return info;
}

v1::ReloadModelsResponse to_proto(const ReloadReport& report) {
  v1::ReloadModelsResponse out;
  for (const auto& n : report.added) out.add_added(n);
  for (const auto& n : report.changed) out.add_changed(n);
  for (const auto& n : report.removed) out.add_removed(n);
  for (const auto& n : report.unchanged) out.add_unchanged(n);
  for (const auto& r : report.refused) {
    v1::RefusedModel* refused = out.add_refused();
    refused->set_path(r.path);
    refused->set_reason(r.reason);
  }
  return out;
}

Result<CatalogEntry> create_model(ModelCatalog& models, const std::string& tenant,
                                  const v1::CreateModelRequest& request) {
  if (request.source().size() > kMaxTextModelBytes) {
    return invalid_argument("the model is " + std::to_string(request.source().size()) +
                            " bytes, more than the limit of " + std::to_string(kMaxTextModelBytes));
  }
  const std::string origin = request.file_name().empty() ? "model" : request.file_name();
  return models.create(tenant, request.source(), origin, request.validate_only());
}

grpc::Status ModelServiceImpl::ListModels(grpc::ServerContext* context, const v1::ListModelsRequest*,
                                          v1::ListModelsResponse* response) {
  const Result<std::vector<CatalogEntry>> entries = models_.list(auth_.tenant(*context));
  if (!entries.is_ok()) return to_grpc(entries.status());
  for (const CatalogEntry& e : entries.value()) *response->add_models() = to_proto(e);
  return grpc::Status::OK;
}

grpc::Status ModelServiceImpl::GetModel(grpc::ServerContext* context, const v1::GetModelRequest* request,
                                        v1::ModelInfo* response) {
  const Result<CatalogEntry> entry = models_.describe(auth_.tenant(*context), request->name());
  if (!entry.is_ok()) return to_grpc(entry.status());
  *response = to_proto(entry.value());
  return grpc::Status::OK;
}

grpc::Status ModelServiceImpl::CreateModel(grpc::ServerContext* context, const v1::CreateModelRequest* request,
                                           v1::ModelInfo* response) {
  const Result<CatalogEntry> entry = create_model(models_, auth_.tenant(*context), *request);
  if (!entry.is_ok()) return to_grpc(entry.status());
  *response = to_proto(entry.value());
  return grpc::Status::OK;
}

// The operator's: the directory is theirs, and a reload changes every
// tenant's models (reloads run one at a time; an unchanged file is not
// loaded or checked again).
grpc::Status ModelServiceImpl::ReloadModels(grpc::ServerContext* context, const v1::ReloadModelsRequest*,
                                            v1::ReloadModelsResponse* response) {
  if (!auth_.is_operator(*context)) return to_grpc(operator_only("ReloadModels"));
  const Result<ReloadReport> report = models_.reload();
  if (!report.is_ok()) return to_grpc(report.status());
  spdlog::info("models reloaded by tenant={}", auth_.tenant(*context));
  *response = to_proto(report.value());
  return grpc::Status::OK;
}

grpc::Status ModelServiceImpl::DeleteModel(grpc::ServerContext* context, const v1::DeleteModelRequest* request,
                                           v1::DeleteModelResponse*) {
  return to_grpc(models_.remove(auth_.tenant(*context), request->name()));
}

// A Simulate call's work is bounded before it starts (samples x substeps,
// and how many run at once) and as it runs (every integration step, an
// adaptive integrator's internal ones included), and it stops within a
// sample once its client has gone or its deadline has passed: an RPC thread
// is never held by work nobody waits for.
grpc::Status ModelServiceImpl::Simulate(grpc::ServerContext* context, const v1::SimulateRequest* request,
                                        v1::SimulateResponse* response) {
  const Result<ModelPtr> m = models_.get(auth_.tenant(*context), request->model());
  if (!m.is_ok()) return to_grpc(m.status());
  const Result<Simulation> s = simulation_from_proto(*request, *m.value());
  if (!s.is_ok()) return to_grpc(s.status());
  const bool fixed_step = is_fixed_step(s->settings.integrator.kind);
  const std::int64_t steps = (s->t.size() - 1) * (fixed_step ? std::int64_t{s->settings.integrator.substeps} : 1);
  if (steps > limits_.max_simulation_steps) {
    return to_grpc(limit_reached("max_simulation_steps", limits_.max_simulation_steps,
                                 std::to_string(s->t.size()) + " samples x " +
                                     std::to_string(s->settings.integrator.substeps) + " substeps are " +
                                     std::to_string(steps) + " steps"));
  }
  struct Running {
    std::atomic<std::int64_t>& count;
    ~Running() { --count; }
  } running{simulations_};
  if (++simulations_ > limits_.max_simulations) {
    return to_grpc(limit_reached("max_simulations", limits_.max_simulations,
                                 "as many simulations are running; try again when one has ended"));
  }
  // Within a sample too: every integration step counts against the limit
  // (an adaptive integrator's internal steps each), and the integrator polls
  // the call's deadline and cancellation (a shutdown's too) as it goes.
  Interrupt interrupt;
  const auto deadline = context->deadline();
  // IsCancelled() polls gRPC's completion queue (a wait of up to ~1.5 ms):
  // asked every 20 ms, the clock at every poll.
  interrupt.poll = [this, context, deadline, asked = std::chrono::steady_clock::time_point()]() mutable -> Status {
    if (draining_.load(std::memory_order_relaxed)) {
      return {StatusCode::kUnavailable, "riccatid is shutting down: the simulation stopped; call again, on this "
                                        "instance once it restarts or on another"};
    }
    if (std::chrono::system_clock::now() >= deadline) {
      return deadline_exceeded("the call's deadline passed during the simulation: it stopped there");
    }
    const auto now = std::chrono::steady_clock::now();
    if (now - asked >= std::chrono::milliseconds(20)) {
      asked = now;
      if (context->IsCancelled()) return cancelled("the call was cancelled during the simulation: it stopped there");
    }
    return Status::ok();
  };
  interrupt.max_steps_total = limits_.max_simulation_steps;
  interrupt.exhausted = [this](std::int64_t taken) {
    return limit_reached("max_simulation_steps", limits_.max_simulation_steps,
                         "the integrator took " + std::to_string(taken) +
                             " steps (an adaptive integrator's internal steps count each); simulate fewer samples, "
                             "loosen the tolerances, or raise --max-simulation-steps");
  };
  InterruptScope under(interrupt);
  Eigen::MatrixXd x;
  const Result<Eigen::MatrixXd> y = simulate(*m.value(), s->t, s->u, s->x0, s->theta, s->settings, &x,
                                             [context] { return context->IsCancelled(); });
  if (!y.is_ok()) return to_grpc(y.status());
  *response->mutable_y() = to_matrix(y.value());
  *response->mutable_x() = to_matrix(x);
  return grpc::Status::OK;
}

}  // namespace riccati::service
