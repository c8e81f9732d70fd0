// Two-mass flexible manipulator with Coulomb friction (van Kessel's 2-DOF
// set-up; dataset tests/data/flexible_manipulator.json).
//
//   J1 s1'' + k (s1 - s2) + b (v1 - v2) + c1 sat(v1 / vg)     = 0
//   J2 s2'' - k (s1 - s2) - b (v1 - v2) + c2 sat(v2 / vg) - T = 0
//   s1' = v1, s2' = v2, y = [s1, s2]
//
// Angles s1, s2 [rad] (motor side, load side), velocities v1, v2 [rad/s],
// torque T [N m] applied to mass 2. Parameters: Coulomb friction levels c1,
// c2 [N m], spring stiffness k [N m/rad], damping b [N m s/rad], inertias J1,
// J2 [kg m^2]. The friction is smoothed by a linear zone |v| < vg, vg =
// 0.05 rad/s fixed, so that f is continuous.
#include <riccati/model.hpp>

namespace {

struct FlexibleManipulator {
  static constexpr riccati::ModelSpec<4, 6, 1, 2> spec{
      .name = "flexible_manipulator",
      .version = "1.0",
      .description = "Two-mass flexible manipulator with Coulomb friction c*sat(v/vg) (van Kessel)",
      .states = {"s1", "s2", "v1", "v2"},
      .params = {"c1", "c2", "k", "b", "J1", "J2"},
      .inputs = {"T"},
      .outputs = {"s1", "s2"},
      .theta_default = {0.004, 0.003, 5.8, 0.012, 0.0045, 0.0028},
      .theta_lower = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
  };

  static constexpr double kFrictionVelocity = 0.05;  // vg [rad/s]

  template <typename T>
  void f(const T* x, const T* theta, const double* u, double /*t*/, T* dx) const {
    using namespace riccati::math;
    const T& s1 = x[0];
    const T& s2 = x[1];
    const T& v1 = x[2];
    const T& v2 = x[3];
    const T& c1 = theta[0];
    const T& c2 = theta[1];
    const T& k = theta[2];
    const T& b = theta[3];
    const T& j1 = theta[4];
    const T& j2 = theta[5];

    const T coupling = k * (s1 - s2) + b * (v1 - v2);  // spring-damper torque from 1 to 2
    dx[0] = v1;
    dx[1] = v2;
    dx[2] = (-coupling - c1 * sat(v1 / kFrictionVelocity)) / j1;
    dx[3] = (coupling - c2 * sat(v2 / kFrictionVelocity) + u[0]) / j2;
  }

  template <typename T>
  void g(const T* x, const T* /*theta*/, const double* /*u*/, double /*t*/, T* y) const {
    y[0] = x[0];
    y[1] = x[1];
  }
};

}  // namespace

RICCATI_MODEL_PLUGIN(FlexibleManipulator)
