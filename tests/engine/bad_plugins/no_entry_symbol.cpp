// Refused: a shared library that exports something, but not
// riccati_model_entry.
#include <riccati/model_abi.h>

extern "C" RICCATI_PLUGIN_EXPORT int some_other_library_function(void) { return 42; }
