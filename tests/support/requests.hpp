// API requests that several service tests (and the stream bench) send:
// Hensen's two-tank identification, a two-tank EKF session, the
// manipulator's optimal filter session, and measurements.
#pragma once

#include <initializer_list>
#include <string>
#include <vector>

#include "engine/data/dataset.hpp"

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

// The flexible manipulator (400 Hz) in an optimal filter session with the
// weights of case C of docs/optimal-filter.md, the initial confidence given as R0
// (the session's initial covariance is its inverse); RK4, one step a sample.
inline v1::CreateSessionRequest manipulator_case_c_session() {
  const std::vector<double> V = {1e6, 1e6, 1e4, 1e6, 1e6};
  const std::vector<double> W = {1e4, 1e4, 1e4, 1e4, 1e10, 1e10, 1e10, 1e10, 1e10, 1e10};
  const std::vector<double> R0 = {1e12, 1e12, 1e12, 1e12, 1e1, 1e2, 5e-4, 1e1, 5e3, 5e3};
  const std::vector<double> x0 = {0, 0, 0, 0}, theta0 = {.001, .001, 6.5, .01, .005, .0025};
  v1::CreateSessionRequest create;
  create.set_model("flexible_manipulator");
  v1::FilterSettings* filter = create.mutable_filter();
  filter->set_kind(v1::FILTER_KIND_OPTIMAL);
  filter->mutable_integrator()->set_substeps(1);
  for (double v : V) filter->mutable_optimal()->mutable_v()->mutable_diagonal()->add_values(v);
  for (double v : W) filter->mutable_optimal()->mutable_w()->mutable_diagonal()->add_values(v);
  for (double v : R0) filter->mutable_optimal()->mutable_r0()->mutable_diagonal()->add_values(v);
  for (double v : x0) create.mutable_initial_state()->add_x0(v);
  for (double v : theta0) create.add_theta0(v);
  return create;
}

// Appends a measurement at time t to the request's batch.
inline v1::Measurement* add_measurement(v1::StreamRequest& request, double t, std::initializer_list<double> u,
                                        std::initializer_list<double> y) {
  v1::Measurement* m = request.mutable_batch()->add_measurements();
  m->set_t(t);
  for (double v : u) m->add_u(v);
  for (double v : y) m->add_y(v);
  return m;
}

// Appends sample k of a dataset (its inputs and outputs) at time t.
inline v1::Measurement* add_sample(v1::StreamRequest& request, const Dataset& data, Eigen::Index k, double t) {
  v1::Measurement* m = request.mutable_batch()->add_measurements();
  m->set_t(t);
  for (Eigen::Index i = 0; i < data.u.rows(); ++i) m->add_u(data.u(i, k));
  for (Eigen::Index i = 0; i < data.y.rows(); ++i) m->add_y(data.y(i, k));
  return m;
}

// Appends sample k of a dataset at its own time.
inline v1::Measurement* add_sample(v1::StreamRequest& request, const Dataset& data, Eigen::Index k) {
  return add_sample(request, data, k, data.t[k]);
}

}  // namespace riccati::testing
