// Valid: the plain pendulum, which gives no Jacobians (f_jac = g_jac = NULL),
// so the host falls back to finite differences.
#include "pendulum_table.hpp"

extern "C" RICCATI_PLUGIN_EXPORT const riccati_model_v1* riccati_model_entry(uint32_t /*host_abi_version*/) {
  static const riccati_model_v1 table = bad_plugin::pendulum_table("no_jacobians");
  return &table;
}
