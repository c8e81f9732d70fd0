// Refused: the default of parameter k is NaN.
#include "pendulum_table.hpp"

namespace {
constexpr double kThetaDefault[] = {NAN, 0.5};
}  // namespace

extern "C" RICCATI_PLUGIN_EXPORT const riccati_model_v1* riccati_model_entry(uint32_t /*host_abi_version*/) {
  static const riccati_model_v1 table = [] {
    riccati_model_v1 t = bad_plugin::pendulum_table("nonfinite_default");
    t.theta_default = kThetaDefault;
    return t;
  }();
  return &table;
}
