// Refused: the second state has no name (NULL).
#include "pendulum_table.hpp"

namespace {
constexpr const char* kStateNames[] = {"angle", nullptr};
}  // namespace

extern "C" RICCATI_PLUGIN_EXPORT const riccati_model_v1* riccati_model_entry(uint32_t /*host_abi_version*/) {
  static const riccati_model_v1 table = [] {
    riccati_model_v1 t = bad_plugin::pendulum_table("null_state_name");
    t.state_names = kStateNames;
    return t;
  }();
  return &table;
}
