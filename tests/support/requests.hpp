// API requests that several service tests send: Hensen's two-tank
// identification and a two-tank EKF session.
#pragma once

#include <string>

#include "riccati/v1/jobs.pb.h"
#include "riccati/v1/sessions.pb.h"

namespace riccati::testing {

// Hensen's settings (two_tank.json): passes from theta0 = [20 20 1 1].
inline v1::IdentificationSpec hensen_spec(const std::string& dataset_id, int passes = 10) {
  v1::IdentificationSpec spec;
  spec.set_model("two_tank");
  spec.set_dataset_id(dataset_id);
  spec.mutable_filter()->set_kind(v1::FILTER_KIND_EKF);
  spec.mutable_filter()->mutable_integrator()->set_kind(v1::INTEGRATOR_KIND_RK4);
  spec.mutable_filter()->mutable_integrator()->set_substeps(10);
  for (double r : {1e-3, 1e-3}) spec.mutable_filter()->mutable_r()->mutable_diagonal()->add_values(r);
  spec.mutable_initial_state()->set_first_measurement(true);
  for (double v : {20.0, 20.0, 1.0, 1.0}) spec.add_theta0(v);
  for (double v : {0.0, 0.0, 10.0, 10.0, 10.0, 10.0}) spec.mutable_p0()->mutable_diagonal()->add_values(v);
  spec.set_passes(passes);
  return spec;
}

// A two-tank EKF session starting from the first measurement.
inline v1::CreateSessionRequest two_tank_session() {
  v1::CreateSessionRequest create;
  create.set_model("two_tank");
  for (double r : {1e-3, 1e-3}) create.mutable_filter()->mutable_r()->mutable_diagonal()->add_values(r);
  create.mutable_initial_state()->set_first_measurement(true);
  for (double v : {0.0, 0.0, 1.0, 1.0, 1e-6, 1e-6}) create.mutable_p0()->mutable_diagonal()->add_values(v);
  return create;
}

}  // namespace riccati::testing
