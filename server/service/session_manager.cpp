#include "service/session_manager.hpp"

#include <spdlog/spdlog.h>

#include <cmath>

#include "service/convert.hpp"

namespace riccati::service {

Session::Session(std::string id, std::string tenant, ModelPtr model, std::unique_ptr<Filter> filter,
                 InitialState initial_state, Eigen::VectorXd x0, Eigen::VectorXd theta0, Eigen::MatrixXd P0)
    : id_(std::move(id)),
      tenant_(std::move(tenant)),
      model_(std::move(model)),
      initial_state_(initial_state),
      x0_(std::move(x0)),
      theta0_(std::move(theta0)),
      P0_(std::move(P0)),
      created_ms_(now_ms()),
      filter_(std::move(filter)),
      u_last_(Eigen::VectorXd::Zero(model_->nu())),
      u_(model_->nu()),
      y_(model_->ny()),
      last_active_ms_(created_ms_),
      last_active_(std::chrono::steady_clock::now()) {}

Status Session::attach() {
  std::lock_guard lock(mu_);
  if (!diverged_.is_ok()) return failed_precondition("session " + id_ + " diverged: " + diverged_.message());
  if (streaming_) return failed_precondition("session " + id_ + " already has a stream attached");
  streaming_ = true;
  last_active_ = std::chrono::steady_clock::now();
  return Status::ok();
}

void Session::detach() {
  std::lock_guard lock(mu_);
  streaming_ = false;
  last_active_ = std::chrono::steady_clock::now();
  last_active_ms_ = now_ms();
}

bool Session::idle_since(std::chrono::steady_clock::time_point t) const {
  std::lock_guard lock(mu_);
  return !streaming_ && last_active_ < t;
}

Status Session::check(const v1::Measurement& m) const {
  if (m.u_size() != model_->nu() || m.y_size() != model_->ny()) {
    return invalid_argument("measurement needs " + std::to_string(model_->nu()) + " inputs and " +
                            std::to_string(model_->ny()) + " outputs (model " + model_->name() + "), got " +
                            std::to_string(m.u_size()) + " and " + std::to_string(m.y_size()));
  }
  if (!std::isfinite(m.t())) return invalid_argument("measurement time is not finite");
  for (int i = 0; i < m.u_size(); ++i) {
    if (!std::isfinite(m.u(i))) {
      return invalid_argument("input " + model_->input_names()[i] + " is not finite at t = " + std::to_string(m.t()));
    }
  }
  for (int i = 0; i < m.y_size(); ++i) {
    if (!std::isfinite(m.y(i))) {
      return invalid_argument("output " + model_->output_names()[i] + " is not finite at t = " +
                              std::to_string(m.t()));
    }
  }
  if (started_ && !(m.t() > filter_->time())) {
    return invalid_argument("time goes backwards (or repeats): t = " + std::to_string(m.t()) +
                            " after t = " + std::to_string(filter_->time()));
  }
  return Status::ok();
}

// The same sequence as an offline run of the filter (identify()): reset and
// update at the first sample, then a step (predict and update) per sample.
Status Session::step(const v1::Measurement& m) {
  std::copy(m.u().begin(), m.u().end(), u_.data());
  std::copy(m.y().begin(), m.y().end(), y_.data());
  if (!started_) {
    Dataset first;
    first.t = Eigen::VectorXd::Constant(1, m.t());
    first.u = u_;
    first.y = y_;
    RICCATI_ASSIGN_OR_RETURN(const Eigen::VectorXd x0, initial_state(*model_, first, initial_state_, x0_, 0));
    Eigen::VectorXd z(model_->nz());
    z << x0, theta0_;
    RICCATI_RETURN_IF_ERROR(filter_->reset(m.t(), z, P0_));
    started_ = true;
    RICCATI_RETURN_IF_ERROR(filter_->update(y_.data(), u_.data()));
  } else {
    RICCATI_RETURN_IF_ERROR(filter_->step(m.t(), u_last_.data(), u_.data(), y_.data()));
  }
  u_last_ = u_;
  return Status::ok();
}

Status Session::process(const v1::Measurement& m, bool full_covariance, v1::MeasurementResult* out) {
  std::lock_guard lock(mu_);
  out->set_sequence(received_++);
  last_active_ = std::chrono::steady_clock::now();
  if (!diverged_.is_ok()) {
    *out->mutable_error() = to_error(diverged_);
    return diverged_;
  }
  const Status refused = check(m);
  if (!refused.is_ok()) {
    *out->mutable_error() = to_error(refused);
    return Status::ok();
  }
  const Status stepped = step(m);
  if (!stepped.is_ok()) {
    // Past the checks above, a failure is the filter's: it diverged (or
    // the model failed) and its estimate can no longer be trusted.
    diverged_ = Status(StatusCode::kFailedPrecondition,
                       "session " + id_ + ": " + stepped.message());
    spdlog::warn("session diverged id={} error=\"{}\"", id_, stepped.message());
    *out->mutable_error() = to_error(diverged_);
    return diverged_;
  }
  ++accepted_;
  v1::Estimate* e = out->mutable_estimate();
  e->set_t(m.t());
  const Eigen::VectorXd& z = filter_->state();
  const Eigen::MatrixXd& P = filter_->covariance();
  copy_values(z, e->mutable_state());
  copy_values(P.diagonal().cwiseMax(0.0).cwiseSqrt(), e->mutable_std());
  if (full_covariance) *e->mutable_covariance() = to_matrix(P);
  copy_values(filter_->predicted_output(), e->mutable_y_predicted());
  copy_values(filter_->innovation(), e->mutable_innovation());
  e->set_nis(filter_->nis());
  copy_values(filter_->estimated_inputs(), e->mutable_estimated_inputs());
  copy_values(filter_->equation_residuals(), e->mutable_residuals());
  return Status::ok();
}

v1::SessionInfo Session::info() const {
  std::lock_guard lock(mu_);
  v1::SessionInfo info;
  info.set_id(id_);
  info.set_model(model_->name());
  info.set_filter(to_proto(filter_->settings().kind));
  info.set_state(!diverged_.is_ok() ? v1::SESSION_STATE_DIVERGED
                                    : (streaming_ ? v1::SESSION_STATE_STREAMING : v1::SESSION_STATE_IDLE));
  info.set_measurements(accepted_);
  if (started_) {
    info.set_t(filter_->time());
    copy_values(filter_->state(), info.mutable_state_estimate());
  }
  set_timestamp(created_ms_, info.mutable_created());
  set_timestamp(last_active_ms_, info.mutable_last_active());
  if (!diverged_.is_ok()) *info.mutable_error() = to_error(diverged_);
  return info;
}

SessionManager::SessionManager(const ModelRegistry& models, std::chrono::seconds idle_timeout, Limits limits)
    : models_(models), idle_timeout_(idle_timeout), limits_(limits) {
  reaper_ = std::thread([this] {
    std::unique_lock lock(mu_);
    const auto period = std::max<std::chrono::milliseconds>(std::chrono::milliseconds(200),
                                                            std::chrono::milliseconds(idle_timeout_) / 4);
    while (!stop_cv_.wait_for(lock, period, [this] { return stopping_; })) {
      lock.unlock();
      expire_idle();
      lock.lock();
    }
  });
}

SessionManager::~SessionManager() {
  {
    std::lock_guard lock(mu_);
    stopping_ = true;
  }
  stop_cv_.notify_all();
  reaper_.join();
}

Result<std::shared_ptr<Session>> SessionManager::create(const std::string& tenant,
                                                        const v1::CreateSessionRequest& request) {
  ModelPtr model = models_.find(request.model());
  if (model == nullptr) return not_found("no model \"" + request.model() + "\" is loaded");
  RICCATI_ASSIGN_OR_RETURN(const FilterSettings settings, from_proto(request.filter(), *model));
  InitialState mode;
  Eigen::VectorXd x0;
  initial_state_from_proto(request.initial_state(), &mode, &x0);
  if (mode == InitialState::kGiven && x0.size() != model->nx()) {
    return invalid_argument("initial_state.x0 needs " + std::to_string(model->nx()) +
                            " values (or first_measurement = true)");
  }
  if (x0.size() != 0 && x0.size() != model->nx()) {
    return invalid_argument("initial_state.x0 needs " + std::to_string(model->nx()) + " values");
  }
  Eigen::VectorXd theta0 = model->theta_default();
  if (request.theta0_size() != 0) {
    RICCATI_ASSIGN_OR_RETURN(theta0, from_values(request.theta0(), model->ntheta(), "theta0"));
  }
  RICCATI_ASSIGN_OR_RETURN(const Eigen::MatrixXd P0, initial_covariance(request.p0(), request.filter(), *model));
  RICCATI_ASSIGN_OR_RETURN(std::unique_ptr<Filter> filter, make_filter(model, settings));
  // Checks P0 now rather than at the first measurement.
  Eigen::VectorXd z(model->nz());
  z << (x0.size() == model->nx() ? x0 : Eigen::VectorXd::Zero(model->nx())), theta0;
  Status valid = filter->reset(0.0, z, P0);
  if (!valid.is_ok()) return valid;

  auto session = std::make_shared<Session>(new_id("ses"), tenant, model, std::move(filter), mode, x0, theta0, P0);
  {
    std::lock_guard lock(mu_);
    if (static_cast<std::int64_t>(sessions_.size()) >= limits_.max_sessions) {
      return limit_reached("max_sessions", limits_.max_sessions, "riccatid has that many sessions open");
    }
    const auto own = std::count_if(sessions_.begin(), sessions_.end(),
                                   [&](const auto& entry) { return entry.second->tenant() == tenant; });
    if (own >= limits_.max_tenant_sessions) {
      return limit_reached("max_tenant_sessions", limits_.max_tenant_sessions,
                           "this tenant has that many sessions open; close one (CloseSession) first");
    }
    sessions_[session->id()] = session;
  }
  spdlog::info("session created id={} model={} tenant={}", session->id(), model->name(), tenant);
  return session;
}

Result<std::shared_ptr<Session>> SessionManager::get(const std::string& tenant, const std::string& id) {
  std::lock_guard lock(mu_);
  auto it = sessions_.find(id);
  if (it == sessions_.end() || it->second->tenant() != tenant) return not_found("no session " + id);
  return it->second;
}

std::vector<std::shared_ptr<Session>> SessionManager::list(const std::string& tenant) {
  std::vector<std::shared_ptr<Session>> out;
  std::lock_guard lock(mu_);
  for (const auto& [id, s] : sessions_) {
    if (s->tenant() == tenant) out.push_back(s);
  }
  return out;
}

Status SessionManager::close(const std::string& tenant, const std::string& id) {
  std::lock_guard lock(mu_);
  auto it = sessions_.find(id);
  if (it == sessions_.end() || it->second->tenant() != tenant) return not_found("no session " + id);
  sessions_.erase(it);
  spdlog::info("session closed id={}", id);
  return Status::ok();
}

std::size_t SessionManager::size() {
  std::lock_guard lock(mu_);
  return sessions_.size();
}

std::size_t SessionManager::expire_idle() {
  const auto cutoff = std::chrono::steady_clock::now() - idle_timeout_;
  std::size_t expired = 0;
  std::lock_guard lock(mu_);
  for (auto it = sessions_.begin(); it != sessions_.end();) {
    if (it->second->idle_since(cutoff)) {
      spdlog::info("session expired id={}", it->first);
      it = sessions_.erase(it);
      ++expired;
    } else {
      ++it;
    }
  }
  return expired;
}

}  // namespace riccati::service
