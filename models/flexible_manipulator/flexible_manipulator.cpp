// Two-mass flexible manipulator with Coulomb friction (van Kessel's 2-DOF
// set-up; dataset tests/data/flexible_manipulator.json), in the mechanical
// form that the optimal filter needs (the SDK derives the explicit f for the
// EKF and the UKF):
//
//   J1 a1 + k (s1 - s2) + b (v1 - v2) + c1 sat(v1 / vg)     = 0
//   J2 a2 - k (s1 - s2) - b (v1 - v2) + c2 sat(v2 / vg)     = T
//   y = [s1, s2]
//
// Angles s1, s2 [rad] (motor side, load side), velocities v1, v2 [rad/s],
// accelerations a1, a2 [rad/s^2], torque T [N m] applied to mass 2.
// Parameters: Coulomb friction levels c1, c2 [N m], spring stiffness k
// [N m/rad], damping b [N m s/rad], inertias J1, J2 [kg m^2]. The friction is
// smoothed by a linear zone |v| < vg, vg = 0.05 rad/s fixed, so that it is
// continuous.
#include <riccati/model.hpp>

namespace {

struct FlexibleManipulator {
  static constexpr int ndof = 2;
  static constexpr riccati::ModelSpec<4, 6, 1, 2> spec{
      .name = "flexible_manipulator",
      .version = "1.1",
      .description = "Two-mass flexible manipulator with Coulomb friction c*sat(v/vg) (van Kessel)",
      .states = {"s1", "s2", "v1", "v2"},
      .params = {"c1", "c2", "k", "b", "J1", "J2"},
      .inputs = {"T"},
      .outputs = {"s1", "s2"},
      .theta_default = {0.004, 0.003, 5.8, 0.012, 0.0045, 0.0028},
      .theta_lower = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
      .state_units = {"rad", "rad", "rad/s", "rad/s"},
      .param_units = {"N m", "N m", "N m/rad", "N m s/rad", "kg m^2", "kg m^2"},
      .input_units = {"N m"},
      .output_units = {"rad", "rad"},
  };

  static constexpr double kFrictionVelocity = 0.05;  // vg [rad/s]

  template <typename T>
  void equations_of_motion(const T* s, const T* v, const T* theta, double /*t*/, auto& eom) const {
    using namespace riccati::math;
    const T& c1 = theta[0];
    const T& c2 = theta[1];
    const T& k = theta[2];
    const T& b = theta[3];
    const T coupling = k * (s[0] - s[1]) + b * (v[0] - v[1]);  // spring-damper torque from 1 to 2
    eom.M(0, 0) = theta[4];  // J1
    eom.M(1, 1) = theta[5];  // J2
    eom.h(0) = coupling + c1 * sat(v[0] / kFrictionVelocity);
    eom.h(1) = -coupling + c2 * sat(v[1] / kFrictionVelocity);
    eom.H(1, 0) = 1.0;  // T drives mass 2
  }

  template <typename T>
  void measurement(const T* s, const T* /*v*/, const T* /*theta*/, double /*t*/, auto& y) const {
    y.g(0) = s[0];
    y.g(1) = s[1];
  }
};

}  // namespace

RICCATI_MODEL_PLUGIN(FlexibleManipulator)
