// The model simulated over a record together with its forward sensitivities:
// the variational equations integrated alongside the states (docs/identification.md),
//
//     x' = f(x, theta, u, t),              x(t0) = x0
//     S' = f_x S + [0  f_theta],           S(t0) = [I  0],   S = [dx/dx0  dx/dtheta]
//     y_k = g(x_k, theta, u_k, t_k),       dy_k/dtheta = g_x S_theta + g_theta,  dy_k/dx0 = g_x S_x0
//
// (models/variational.hpp; without dx/dx0 when the initial states are
// known) with the model's exact Jacobians f_x, f_theta, g_x, g_theta (dual
// numbers in the plugin) and the inputs held between samples as the filters hold
// them. The same integrator steps carry x and S, so with a fixed-step
// integrator S is the exact derivative of the discretised solution: an
// optimiser sees the gradient of the very cost it minimises.
#pragma once

#include <Eigen/Core>
#include <memory>

#include "engine/estimation/validation.hpp"
#include "engine/integrators/integrator.hpp"
#include "engine/models/input_hold.hpp"
#include "engine/models/model.hpp"
#include "engine/status.hpp"

namespace riccati {

struct SimulatedRecord {
  Eigen::MatrixXd x;          // [nx x N] states
  Eigen::MatrixXd y;          // [ny x N] outputs
  Eigen::MatrixXd dy_dtheta;  // [(N ny) x ntheta]: row k ny + i is d y_i(t_k) / d theta
  Eigen::MatrixXd dy_dx0;     // [(N ny) x nx]: row k ny + i is d y_i(t_k) / d x0 (when asked for)
};

class SensitivitySimulator {
 public:
  // `x0_sensitivities`: also d y / d x0, for initial states that are estimated.
  static Result<SensitivitySimulator> create(ModelPtr model, const SimulationSettings& settings,
                                             bool x0_sensitivities);

  // Simulates over the times t [N] with the inputs u [nu x N] from x0 with
  // theta; with `sensitivities` false only x and y (what a trial step of an
  // optimiser needs). `out` is sized on first use and reused.
  Status simulate(const Eigen::VectorXd& t, const Eigen::MatrixXd& u, const Eigen::VectorXd& x0,
                  const Eigen::VectorXd& theta, bool sensitivities, SimulatedRecord* out);

  const Model& model() const { return *model_; }
  bool x0_sensitivities() const { return x0_sensitivities_; }

  SensitivitySimulator(SensitivitySimulator&&) noexcept;
  SensitivitySimulator& operator=(SensitivitySimulator&&) noexcept;
  ~SensitivitySimulator();

 private:
  class Rhs;
  SensitivitySimulator(ModelPtr model, HoldOrder hold, std::unique_ptr<Integrator> values,
                       std::unique_ptr<Integrator> sensitivities, bool x0_sensitivities);

  ModelPtr model_;
  // One integrator for x alone and one for [x; S]: each keeps its work space
  // (SUNDIALS memory) sized for its system, whichever an optimiser asks for.
  std::unique_ptr<Integrator> values_integrator_, sensitivity_integrator_;
  bool x0_sensitivities_ = false;
  std::unique_ptr<Rhs> rhs_;
  // Work space, sized once: [x; vec S] and the Jacobian of g at a sample.
  Eigen::VectorXd w_;
  Eigen::MatrixXd g_jac_;
  Eigen::VectorXd y_;
};

}  // namespace riccati
