// A valid model table written against model_abi.h alone (no SDK). Each
// deliberately broken plugin copies it and spoils exactly one thing.
//
//   x = [angle, velocity], theta = [k, c], u = [torque]
//   angle'    = velocity
//   velocity' = -k sin(angle) - c velocity + torque
//   y = angle
//
// It gives no Jacobians (f_jac = g_jac = NULL), so the host must fall back to
// finite differences; the exact Jacobian is easy to write down in a test.
#pragma once

#include <riccati/model_abi.h>

#include <cmath>

namespace bad_plugin {

inline int pendulum_f(uint32_t n, size_t ld, double /*t*/, const double* u, const double* x, const double* theta,
                      double* out, char* /*err*/, size_t /*err_len*/) {
  for (uint32_t p = 0; p < n; ++p) {
    const double angle = x[p], velocity = x[ld + p];
    const double k = theta[p], c = theta[ld + p];
    out[p] = velocity;
    out[ld + p] = -k * std::sin(angle) - c * velocity + u[0];
  }
  return 0;
}

inline int pendulum_g(uint32_t n, size_t /*ld*/, double /*t*/, const double* /*u*/, const double* x,
                      const double* /*theta*/, double* out, char* /*err*/, size_t /*err_len*/) {
  for (uint32_t p = 0; p < n; ++p) out[p] = x[p];
  return 0;
}

inline constexpr const char* kStateNames[] = {"angle", "velocity"};
inline constexpr const char* kParamNames[] = {"k", "c"};
inline constexpr const char* kInputNames[] = {"torque"};
inline constexpr const char* kOutputNames[] = {"angle"};
inline constexpr double kThetaDefault[] = {9.0, 0.5};
inline constexpr double kThetaLower[] = {0.0, 0.0};
inline constexpr double kThetaUpper[] = {HUGE_VAL, HUGE_VAL};

inline riccati_model_v1 pendulum_table(const char* model_name) {
  riccati_model_v1 t{};
  t.abi_version = RICCATI_MODEL_ABI_VERSION;
  t.struct_size = sizeof(riccati_model_v1);
  t.name = model_name;
  t.version = "1.0";
  t.description = "Damped pendulum, plain C table for the loader's tests";
  t.nx = 2;
  t.ntheta = 2;
  t.nu = 1;
  t.ny = 1;
  t.state_names = kStateNames;
  t.param_names = kParamNames;
  t.input_names = kInputNames;
  t.output_names = kOutputNames;
  t.theta_default = kThetaDefault;
  t.theta_lower = kThetaLower;
  t.theta_upper = kThetaUpper;
  t.f = &pendulum_f;
  t.g = &pendulum_g;
  t.f_jac = nullptr;
  t.g_jac = nullptr;
  return t;
}

}  // namespace bad_plugin

