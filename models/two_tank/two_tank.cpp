// Two cascaded tanks (Hensen 1999, sec. 4.1, eqs 4.3-4.6).
//
//   A1 h1' = F1 - k1 sqrt(h1)
//   A2 h2' = F2 + k1 sqrt(h1) - k2 sqrt(h2)
//   y = [h1, h2]
//
// An empty tank has no outflow: sqrt(h) is taken as 0 for h <= 0. Filters
// need this: sigma points or a poor first guess of the parameters can drain
// a tank below zero within one sample, where sqrt would be NaN.
//
// Inflows F1, F2 [m^3/s]; levels h1, h2 [m]; cross sections A1, A2 [m^2];
// outflow coefficients k1, k2 [m^2.5/s].
#include <riccati/model.hpp>

namespace {

struct TwoTank {
  static constexpr riccati::ModelSpec<2, 4, 2, 2> spec{
      .name = "two_tank",
      .version = "1.0",
      .description = "Two cascaded tanks with outflow k*sqrt(h) (Hensen 1999, sec. 4.1)",
      .states = {"h1", "h2"},
      .params = {"A1", "A2", "k1", "k2"},
      .inputs = {"F1", "F2"},
      .outputs = {"h1", "h2"},
      .theta_default = {10.0, 5.0, 0.0791, 0.1342},
      .theta_lower = {0.0, 0.0, 0.0, 0.0},
      .state_units = {"m", "m"},
      .param_units = {"m^2", "m^2", "m^2.5/s", "m^2.5/s"},
      .input_units = {"m^3/s", "m^3/s"},
      .output_units = {"m", "m"},
  };

  // sqrt(h) for h > 0, else 0 (with derivative 0, not sqrt's infinite one at 0).
  template <typename T>
  static T root_level(const T& h) {
    using namespace riccati::math;
    return h > 0.0 ? sqrt(h) : T(0.0);
  }

  template <typename T>
  void f(const T* x, const T* theta, const double* u, double /*t*/, T* dx) const {
    const T q1 = theta[2] * root_level(x[0]);  // flow from tank 1 into tank 2
    const T q2 = theta[3] * root_level(x[1]);  // outflow of tank 2
    dx[0] = (u[0] - q1) / theta[0];
    dx[1] = (u[1] + q1 - q2) / theta[1];
  }

  template <typename T>
  void g(const T* x, const T* /*theta*/, const double* /*u*/, double /*t*/, T* y) const {
    y[0] = x[0];
    y[1] = x[1];
  }
};

}  // namespace

RICCATI_MODEL_PLUGIN(TwoTank)
