#include "service/run_settings.hpp"

#include <algorithm>

#include "engine/filters/filter_kinds.hpp"
#include "riccati/settings_schema.hpp"
#include "service/convert.hpp"

namespace riccati::service {

Status check_settings_apply(const google::protobuf::Message& request, std::string_view filter) {
  const std::string kind = filter.empty() ? api::choice_of(request, "filter.kind") : std::string(filter);
  const std::string misplaced = api::misplaced_setting(request, api::choice_of(request, "method"), kind);
  if (!misplaced.empty()) return invalid_argument(misplaced);
  return Status::ok();
}

Result<IntegratorSettings> from_proto(const v1::IntegratorSettings& s) {
  IntegratorSettings out;
  RICCATI_RETURN_IF_ERROR(enum_from_proto(s.kind(), *v1::IntegratorKind_descriptor(), &parse_integrator_kind,
                                          "integrator.kind", &out.kind));
  // The engine's range (validate) is 1 to 1000000; a larger count is named
  // here as given, not as it would be once narrowed to an int.
  constexpr uint32_t kMostSubsteps = 1000000;
  if (s.substeps() > kMostSubsteps) {
    return invalid_argument("integrator.substeps " + std::to_string(s.substeps()) + " is over the most, " +
                            std::to_string(kMostSubsteps) + " (use fewer, or an adaptive integrator)");
  }
  if (s.substeps() != 0) out.substeps = static_cast<int>(s.substeps());
  if (s.rtol() != 0.0) out.rtol = s.rtol();
  if (s.atol() != 0.0) out.atol = s.atol();
  if (s.max_steps() != 0) out.max_steps = static_cast<long>(std::min<uint64_t>(s.max_steps(), 1000000000));
  RICCATI_RETURN_IF_ERROR(validate(out));
  return out;
}

Result<HoldOrder> from_proto(v1::HoldOrder hold) {
  HoldOrder out = HoldOrder::kZero;
  RICCATI_RETURN_IF_ERROR(enum_from_proto(hold, *v1::HoldOrder_descriptor(), &parse_hold_order, "hold", &out));
  return out;
}

v1::FilterKind to_proto(FilterKind kind) {
  return static_cast<v1::FilterKind>(enum_to_proto(*v1::FilterKind_descriptor(), filter_kind_name(kind)));
}

namespace {

// Q and R, and how the gain is solved: the EKF's and UKF's settings.
Status covariances_from_proto(const v1::FilterSettings& s, const Model& model, FilterSettings* out) {
  if (s.has_optimal()) {
    return invalid_argument("filter.optimal applies to the optimal filter only, not to " +
                            std::string(filter_kind_name(out->kind)));
  }
  RICCATI_ASSIGN_OR_RETURN(out->Q, from_covariance(s.q(), model.nz(), false, "filter.q"));
  RICCATI_ASSIGN_OR_RETURN(out->R, from_covariance(s.r(), model.ny(), true, "filter.r"));
  RICCATI_RETURN_IF_ERROR(enum_from_proto(s.inversion(), *v1::GainInversion_descriptor(), &parse_gain_inversion,
                                          "filter.inversion", &out->inversion));
  out->joseph = !s.short_covariance_update();
  const v1::UkfSettings& ukf = s.ukf();
  RICCATI_RETURN_IF_ERROR(enum_from_proto(ukf.weights(), *v1::SigmaWeights_descriptor(), &parse_sigma_weights,
                                          "filter.ukf.weights", &out->ukf.weights));
  if (ukf.has_alpha()) out->ukf.alpha = ukf.alpha();
  if (ukf.has_beta()) out->ukf.beta = ukf.beta();
  if (ukf.has_kappa()) out->ukf.kappa = ukf.kappa();
  return Status::ok();
}

// The optimal filter's weights V and W and its form; it has no Q and no R.
Status optimal_weights_from_proto(const v1::FilterSettings& s, const Model& model, FilterSettings* out) {
  if (s.has_q() || s.has_r()) {
    return invalid_argument("filter.q and filter.r do not apply to the " + std::string(filter_kind_name(out->kind)) +
                            " filter: give filter.optimal.v and w");
  }
  if (!model.has_mechanical_form()) {
    return invalid_argument("model " + model.name() +
                            " has no mechanical form (M a + h = H u): the optimal filter needs one");
  }
  const v1::OptimalSettings& o = s.optimal();
  RICCATI_ASSIGN_OR_RETURN(out->optimal.V,
                           from_covariance(o.v(), optimal_equation_count(model), true, "filter.optimal.v"));
  RICCATI_ASSIGN_OR_RETURN(out->optimal.W, from_covariance(o.w(), model.nz(), true, "filter.optimal.w"));
  RICCATI_RETURN_IF_ERROR(enum_from_proto(o.form(), *v1::OptimalForm_descriptor(), &parse_optimal_form,
                                          "filter.optimal.form", &out->optimal.form));
  out->optimal.interpolate_outputs = !o.hold_outputs();
  return Status::ok();
}

}  // namespace

Result<FilterSettings> from_proto(const v1::FilterSettings& s, const Model& model) {
  FilterSettings out;
  RICCATI_RETURN_IF_ERROR(
      enum_from_proto(s.kind(), *v1::FilterKind_descriptor(), &parse_filter_kind, "filter.kind", &out.kind));
  RICCATI_ASSIGN_OR_RETURN(out.hold, from_proto(s.hold()));
  RICCATI_ASSIGN_OR_RETURN(out.integrator, from_proto(s.integrator()));
  switch (filter_kind_info(out.kind).noise) {
    case NoiseSettings::kCovariances: RICCATI_RETURN_IF_ERROR(covariances_from_proto(s, model, &out)); break;
    case NoiseSettings::kOptimalWeights: RICCATI_RETURN_IF_ERROR(optimal_weights_from_proto(s, model, &out)); break;
  }
  const Status valid = validate(out, model);
  if (!valid.is_ok()) return valid.with_context("filter");
  return out;
}

void initial_state_from_proto(const v1::InitialState& s, InitialState* mode, Eigen::VectorXd* x0) {
  // Neither given: the first measurement, the default every client states (the schema's).
  *mode = s.first_measurement() || s.x0_size() == 0 ? InitialState::kFirstMeasurement : InitialState::kGiven;
  *x0 = Eigen::Map<const Eigen::VectorXd>(s.x0().data(), s.x0_size());
}

namespace {

// P0 when a request gives none (documented with the p0 fields in the protos):
// a state that starts at its first measurement (a state named as an output,
// with x0 "first") variance 0, any other state 1; each parameter the square
// of its start (a standard deviation of 100 % of theta0), 1 for a start of 0.
Eigen::MatrixXd default_p0(const InitialEstimate& initial, const Model& model) {
  Eigen::VectorXd variances(model.nx() + model.ntheta());
  const auto& outputs = model.output_names();
  for (int i = 0; i < model.nx(); ++i) {
    const bool measured = std::find(outputs.begin(), outputs.end(), model.state_names()[static_cast<std::size_t>(i)]) !=
                          outputs.end();
    variances(i) = initial.mode == InitialState::kFirstMeasurement && measured ? 0.0 : 1.0;
  }
  for (int j = 0; j < model.ntheta(); ++j) {
    const double start = initial.theta0(j);
    variances(model.nx() + j) = start != 0.0 ? start * start : 1.0;
  }
  return variances.asDiagonal();
}

}  // namespace

Result<InitialEstimate> initial_estimate_from_proto(const v1::InitialState& initial_state,
                                                    const google::protobuf::RepeatedField<double>& theta0,
                                                    const v1::Covariance& p0, const v1::FilterSettings& filter,
                                                    const Model& model) {
  InitialEstimate out;
  initial_state_from_proto(initial_state, &out.mode, &out.x0);
  if (out.x0.size() != 0 || out.mode == InitialState::kGiven) {
    const Result<Eigen::VectorXd> x0 = from_values(initial_state.x0(), model.nx(), "initial_state.x0");
    if (!x0.is_ok()) {
      return Status(x0.status().code(), x0.status().message() +
                                            (out.mode == InitialState::kGiven ? " (or first_measurement = true)" : ""));
    }
  }
  out.theta0 = model.theta_default();
  if (!theta0.empty()) {
    RICCATI_ASSIGN_OR_RETURN(out.theta0, from_values(theta0, model.ntheta(), "theta0"));
  }
  if (!filter.optimal().has_r0() && p0.form_case() == v1::Covariance::FORM_NOT_SET) {
    out.P0 = default_p0(out, model);
  } else if (!filter.optimal().has_r0()) {
    RICCATI_ASSIGN_OR_RETURN(out.P0, from_covariance(p0, model.nz(), true, "p0"));
  } else {
    if (p0.form_case() != v1::Covariance::FORM_NOT_SET) {
      return invalid_argument("give either p0 or filter.optimal.r0 (its inverse), not both");
    }
    RICCATI_ASSIGN_OR_RETURN(const Eigen::MatrixXd R0,
                             from_covariance(filter.optimal().r0(), model.nz(), true, "filter.optimal.r0"));
    RICCATI_ASSIGN_OR_RETURN(out.P0, covariance_from_confidence(R0, "filter.optimal.r0"));
  }
  RICCATI_RETURN_IF_ERROR(validate(out, model));
  return out;
}

Result<OnlineRunner> online_runner_from_proto(const ModelPtr& model, const v1::CreateSessionRequest& request) {
  RICCATI_RETURN_IF_ERROR(check_settings_apply(request));
  RICCATI_ASSIGN_OR_RETURN(const FilterSettings settings, from_proto(request.filter(), *model));
  RICCATI_ASSIGN_OR_RETURN(InitialEstimate initial,
                           initial_estimate_from_proto(request.initial_state(), request.theta0(), request.p0(),
                                                       request.filter(), *model));
  return OnlineRunner::create(model, settings, std::move(initial));
}

}  // namespace riccati::service
