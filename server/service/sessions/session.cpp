#include "service/sessions/session.hpp"

#include <spdlog/spdlog.h>

#include "riccati/settings_schema.hpp"
#include "service/convert.hpp"
#include "service/ids.hpp"
#include "service/run_settings.hpp"

namespace riccati::service {

Session::Session(std::string id, std::string tenant, v1::CreateSessionRequest request, std::int64_t created_ms,
                 OnlineRunner runner)
    : id_(std::move(id)),
      tenant_(std::move(tenant)),
      request_(std::move(request)),
      created_ms_(created_ms),
      runner_(std::move(runner)),
      last_active_ms_(created_ms_),
      last_active_(std::chrono::steady_clock::now()) {
  last_snapshot_ = last_active_;
}

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

Status Session::process(const v1::Measurement& m, bool full_covariance, v1::MeasurementResult* out) {
  std::lock_guard lock(mu_);
  // last_active_ is not read while a stream is attached (detach() sets it):
  // no clock read per measurement.
  out->set_sequence(received_++);
  if (!lost_.is_ok()) {
    *out->mutable_error() = to_error(lost_);
    return lost_;
  }
  if (closed_) {  // CloseSession (or expiry) while a batch was being processed
    const Status ended(StatusCode::kFailedPrecondition, "session " + id_ + " was closed: measurement not processed");
    *out->mutable_error() = to_error(ended);
    return ended;
  }
  if (!diverged_.is_ok()) {
    *out->mutable_error() = to_error(diverged_);
    return diverged_;
  }
  const Status advanced = runner_.advance(m.t(), {m.u().data(), static_cast<std::size_t>(m.u_size())},
                                          {m.y().data(), static_cast<std::size_t>(m.y_size())});
  if (!advanced.is_ok() && !runner_.diverged()) {  // this measurement refused; the session goes on
    *out->mutable_error() = to_error(advanced);
    return Status::ok();
  }
  if (runner_.diverged()) {
    diverged_ = Status(StatusCode::kFailedPrecondition, "session " + id_ + ": " + advanced.message());
    spdlog::warn("session diverged id={} error=\"{}\"", id_, advanced.message());
    *out->mutable_error() = to_error(diverged_);
    return diverged_;
  }
  ++accepted_;
  fill_estimate(m.t(), full_covariance, out->mutable_estimate());
  return Status::ok();
}

std::int64_t Session::result_bytes(bool full_covariance) const {
  std::lock_guard lock(mu_);
  const Filter& filter = runner_.filter();
  const auto nz = static_cast<std::int64_t>(filter.state().size());
  const auto values = 2 * nz + 2 * static_cast<std::int64_t>(filter.predicted_output().size()) + 2 +
                      static_cast<std::int64_t>(filter.estimated_inputs().size() + filter.equation_residuals().size()) +
                      (full_covariance ? nz * nz + 2 : 0);
  return 8 * values + 64;  // each value's 8 bytes, and the fields' tags and lengths
}

void Session::fill_estimate(double t, bool full_covariance, v1::Estimate* e) const {
  const Filter& filter = runner_.filter();
  const Eigen::MatrixXd& P = filter.covariance();
  e->set_t(t);
  copy_values(filter.state(), e->mutable_state());
  copy_values(P.diagonal().cwiseMax(0.0).cwiseSqrt(), e->mutable_std());
  if (full_covariance) *e->mutable_covariance() = to_matrix(P);
  copy_values(filter.predicted_output(), e->mutable_y_predicted());
  copy_values(filter.innovation(), e->mutable_innovation());
  e->set_nis(filter.nis());
  copy_values(filter.estimated_inputs(), e->mutable_estimated_inputs());
  copy_values(filter.equation_residuals(), e->mutable_residuals());
}

v1::SessionInfo Session::info() const {
  std::lock_guard lock(mu_);
  v1::SessionInfo info;
  info.set_id(id_);
  info.set_model(runner_.model().name());
  info.set_filter(to_proto(runner_.filter().settings().kind));
  info.set_state(!diverged_.is_ok() ? v1::SESSION_STATE_DIVERGED
                                    : (streaming_ ? v1::SESSION_STATE_STREAMING : v1::SESSION_STATE_IDLE));
  info.set_measurements(accepted_);
  if (runner_.started()) {
    info.set_t(runner_.filter().time());
    copy_values(runner_.filter().state(), info.mutable_state_estimate());
  }
  set_timestamp(created_ms_, info.mutable_created());
  set_timestamp(last_active_ms_, info.mutable_last_active());
  if (!diverged_.is_ok()) *info.mutable_error() = to_error(diverged_);
  *info.mutable_retunings() = retunings_;
  const FilterSettings& settings = runner_.filter().settings();
  if (settings.kind == FilterKind::kOptimal) {
    *info.mutable_v() = to_covariance(settings.optimal.V);
    *info.mutable_w() = to_covariance(settings.optimal.W);
  } else {
    *info.mutable_q() = to_covariance(settings.Q);
    *info.mutable_r() = to_covariance(settings.R);
  }
  return info;
}

Status Session::retune(const v1::RetuneSessionRequest& request) {
  if (!request.has_q() && !request.has_r() && !request.has_v() && !request.has_w()) {
    return invalid_argument("a retuning gives new weights: q and r (EKF, UKF), or v and w (optimal filter)");
  }
  std::lock_guard lock(mu_);
  if (!diverged_.is_ok()) return failed_precondition("session " + id_ + " diverged: " + diverged_.message());
  RICCATI_RETURN_IF_ERROR(check_settings_apply(request, api::choice_of(request_, "filter.kind")));
  v1::FilterSettings filter = request_.filter();
  if (request.has_q()) *filter.mutable_q() = request.q();
  if (request.has_r()) *filter.mutable_r() = request.r();
  if (request.has_v()) *filter.mutable_optimal()->mutable_v() = request.v();
  if (request.has_w()) *filter.mutable_optimal()->mutable_w() = request.w();
  RICCATI_ASSIGN_OR_RETURN(const FilterSettings settings, from_proto(filter, runner_.model()));
  RICCATI_RETURN_IF_ERROR(runner_.retune(settings));
  *request_.mutable_filter() = std::move(filter);
  // The history is the newest kRetuningsKept: it goes into every snapshot
  // and SessionInfo, so it must not grow with a client's retunings.
  if (retunings_.size() >= kRetuningsKept) retunings_.DeleteSubrange(0, retunings_.size() - kRetuningsKept + 1);
  v1::Retuning* retuning = retunings_.Add();
  retuning->set_t(runner_.started() ? runner_.filter().time() : 0.0);
  retuning->set_measurements(accepted_);
  set_timestamp(now_ms(), retuning->mutable_at());
  if (request.has_q()) *retuning->mutable_q() = request.q();
  if (request.has_r()) *retuning->mutable_r() = request.r();
  if (request.has_v()) *retuning->mutable_v() = request.v();
  if (request.has_w()) *retuning->mutable_w() = request.w();
  spdlog::info("session retuned id={} t={} measurements={}", id_, retuning->t(), accepted_);
  return Status::ok();
}

bool Session::latest(v1::Estimate* out, std::uint64_t* accepted) const {
  std::lock_guard lock(mu_);
  *accepted = accepted_;
  if (!runner_.started()) return false;
  fill_estimate(runner_.filter().time(), false, out);
  return true;
}

std::string Session::snapshot(const std::string& instance) const {
  std::lock_guard lock(mu_);
  return encode(instance);
}

std::string Session::encode(const std::string& instance) const {
  internal::SessionSnapshot out;
  *out.mutable_request() = request_;
  out.set_tenant(tenant_);
  out.set_created_ms(created_ms_);
  out.set_last_active_ms(last_active_ms_);
  out.set_instance(instance);
  const OnlineRunner::Snapshot run = runner_.snapshot();
  out.set_started(run.started);
  if (run.started) {
    out.set_t(run.t);
    copy_values(run.z, out.mutable_z());
    *out.mutable_p() = to_matrix(run.P);
    copy_values(run.carried, out.mutable_carried());
    copy_values(run.u_last, out.mutable_u_last());
  }
  out.set_received(received_);
  out.set_accepted(accepted_);
  if (!diverged_.is_ok()) *out.mutable_diverged() = to_error(diverged_);
  out.set_streaming(streaming_);
  *out.mutable_retunings() = retunings_;
  return out.SerializeAsString();
}

bool Session::save(const std::string& instance, const std::function<void(std::string)>& sink) {
  std::lock_guard lock(mu_);
  if (closed_) return false;
  sink(encode(instance));
  received_at_snapshot_ = received_;
  last_snapshot_ = std::chrono::steady_clock::now();
  return true;
}

bool Session::snapshot_due(std::chrono::steady_clock::time_point now, std::chrono::milliseconds interval) const {
  std::lock_guard lock(mu_);
  return !closed_ && received_ != received_at_snapshot_ && (!diverged_.is_ok() || now - last_snapshot_ >= interval);
}

Status Session::restore(const internal::SessionSnapshot& s) {
  std::lock_guard lock(mu_);
  const Model& model = runner_.model();
  const Eigen::Index nz = model.nz(), nu = model.nu();
  OnlineRunner::Snapshot run;
  run.started = s.started();
  if (run.started) {
    if (s.z_size() != nz || s.p().rows() != nz || s.p().cols() != nz || s.p().values_size() != nz * nz ||
        s.u_last_size() != nu) {
      return internal_error("the snapshot of session " + id_ + " does not fit model " + model.name());
    }
    run.t = s.t();
    run.z = Eigen::Map<const Eigen::VectorXd>(s.z().data(), nz);
    run.P = Eigen::Map<const Eigen::MatrixXd>(s.p().values().data(), nz, nz);
    run.carried = Eigen::Map<const Eigen::VectorXd>(s.carried().data(), s.carried_size());
    run.u_last = Eigen::Map<const Eigen::VectorXd>(s.u_last().data(), nu);
  }
  if (s.has_diverged()) run.divergence = from_error(s.diverged(), StatusCode::kFailedPrecondition);
  RICCATI_RETURN_IF_ERROR(runner_.restore(run).with_context("session " + id_));
  diverged_ = run.divergence;
  received_ = received_at_snapshot_ = s.received();
  accepted_ = s.accepted();
  last_active_ms_ = s.last_active_ms();
  retunings_ = s.retunings();
  return Status::ok();
}

void Session::close() {
  closing_.store(true, std::memory_order_relaxed);  // first: a measurement being processed stops (closing())
  std::lock_guard lock(mu_);
  closed_ = true;
}

void Session::lose(const Status& why) {
  std::lock_guard lock(mu_);
  closed_ = true;
  lost_ = why;
}

}  // namespace riccati::service
