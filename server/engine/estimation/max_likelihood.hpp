// Maximum likelihood with the continuous-discrete EKF as predictor (the
// prediction-error method of CTSM-R; docs/identification.md): the parameters, and
// the initial states and noise levels asked for, that minimise the negative
// log-likelihood of the one-step innovations
//
//     L = sum_e sum_k 1/2 (ln det S_k + e_k' S_k^-1 e_k)
//
// where e_k = y_k - g(x_k|k-1) and S_k = G P_k|k-1 G' + R come from the filter
// run over each record on the states alone (the parameters held, not
// augmented), with process noise intensity Q on the states and measurement
// noise R. With Q = 0 and P0 = 0 the gain is zero, S_k = R, and L is the
// output-error cost scaled by R; with Q > 0 the predictor follows the data,
// so a model that is unstable or chaotic in simulation (a pendulum far from
// its parameters) still has a smooth criterion.
//
// L is minimised as a sum of squares: with S_k >= R, L = 1/2 sum |S_k^-1/2
// e_k|^2 + 1/2 sum rho_k^2 + 1/2 N ln det R + const, rho_k = sqrt(ln det S_k -
// ln det R + 1), so Ceres' Levenberg-Marquardt takes it (bounds as box
// constraints, as output error). Noise levels, when estimated, are on a log
// scale, at most 13 decades below their start.
//
// The residuals' Jacobian is exact where it can be (likelihood_sensitivity.hpp:
// the EKF predictor, the Cholesky gain and a model with second derivatives,
// as the SDK's plugins and text models written with der: have): forward
// sensitivities of the filter's state and covariance. Otherwise it is
// central differences of the filter's residuals, and the result says why.
// The covariance of the estimate is the inverse of L's Hessian, not the
// Gauss-Newton approximation: central differences of the exact gradient, or
// (without it) central second differences of L's two sums, each differenced
// apart so that neither's size spoils the other's precision.
#pragma once

#include "engine/estimation/estimate.hpp"
#include "engine/filters/filter.hpp"

namespace riccati {

struct MaxLikelihoodSettings {
  // The predictor: kind (EKF or UKF), hold, integrator; Q [nz x nz] of which
  // the states' block is used (the parameters' is zero), R [ny x ny].
  FilterSettings filter;
  Eigen::MatrixXd P0x;  // [nx x nx] initial covariance of the states (zero: known)
  ParameterSettings parameters;
  bool estimate_process_noise = false;      // the diagonal of Q's states' block, from filter.Q's
  bool estimate_measurement_noise = false;  // the diagonal of R, from filter.R's
  OptimizerSettings optimizer;
  // Central differences even where the exact gradient is at hand: the
  // baseline of bench/ and of the tests that compare the two.
  bool differenced_gradient = false;
};

// Noise levels at the estimate, when estimated (else as given).
struct NoiseEstimate {
  Eigen::VectorXd q, q_std;  // [nx] the diagonal of Q's states' block
  Eigen::VectorXd r, r_std;  // [ny] the diagonal of R
};

struct MaxLikelihoodResult {
  EstimationResult estimate;  // residuals: S_k^-1/2 e_k; y_model: the one-step predictions
  NoiseEstimate noise;
};

// The experiments' data must be bound to the model; their x0 is the
// predictor's initial state (estimated where asked). A sample with an output
// masked out is a prediction without an update, and adds nothing to L.
Result<MaxLikelihoodResult> max_likelihood(ModelPtr model, const std::vector<Experiment>& experiments,
                                           const MaxLikelihoodSettings& settings, const EstimationHooks& hooks = {});

}  // namespace riccati
