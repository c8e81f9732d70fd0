// Rotating arm with friction learnt by a small neural network (Hensen 1999,
// sec. 4.2, eq. 4.9; dataset tests/data/rotating_arm.json).
//
//   q'    = qdot
//   qdot' = Minv * (-b qdot + sum_k W2_k tanh(W1_k qdot) + i)
//   y = [q, qdot]
//
// The friction is a 3-neuron tanh network without biases, so it is odd in
// qdot like real friction. Arm angle q [rad], velocity qdot [rad/s]; the
// motor input i is in the rig's drive units [u] (the motor constant is lumped
// into Minv). Minv [rad/s^2 per u] is the inverse inertia; b [u s/rad],
// W2 [u] and W1 [s/rad] express friction as an equivalent input.
//
// Defaults are Hensen's fitted model (mean over the last pass), not his
// starting guess theta0 = [1 1 1 1 1 1 0 10]. The rig's true friction is a
// Stribeck curve, so no parameter value makes this model exact.
#include <riccati/model.hpp>

namespace {

struct RotatingArm {
  static constexpr riccati::ModelSpec<2, 8, 1, 2> spec{
      .name = "rotating_arm",
      .version = "1.0",
      .description = "Rotating arm, friction by a 3-neuron tanh network (Hensen 1999, sec. 4.2)",
      .states = {"q", "qdot"},
      .params = {"W1_1", "W1_2", "W1_3", "W2_1", "W2_2", "W2_3", "b", "Minv"},
      .inputs = {"i"},
      .outputs = {"q", "qdot"},
      .theta_default = {0.2069, 12.8021, 0.0428, 1.346, -1.5092, -0.0355, -0.0778, 34.4013},
      // Only the inverse inertia has a physical sign; the network weights and
      // the linear term b (negative in Hensen's fit) are free.
      .theta_lower = {-HUGE_VAL, -HUGE_VAL, -HUGE_VAL, -HUGE_VAL, -HUGE_VAL, -HUGE_VAL, -HUGE_VAL, 0.0},
  };

  static constexpr int kNeurons = 3;

  template <typename T>
  void f(const T* x, const T* theta, const double* u, double /*t*/, T* dx) const {
    using namespace riccati::math;
    const T& qdot = x[1];
    const T* w1 = theta;
    const T* w2 = theta + kNeurons;
    const T& b = theta[6];
    const T& minv = theta[7];
    T friction_network = T(0.0);
    for (int k = 0; k < kNeurons; ++k) friction_network += w2[k] * tanh(w1[k] * qdot);
    dx[0] = qdot;
    dx[1] = minv * (-b * qdot + friction_network + u[0]);
  }

  template <typename T>
  void g(const T* x, const T* /*theta*/, const double* /*u*/, double /*t*/, T* y) const {
    y[0] = x[0];
    y[1] = x[1];
  }
};

}  // namespace

RICCATI_MODEL_PLUGIN(RotatingArm)
