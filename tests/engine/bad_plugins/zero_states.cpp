// Refused: a model without states (nx = 0).
#include "pendulum_table.hpp"

extern "C" RICCATI_PLUGIN_EXPORT const riccati_model_v1* riccati_model_entry(uint32_t /*host_abi_version*/) {
  static const riccati_model_v1 table = [] {
    riccati_model_v1 t = bad_plugin::pendulum_table("zero_states");
    t.nx = 0;
    return t;
  }();
  return &table;
}
