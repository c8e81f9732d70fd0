// Refused: two parameters share the name "k".
#include "pendulum_table.hpp"

namespace {
constexpr const char* kParamNames[] = {"k", "k"};
}  // namespace

extern "C" RICCATI_PLUGIN_EXPORT const riccati_model_v1* riccati_model_entry(uint32_t /*host_abi_version*/) {
  static const riccati_model_v1 table = [] {
    riccati_model_v1 t = bad_plugin::pendulum_table("duplicate_param_names");
    t.param_names = kParamNames;
    return t;
  }();
  return &table;
}
