// Filters on the augmented state z = [x; theta] of a continuous-time model
//
//     x' = f(x, theta, u, t) + w,   theta' = 0 (+ w_theta),   w ~ N(0, Q dt)
//     y_k = g(x, theta, u, t_k) + v_k,                       v ~ N(0, R)
//
// One interface for every filter kind: predict to a time with the inputs,
// update with a measurement, read the estimate. Filters are created once per
// session or job, then stepped with no allocation per sample.
#pragma once

#include <Eigen/Core>
#include <memory>
#include <string_view>

#include "engine/integrators/integrator.hpp"
#include "engine/models/input_hold.hpp"
#include "engine/models/model.hpp"
#include "engine/status.hpp"

namespace riccati {

enum class FilterKind {
  kEkf,      // continuous-discrete extended Kalman filter (Hensen 1999, ch. 2)
  kUkf,      // continuous-discrete unscented Kalman filter (Zheng et al. 2010)
  kOptimal,  // the optimal filter of van de Molengraft / van Kessel (mechanical models)
};


// How the gain solves with the innovation covariance S (the toolbox's `inverse`).
enum class GainInversion {
  kCholesky,       // S must be positive definite; factorised, never inverted
  kPseudoInverse,  // minimum-norm least squares: tolerates a singular S
};

enum class SigmaWeights {
  kJulier,  // Julier & Uhlmann: lambda = kappa, Wc = Wm
  kScaled,  // scaled set: lambda = alpha^2 (n + kappa) - n, Wc0 += 1 - alpha^2 + beta
};

struct UkfSettings {
  SigmaWeights weights = SigmaWeights::kJulier;
  double alpha = 1.0;
  double beta = 2.0;
  // NaN selects the usual default: 3 - n for kJulier, 0 for kScaled.
  double kappa = std::numeric_limits<double>::quiet_NaN();
};

// How the optimal filter integrates (docs/optimal-filter.md, sec. 3).
enum class OptimalForm {
  kContinuous,  // equations 8 and 10 with the integrator: the measurements act continuously
  kSplitStep,   // predict without the measurement terms, then a discrete update at each
                // sample: the same continuous limit, and stable for any V
};

// The weights of the optimal filter. With n degrees of freedom, nu inputs and
// ny outputs there are L = n + nu + ny equations: the n equations of motion,
// the nu measured inputs and the ny measured outputs, in that order.
struct OptimalSettings {
  Eigen::MatrixXd V;  // [L x L] confidence in each equation (inverse intensity)
  Eigen::MatrixXd W;  // [nz x nz] confidence in the state equation; W^-1 is the process noise
  OptimalForm form = OptimalForm::kContinuous;
  // Measured outputs within a step: linear between the two samples (true),
  // or held at the step's start for strict real time (a half-sample lag).
  // Applied inputs are always held as `hold` says.
  bool interpolate_outputs = true;
};

struct FilterSettings {
  FilterKind kind = FilterKind::kEkf;
  HoldOrder hold = HoldOrder::kZero;
  IntegratorSettings integrator;
  Eigen::MatrixXd Q;  // [nz x nz] process noise intensity; zero is allowed (EKF, UKF)
  Eigen::MatrixXd R;  // [ny x ny] measurement noise covariance (EKF, UKF)
  GainInversion inversion = GainInversion::kCholesky;
  bool joseph = true;  // EKF: Joseph-form covariance update
  UkfSettings ukf;
  OptimalSettings optimal;
  // Keep what a fixed-interval smoother needs from every prediction
  // (Filter::prediction()). Off, a filter does nothing for it; on, the EKF
  // also integrates its transition matrix over each step (with a fixed-step
  // integrator its estimate stays the same to the bit; an adaptive one
  // controls that matrix's error too, so takes other steps). The EKF and the
  // UKF support it, the optimal filter does not.
  bool smoothing = false;
};

// What a prediction from t_k to t_k+1 tells a fixed-interval smoother, in one
// form for every filter that supports it: the prior and its cross covariance
// with the estimate it was predicted from, so that the Rauch-Tung-Striebel
// gain is G_k = C_k P_k+1|k^-1 whatever the filter.
struct Prediction {
  Eigen::VectorXd z;  // z_k+1|k [nz]
  Eigen::MatrixXd P;  // P_k+1|k [nz x nz]
  // C_k = Cov(z_k|k, z_k+1|k) [nz x nz]: P_k|k Phi_k^T for the EKF (Phi_k the
  // transition matrix over the step), D_k+1 from the sigma points for the
  // UKF (Särkkä 2008).
  Eigen::MatrixXd C;
};

// Names of the settings' other enums, as the API, the CLI and job files write
// them (hold_order_name and parse_hold_order are in input_hold.hpp).
Result<GainInversion> parse_gain_inversion(std::string_view name);  // "cholesky", "pinv"
Result<SigmaWeights> parse_sigma_weights(std::string_view name);    // "julier", "scaled"
Result<OptimalForm> parse_optimal_form(std::string_view name);      // "continuous", "split-step"
const char* optimal_form_name(OptimalForm form);
// Number of equations L of the optimal filter for a mechanical model.
int optimal_equation_count(const Model& model);

// Checks the settings against a model: the integrator's, then those of the
// filter's kind (filter_kinds.hpp): sizes, symmetry, finiteness and
// semi-definiteness of its noise or weights.
Status validate(const FilterSettings& settings, const Model& model);
// The EKF's and UKF's noise: Q (nz x nz) and R (ny x ny) covariances.
Status validate_noise_covariances(const FilterSettings& settings, const Model& model);

// The largest magnitude of an entry of Q, R, P0, V or W: its square, and the
// products a filter forms of such entries, stay finite (1e300 would not).
inline constexpr double kMaxCovarianceEntry = 1e150;

// A covariance-like matrix: n x n, finite, entries within
// kMaxCovarianceEntry, symmetric, no negative eigenvalue beyond rounding.
// `what` names it in messages. The one check of Q, R, P0 (each filter kind's
// validation and the initial estimate's) and of the optimal filter's V and W.
Status check_covariance(const Eigen::MatrixXd& M, Eigen::Index n, const std::string& what);

class Filter {
 public:
  virtual ~Filter() = default;

  // Sets the estimate at time t: z [nz], P [nz x nz] symmetric positive
  // semi-definite (zero variances mean "known exactly").
  Status reset(double t, const Eigen::VectorXd& z, const Eigen::MatrixXd& P);

  // Propagates the estimate from time() to t1 > time(); u0 is the input at
  // time(), u1 at t1 (used by first-order hold only). Both [nu].
  virtual Status predict(double t1, const double* u0, const double* u1) = 0;

  // Measurement update at time() with y [ny] and the input u [nu] at that time.
  virtual Status update(const double* y, const double* u) = 0;

  // One sample: predict to t1, then update with y1 [ny]; u0, u1 as in
  // predict. A filter whose prediction can use the measurement at the end of
  // the interval (the optimal filter interpolates it) overrides this.
  virtual Status step(double t1, const double* u0, const double* u1, const double* y1);

  // What the filter keeps between samples besides time(), state() and
  // covariance() (the optimal filter: its last measurement), so that a
  // filter restored from those four continues as this one would, bit for
  // bit. Empty for the EKF and the UKF.
  virtual Eigen::VectorXd carried_state() const { return {}; }
  // Holds the parameters of the estimate within [lower, upper] [ntheta]
  // (the covariance is left as it is): the projection that keeps an
  // estimate inside its bounds. Sets hit[i] for each parameter moved.
  void clamp_parameters(const Eigen::VectorXd& lower, const Eigen::VectorXd& upper, Eigen::VectorXi* hits);
  // Puts back what time(), state(), covariance() and carried_state() of a
  // filter of the same model and settings returned. Only sizes are checked:
  // the values are a filter's own, kept exactly (even a diverged one's).
  Status restore(double t, const Eigen::VectorXd& z, const Eigen::MatrixXd& P, const Eigen::VectorXd& carried);
  // Live retuning (COCKPIT's weights changed on the rig): the noise of
  // `settings` (Q and R; the optimal filter's V and W) from the next step
  // on, the estimate and its covariance kept. The kind must be the filter's;
  // the settings are checked as at construction (validate()). Nothing
  // changes when they are refused.
  Status retune(const FilterSettings& settings);

  const Model& model() const { return *model_; }
  const FilterSettings& settings() const { return settings_; }
  double time() const { return t_; }
  const Eigen::VectorXd& state() const { return z_; }             // [nz] = [x; theta]
  const Eigen::MatrixXd& covariance() const { return P_; }        // [nz x nz]
  // Of the last update:
  const Eigen::VectorXd& predicted_output() const { return y_pred_; }  // g at the prior [ny]
  const Eigen::VectorXd& innovation() const { return innovation_; }    // y - y_pred [ny]
  const Eigen::MatrixXd& innovation_covariance() const { return S_; }  // [ny x ny]
  double nis() const { return nis_; }  // normalised innovation squared, innovation' S^-1 innovation
  // Of filters that estimate the inputs (the optimal filter; empty for the
  // others), at the last update: the estimated inputs and accelerations
  // p = [u; a] [nu + ndof] and the residuals zeta of the L equations.
  virtual const Eigen::VectorXd& estimated_inputs() const { return kNothing; }
  virtual const Eigen::VectorXd& equation_residuals() const { return kNothing; }
  // Of the last prediction, with settings().smoothing (empty without): what a
  // smoother keeps of it. predict() and step() overwrite it.
  const Prediction& prediction() const { return prediction_; }

 protected:
  Filter(ModelPtr model, FilterSettings settings);

  // Called at the end of reset(): a filter that keeps more than z and P
  // (the optimal filter's last measurement) clears it here.
  virtual void restarted() {}
  // Called by retune() once settings_ holds the new noise: a filter that
  // derived something from it (a zero pattern, an inverse) derives it again.
  virtual void noise_changed() {}
  // restore()'s part for carried_state(); false if `carried` does not fit.
  virtual bool restore_carried(const Eigen::VectorXd& carried) { return carried.size() == 0; }

  // A diverged filter: non-finite state or a covariance that lost positive
  // semi-definiteness. Returns kFailedPrecondition naming what went wrong.
  Status check_estimate(const char* where) const;
  // "state h1", "parameter A1": element i of z = [x; theta] as messages name it.
  std::string element_name(Eigen::Index i) const;

  ModelPtr model_;
  FilterSettings settings_;
  double t_ = 0.0;
  Eigen::VectorXd z_;
  Eigen::MatrixXd P_;
  Eigen::VectorXd y_pred_, innovation_;
  Eigen::MatrixXd S_;
  double nis_ = 0.0;
  InputHold hold_;  // the inputs over the interval being integrated
  Prediction prediction_;  // sized at construction with settings_.smoothing

 private:
  static const Eigen::VectorXd kNothing;
};

// Creates a filter of settings.kind for `model` (validated first).
Result<std::unique_ptr<Filter>> make_filter(ModelPtr model, const FilterSettings& settings);

// Covariance and inverse covariance: P = R^-1 for a symmetric positive
// definite R (the optimal filter's initial confidence R0 gives P0), by a
// Cholesky solve; kInvalidArgument naming `what` if R is not.
Result<Eigen::MatrixXd> covariance_from_confidence(const Eigen::MatrixXd& R, const std::string& what);

}  // namespace riccati
