// Hensen's two-tank identification settings (two_tank.json, 1999 report):
// 10 passes from theta0 = [20 20 1 1], P0 = diag(0 0 10 10 10 10), Q = 0,
// R = 1e-3 I, x0 = first measurement, EKF with RK4 and 10 substeps. Shared by
// the tests and benchmarks that run it in-process as a reference.
#pragma once

#include "engine/estimation/identification.hpp"

namespace riccati::testing {

inline IdentificationSettings two_tank_hensen(FilterKind kind = FilterKind::kEkf, int passes = 10) {
  IdentificationSettings s;
  s.filter.kind = kind;
  s.filter.integrator.kind = IntegratorKind::kRk4;
  s.filter.integrator.substeps = 10;
  s.filter.Q = Eigen::MatrixXd::Zero(6, 6);
  s.filter.R = Eigen::Vector2d(1e-3, 1e-3).asDiagonal();
  s.initial.mode = InitialState::kFirstMeasurement;
  s.initial.theta0 = Eigen::Vector4d(20, 20, 1, 1);
  Eigen::VectorXd p0(6);
  p0 << 0, 0, 10, 10, 10, 10;
  s.initial.P0 = p0.asDiagonal();
  s.passes = passes;
  return s;
}

}  // namespace riccati::testing
