// Refused: the entry point declines every host ABI version (returns NULL).
#include <riccati/model_abi.h>

extern "C" RICCATI_PLUGIN_EXPORT const riccati_model_v1* riccati_model_entry(uint32_t /*host_abi_version*/) {
  return nullptr;
}
