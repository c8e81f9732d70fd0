// Fixed-interval smoothing over a dataset: the Rauch-Tung-Striebel smoother
// after the CD-EKF, and the unscented RTS smoother (Särkkä 2008) after the
// UKF, in one backward pass.
//
// Forward, the on-line run of the filter (online_runner.hpp) over the samples
// k = 0 .. N-1, keeping z_k|k, P_k|k and, of each prediction, z_k+1|k,
// P_k+1|k and C_k = Cov(z_k|k, z_k+1|k) (Filter::prediction()). Backward, from
// z_N-1|N-1 (every "|N" below: given all the samples):
//     G_k   = C_k P_k+1|k^-1                                   (a solve)
//     z_k|N = z_k|k + G_k (z_k+1|N - z_k+1|k)
//     P_k|N = P_k|k + G_k (P_k+1|N - P_k+1|k) G_k^T           (symmetrised)
// With the EKF, C_k = P_k|k Phi_k^T and this is the classical RTS smoother;
// with the UKF, C_k = D_k+1 from the propagated sigma points, Särkkä's URTS.
// Both are the exact RTS smoother on a linear model.
//
// z = [x; theta], so the parameters are smoothed too: with no process noise
// on theta, theta_k|N is the final estimate theta_N-1|N-1 at every k, with
// its covariance.
//
// A prior P_k+1|k may be singular (no process noise and states known
// exactly: the states are then functions of the parameters, as in Hensen's
// settings); the gain then uses the directions the prior has variance in (a
// generalised inverse, which gives the same smoother as any other: the
// corrections lie in them). The EKF's P_k+1|k comes from its Riccati
// equation and its C_k from Phi_k, which the integrator makes agree to its
// own error only, which with a singular prior the smoother amplifies
// (smoother_test: give the integrator a finer step if it matters).
//
// Memory: the forward pass keeps 3 nz x nz matrices per sample (P_k|k,
// P_k+1|k, C_k), sized once before it starts; P_k|N overwrites P_k|k.
#pragma once

#include <Eigen/Core>
#include <functional>
#include <stop_token>
#include <string>
#include <vector>

#include "engine/data/dataset.hpp"
#include "engine/estimation/online_runner.hpp"
#include "engine/filters/filter.hpp"
#include "engine/models/model.hpp"
#include "engine/status.hpp"

namespace riccati {

struct SmootherSettings {
  // A filter that supports smoothing (the EKF or the UKF); smooth() turns
  // FilterSettings::smoothing on itself.
  FilterSettings filter;
  InitialEstimate initial;  // [x0; theta0] and P0 at the first sample
  // Smooth only samples [first_sample, end_sample) (end_sample < 0: to the
  // end), as IdentificationSettings.
  Eigen::Index first_sample = 0;
  Eigen::Index end_sample = -1;
};

struct SmootherResult {
  std::vector<std::string> names;  // of z [nz]: the model's states, then its parameters
  Eigen::VectorXd t;               // [N] sample times
  Eigen::MatrixXd z_filtered;      // [nz x N] z_k|k
  Eigen::MatrixXd std_filtered;    // [nz x N] sqrt(diag P_k|k)
  Eigen::MatrixXd z_smoothed;      // [nz x N] z_k|N
  Eigen::MatrixXd std_smoothed;    // [nz x N] sqrt(diag P_k|N)
  // [nz x (nz N)]: P_k|N in columns k nz .. (k + 1) nz - 1 (smoothed_covariance(k)).
  Eigen::MatrixXd P_smoothed;
  Eigen::MatrixXd y_model;      // [ny x N] g(x_k|N, theta_k|N, u_k, t_k)
  Eigen::MatrixXd innovations;  // [ny x N] the filter's, y_k - y^_k|k-1 (k = 0: against the initial estimate)

  auto smoothed_covariance(Eigen::Index k) const {
    return P_smoothed.middleCols(k * z_smoothed.rows(), z_smoothed.rows());
  }
};

struct SmootherProgress {
  enum class Pass { kForward, kBackward };
  Pass pass = Pass::kForward;
  // 1-based: the sample just filtered (forward, 1 .. N) or smoothed
  // (backward, N - 1 down to 1).
  Eigen::Index sample = 0;
  Eigen::Index samples = 0;  // N
};

// How a run is observed and stopped; both optional.
struct SmootherHooks {
  std::function<void(const SmootherProgress&)> progress;  // after every sample; keep it cheap
  std::stop_token stop;  // checked between samples: a stop request ends the run with kCancelled
};

// The filter's settings (with smoothing, which the optimal filter refuses)
// and the initial estimate, against the model.
Status validate(const SmootherSettings& settings, const Model& model);

// Smooths `data` (bound to the model by bind_dataset). Errors say where
// ("sample 17 (t = 16)", 1-based within the range), as identify()'s do.
Result<SmootherResult> smooth(ModelPtr model, const Dataset& data, const SmootherSettings& settings,
                              const SmootherHooks& hooks = {});

}  // namespace riccati
