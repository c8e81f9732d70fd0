// The settings of a filter run, from the API: what sessions (CreateSession)
// and identification jobs (IdentificationSpec) share. Every enum maps onto
// the engine's by name (convert.hpp); which settings apply to which filter
// kind comes from the engine's table (engine/filters/filter_kinds.hpp), so
// nothing here knows the kinds one by one.
#pragma once

#include "engine/estimation/online_runner.hpp"
#include "engine/filters/filter.hpp"
#include "engine/integrators/integrator.hpp"
#include "engine/models/model.hpp"
#include "riccati/v1/common.pb.h"
#include "riccati/v1/sessions.pb.h"

namespace riccati::service {

// A setting given where the request's method or its filter kind does not
// take it, as the proto's schema says (riccati/settings_schema.hpp):
// INVALID_ARGUMENT naming the field, the method or kind it applies to and
// the one asked for. `filter`: the kind's short name where the request does
// not say it (a session's, for a retuning).
Status check_settings_apply(const google::protobuf::Message& request, std::string_view filter = {});

Result<IntegratorSettings> from_proto(const v1::IntegratorSettings& s);
Result<HoldOrder> from_proto(v1::HoldOrder hold);
Result<FilterSettings> from_proto(const v1::FilterSettings& s, const Model& model);
v1::FilterKind to_proto(FilterKind kind);

void initial_state_from_proto(const v1::InitialState& s, InitialState* mode, Eigen::VectorXd* x0);
// The estimate a run starts from: initial_state, theta0 (empty: the model's
// defaults) and p0, or for the optimal filter P0 = R0^-1 from
// filter.optimal.r0 (one of the two).
Result<InitialEstimate> initial_estimate_from_proto(const v1::InitialState& initial_state,
                                                    const google::protobuf::RepeatedField<double>& theta0,
                                                    const v1::Covariance& p0, const v1::FilterSettings& filter,
                                                    const Model& model);

// The filter a session runs (CreateSession): the request's filter settings
// and initial estimate for `model`. Sessions are made here, and so is the
// stream bench's figure of the filter alone.
Result<OnlineRunner> online_runner_from_proto(const ModelPtr& model, const v1::CreateSessionRequest& request);

}  // namespace riccati::service
