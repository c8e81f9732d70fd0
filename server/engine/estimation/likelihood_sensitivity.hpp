// The exact derivatives of maximum likelihood's criterion (max_likelihood.hpp)
// with respect to its unknowns: the continuous-discrete EKF on the states
// alone, run together with the forward sensitivities of its state and
// covariance (docs/identification.md, "Maximum likelihood").
//
// Along a direction (dtheta, dx0, dQ, dR) the prediction carries, with
// F = df/dx and dF = d(df/dx) along (dx, dtheta) from the model's second
// derivatives,
//     dx' = F dx + f_theta dtheta
//     dP' = dF P + P dF^T + F dP + dP F^T + dQ,
// and the update, with e = y - g, S = G P G^T + R, K = P G^T S^-1,
//     de = -(g_x dx + g_theta dtheta),   dG from g's second derivatives
//     dS = dG P G^T + G dP G^T + G P dG^T + dR
//     dK = (dP G^T + P dG^T - K dS) S^-1
//     dx+ = dx + dK e + K de,   dP+ = dP - dK S K^T - K dS K^T - K S dK^T.
// L's derivatives follow (LikelihoodDerivatives below). The sensitivities go through the same
// integrator steps as the state and covariance, so with a fixed-step
// integrator they are the derivatives of the very likelihood computed.
#pragma once

#include <Eigen/Core>
#include <memory>

#include "engine/estimation/estimate.hpp"
#include "engine/filters/filter.hpp"

namespace riccati {

// The predictor's point: parameters, initial states and noise.
struct LikelihoodPoint {
  Eigen::VectorXd theta;  // [ntheta]
  Eigen::VectorXd x0;     // [nx]
  Eigen::MatrixXd Q;      // [nx x nx] process noise intensity on the states
  Eigen::MatrixXd R;      // [ny x ny] measurement noise covariance
};

// Directions, one per column: how a unit change of an unknown moves theta,
// x0, Q's diagonal and R's diagonal.
struct LikelihoodDirections {
  Eigen::MatrixXd theta;  // [ntheta x m]
  Eigen::MatrixXd x0;     // [nx x m]
  Eigen::MatrixXd q;      // [nx x m]
  Eigen::MatrixXd r;      // [ny x m]

  void resize(const Model& model, Eigen::Index m) {
    theta.setZero(model.ntheta(), m);
    x0.setZero(model.nx(), m);
    q.setZero(model.nx(), m);
    r.setZero(model.ny(), m);
  }
  Eigen::Index size() const { return theta.cols(); }
};

// The negative log-likelihood L = 1/2 sum_k (ln det S_k + e_k' S_k^-1 e_k)
// over the samples measured, its gradient along the directions and its
// Fisher information (the expected Hessian): with w = L_k^-1 e_k, a_c =
// L_k^-1 de_c and X_c = L_k^-1 dS_c L_k^-T (S_k = L_k L_k^T),
//     dL/dc = sum_k a_c' w - 1/2 w' X_c w + 1/2 tr X_c
//     F_cd  = sum_k a_c' a_d + 1/2 tr(X_c X_d).
// Gauss-Newton on the whitened residuals alone would give half of F's
// curvature in a log noise level (1/4 sum e^2/r against 1/2): Fisher
// scoring takes the step the likelihood asks for.
struct LikelihoodDerivatives {
  double logdet = 0.0;        // sum ln det S_k
  double quadratic = 0.0;     // sum e_k' S_k^-1 e_k
  double measurements = 0.0;  // the scalar innovations
  Eigen::VectorXd gradient;   // [m]
  Eigen::MatrixXd fisher;     // [m x m]
  double value() const { return 0.5 * (logdet + quadratic); }
  void reset(Eigen::Index m) {
    *this = LikelihoodDerivatives{};
    gradient.setZero(m);
    fisher.setZero(m, m);
  }
};

class LikelihoodSensitivity {
 public:
  // Whether these settings have exact derivatives: a model with second
  // derivatives (model_abi.h's f_hess and g_hess), the EKF as predictor and
  // the Cholesky gain. Otherwise: why not, for the result to say.
  static Status available(const Model& model, const FilterSettings& filter);
  // `filter`: the predictor's kind, hold and integrator (its Q and R are the
  // point's); P0x [nx x nx] the states' initial covariance.
  static Result<LikelihoodSensitivity> create(ModelPtr model, const FilterSettings& filter, Eigen::MatrixXd P0x);

  // The experiment's share of L and (with `derivatives` sized for the
  // directions, or 0 for L alone) of its gradient and Fisher information,
  // added to `out`.
  Status accumulate(const Experiment& experiment, const LikelihoodPoint& at, const LikelihoodDirections& directions,
                    bool derivatives, LikelihoodDerivatives* out);

  LikelihoodSensitivity(LikelihoodSensitivity&&) noexcept;
  LikelihoodSensitivity& operator=(LikelihoodSensitivity&&) noexcept;
  ~LikelihoodSensitivity();

 private:
  class Rhs;
  struct Work;
  LikelihoodSensitivity(ModelPtr model, HoldOrder hold, std::unique_ptr<Integrator> integrator,
                        Eigen::MatrixXd P0x);
  Status pass(const Experiment& experiment, const LikelihoodPoint& at, const LikelihoodDirections& directions,
              Eigen::Index m, LikelihoodDerivatives* sums);
  Status update(double t, const double* u, const double* y, Eigen::Index m, LikelihoodDerivatives* sums);
  Status check_estimate(double t, const char* where) const;

  ModelPtr model_;
  std::unique_ptr<Integrator> integrator_;
  std::unique_ptr<Work> work_;
  std::unique_ptr<Rhs> rhs_;
  Eigen::MatrixXd P0x_;
};

}  // namespace riccati
