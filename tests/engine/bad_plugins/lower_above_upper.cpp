// Refused: parameter c has lower bound 1 above upper bound 0.5.
#include "pendulum_table.hpp"

namespace {
constexpr double kThetaLower[] = {0.0, 1.0};
constexpr double kThetaUpper[] = {10.0, 0.5};
}  // namespace

extern "C" RICCATI_PLUGIN_EXPORT const riccati_model_v1* riccati_model_entry(uint32_t /*host_abi_version*/) {
  static const riccati_model_v1 table = [] {
    riccati_model_v1 t = bad_plugin::pendulum_table("lower_above_upper");
    t.theta_lower = kThetaLower;
    t.theta_upper = kThetaUpper;
    return t;
  }();
  return &table;
}
