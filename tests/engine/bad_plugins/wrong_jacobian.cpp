// Loaded and running, but wrong: the pendulum with hand-written Jacobians in
// which d velocity' / d angle has the wrong sign (+k cos(angle) instead of
// -k cos(angle)). Nothing fails; only the Jacobian check can tell.
#include "pendulum_table.hpp"

namespace {

int pendulum_f_jac(double t, const double* u, const double* x, const double* theta, double* out, double* jac,
                   char* err, size_t err_len) {
  bad_plugin::pendulum_f(1, 1, t, u, x, theta, out, err, err_len);
  const double angle = x[0], k = theta[0], c = theta[1];
  // 2 rows x 4 columns [angle, velocity, k, c], column-major.
  const double wrong_d_acceleration_d_angle = +k * std::cos(angle);  // the fault: the sign
  const double columns[4][2] = {{0.0, wrong_d_acceleration_d_angle}, {1.0, -c}, {0.0, -std::sin(angle)}, {0.0, -x[1]}};
  for (int j = 0; j < 4; ++j) {
    for (int i = 0; i < 2; ++i) jac[i + 2 * j] = columns[j][i];
  }
  return 0;
}

int pendulum_g_jac(double t, const double* u, const double* x, const double* theta, double* out, double* jac,
                   char* err, size_t err_len) {
  bad_plugin::pendulum_g(1, 1, t, u, x, theta, out, err, err_len);
  const double row[4] = {1.0, 0.0, 0.0, 0.0};  // right
  for (int j = 0; j < 4; ++j) jac[j] = row[j];
  return 0;
}

}  // namespace

extern "C" RICCATI_PLUGIN_EXPORT const riccati_model_v1* riccati_model_entry(uint32_t /*host_abi_version*/) {
  static const riccati_model_v1 table = [] {
    riccati_model_v1 t = bad_plugin::pendulum_table("wrong_jacobian");
    t.f_jac = &pendulum_f_jac;
    t.g_jac = &pendulum_g_jac;
    return t;
  }();
  return &table;
}
