// Valid, but f returns NaN as the derivative of state "velocity": the host
// must notice and name that state.
#include <riccati/model.hpp>

#include <limits>

namespace {

struct NanF {
  static constexpr riccati::ModelSpec<2, 1, 0, 1> spec{
      .name = "nan_f",
      .description = "Returns NaN for the derivative of state velocity",
      .states = {"position", "velocity"},
      .params = {"a"},
      .outputs = {"position"},
      .theta_default = {1.0},
  };

  template <typename T>
  void f(const T* x, const T* theta, const double* /*u*/, double /*t*/, T* dx) const {
    dx[0] = x[1];
    dx[1] = theta[0] * T(std::numeric_limits<double>::quiet_NaN());
  }

  template <typename T>
  void g(const T* x, const T* /*theta*/, const double* /*u*/, double /*t*/, T* y) const {
    y[0] = x[0];
  }
};

}  // namespace

RICCATI_MODEL_PLUGIN(NanF)
