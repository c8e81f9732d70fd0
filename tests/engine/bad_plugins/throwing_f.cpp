// Valid, but f and g throw a C++ exception on every call: the SDK's
// RICCATI_MODEL_PLUGIN must catch it at the C boundary and report it as an
// error message, never let it unwind into the host.
#include <riccati/model.hpp>

#include <stdexcept>

namespace {

struct ThrowingF {
  static constexpr riccati::ModelSpec<1, 1, 0, 1> spec{
      .name = "throwing_f",
      .description = "Throws std::runtime_error from f and g",
      .states = {"x"},
      .params = {"a"},
      .outputs = {"y"},
      .theta_default = {1.0},
  };

  template <typename T>
  void f(const T* /*x*/, const T* /*theta*/, const double* /*u*/, double /*t*/, T* /*dx*/) const {
    throw std::runtime_error("deliberate exception from throwing_f's f");
  }

  template <typename T>
  void g(const T* /*x*/, const T* /*theta*/, const double* /*u*/, double /*t*/, T* /*y*/) const {
    throw std::runtime_error("deliberate exception from throwing_f's g");
  }
};

}  // namespace

RICCATI_MODEL_PLUGIN(ThrowingF)
