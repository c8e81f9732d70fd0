// Output error (simulation error, as MATLAB's nlgreyest; docs/identification.md):
// the parameters, and the initial states asked for, that minimise
//
//     1/2 sum_e sum_k || W^1/2 m_k (g(x(t_k; theta, x0_e), theta, u_k) - y_k) ||^2
//
// over every experiment e, the model simulated over each whole record from
// its initial state. The Jacobian of the residuals comes from the forward
// sensitivities (sensitivity.hpp); the optimiser is Ceres' trust-region
// Levenberg-Marquardt with the bounds as box constraints, fixed parameters
// held by a subset manifold, log-scaled ones estimated as log(theta). A
// simulation that fails inside an iteration (a NaN, the integrator giving up)
// rejects that step and the trust region shrinks; only when no step from the
// start can be taken does the run fail, saying where and with which values.
//
// Uncertainty: Cov = s2 (J'J)^-1 at the estimate, with s2 = 2 cost /
// (m - p) (m residuals used, p unknowns) when the noise is not known, 1 when
// the outputs' noise standard deviations are given (W = diag(1/sigma^2)).
#pragma once

#include "engine/estimation/estimate.hpp"
#include "engine/estimation/uncertainty.hpp"
#include "engine/estimation/validation.hpp"

namespace riccati {

struct OutputErrorSettings {
  SimulationSettings simulation;
  ParameterSettings parameters;
  // Each output's noise standard deviation, when known: the residuals are
  // weighted by 1/sigma and the covariance is (J'J)^-1. Empty: not known,
  // every output weighted 1 and the covariance scaled by the residual variance.
  Eigen::VectorXd output_sigma;
  OptimizerSettings optimizer;
  CovarianceChoice covariance = CovarianceChoice::kAuto;
};

// The experiments' data must be bound to the model (bind_dataset). Residuals
// in the result are normalised: (y - y_model) / sigma, with sigma the given
// one or sqrt(s2).
Result<EstimationResult> output_error(ModelPtr model, const std::vector<Experiment>& experiments,
                                      const OutputErrorSettings& settings, const EstimationHooks& hooks = {});

}  // namespace riccati
