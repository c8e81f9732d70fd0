// Continuous-discrete unscented Kalman filter (Zheng, Ikeda, Shimomura 2010,
// after Julier & Uhlmann and Wan & van der Merwe).
//
// Prediction: 2n+1 sigma points z_i = z, z +- sqrt(n + lambda) s_j, with s_j
// the columns of a square root S of P (S S^T = P), are each integrated
// through x' = f over the interval (theta constant), then
//     z- = sum Wm_i z_i,   P- = sum Wc_i (z_i - z-)(z_i - z-)^T + Q dt.
// Update, with sigma points drawn afresh from z-, P- (so that they carry the
// process noise too): Y_i = g(z_i),
//     y^ = sum Wm_i Y_i,  S = sum Wc_i (Y_i - y^)(Y_i - y^)^T + R,
//     C = sum Wc_i (z_i - z-)(Y_i - y^)^T,  K = C S^-1,
//     z = z- + K (y - y^),  P = P- - K S K^T.
//
// For a smoother (FilterSettings::smoothing) the prediction also gives the
// cross covariance of the estimate and the prior, D_k+1 of Särkkä's (2008)
// unscented RTS smoother:
//     D = sum Wc_i (z_i - z)(z_i- - z-)^T
// from the points before (z_i) and after (z_i-) the integration; as z_i - z
// is 0 or +- sqrt(n + lambda) s_j, D = sqrt(n + lambda) S (Dplus - Dminus)
// with Dplus, Dminus the weighted deviations Wc_i (z_i- - z-) of the + and -
// points.
//
// Covariances with zero variances are normal here (states known exactly at
// the start): the square root comes from a Cholesky factorisation with full
// pivoting that stops at the numerical rank (as LAPACK's dpstrf), so
// directions without variance get exactly no spread.
//
// All sigma points are integrated together as one system stored variable-
// major (column i of X holds element i of every point), so the model
// evaluates f for every point in one batched call.
#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <cmath>
#include <limits>
#include <string>

#include "engine/filters/fixed_size.hpp"
#include "engine/filters/kalman_filter.hpp"

namespace riccati {

namespace {

// S with S S^T = P for a symmetric positive semi-definite P, by Cholesky with
// diagonal pivoting: each step takes the largest remaining variance; once it
// is below n eps max(diag P) the rest is rounding noise and is set to zero.
// Returns false if a remaining variance is clearly negative (P indefinite)
// or P is not finite. `w` is scratch of P's size, `perm` of n; nothing is
// allocated. All n x n, column-major. N: the size, fixed at compile time
// (fixed_size.hpp), or kDynamicSize.
template <int N>
bool psd_square_root(int n_runtime, const double* __restrict P, double* __restrict w, int* __restrict p,
                     double* __restrict s) {
  const int n = size_or<N>(n_runtime);
  double max_diag = 0.0;
  for (int i = 0; i < n * n; ++i) {
    if (!std::isfinite(P[i])) return false;
    w[i] = P[i];
    s[i] = 0.0;
  }
  for (int i = 0; i < n; ++i) {
    p[i] = i;
    max_diag = std::max(max_diag, std::abs(w[i + i * n]));
  }
  const double negligible = static_cast<double>(n) * std::numeric_limits<double>::epsilon() * max_diag;
  for (int k = 0; k < n; ++k) {
    int pivot = k;
    for (int j = k + 1; j < n; ++j) {
      if (w[j + j * n] > w[pivot + pivot * n]) pivot = j;
    }
    if (w[pivot + pivot * n] <= negligible) {
      // The rest is zero up to rounding; a clearly negative variance is not.
      for (int j = k; j < n; ++j) {
        if (w[j + j * n] < -1e-9 * std::max(1.0, max_diag)) return false;
      }
      break;
    }
    if (pivot != k) {  // symmetric swap of rows and columns k and pivot
      for (int j = 0; j < n; ++j) std::swap(w[k + j * n], w[pivot + j * n]);
      for (int i = 0; i < n; ++i) std::swap(w[i + k * n], w[i + pivot * n]);
      std::swap(p[k], p[pivot]);
    }
    const double lkk = std::sqrt(w[k + k * n]);
    double* lk = w + k * n;  // column k of the factor, in pivoted order; rows < k unused
    for (int i = k; i < n; ++i) lk[i] /= lkk;
    // The whole trailing block (both triangles), so later symmetric swaps
    // of rows and columns stay consistent.
    for (int j = k + 1; j < n; ++j) {
      double* wj = w + j * n;
      const double ljk = lk[j];
      for (int i = k + 1; i < n; ++i) wj[i] -= lk[i] * ljk;
    }
    for (int i = k; i < n; ++i) s[p[i] + k * n] = lk[i];
  }
  return true;
}

using PsdSquareRootFn = bool (*)(int, const double*, double*, int*, double*);

// lambda of the sigma points' spread sqrt(n + lambda) for n augmented states,
// from the settings' weights and kappa (NaN: the usual default).
double sigma_lambda(const UkfSettings& ukf, double n) {
  const bool scaled = ukf.weights == SigmaWeights::kScaled;
  const double kappa = std::isnan(ukf.kappa) ? (scaled ? 0.0 : 3.0 - n) : ukf.kappa;
  return scaled ? ukf.alpha * ukf.alpha * (n + kappa) - n : kappa;
}

class Ukf final : public KalmanFilter {
 public:
  Ukf(ModelPtr model, const FilterSettings& settings, std::unique_ptr<Integrator> integrator)
      : KalmanFilter(std::move(model), settings), integrator_(std::move(integrator)), rhs_(this) {
    const int nz = model_->nz(), ny = model_->ny();
    npts_ = 2 * nz + 1;
    const double n = nz;
    const bool scaled = settings_.ukf.weights == SigmaWeights::kScaled;
    const double alpha = settings_.ukf.alpha;
    const double lambda = sigma_lambda(settings_.ukf, n);
    spread_ = std::sqrt(n + lambda);
    wm_ = Eigen::VectorXd::Constant(npts_, 0.5 / (n + lambda));
    wm_[0] = lambda / (n + lambda);
    wc_ = wm_;
    if (scaled) wc_[0] += 1.0 - alpha * alpha + settings_.ukf.beta;

    X_.resize(npts_, nz);
    Ypts_.resize(npts_, ny);
    dX_.resize(npts_, nz);
    dY_.resize(npts_, ny);
    wdX_.resize(npts_, nz);
    wdY_.resize(npts_, ny);
    sqrtP_.resize(nz, nz);
    work_.resize(nz, nz);
    perm_.resize(nz);
    C_.resize(nz, ny);
    Pnew_.resize(nz, nz);
    q_is_zero_ = settings_.Q.isZero(0.0);
    if (settings_.smoothing) dW_.resize(nz, nz);
    psd_square_root_ = kernel_for<1, kMaxFixedSize>(nz, []<int N>() { return &psd_square_root<N>; });
  }

  void noise_changed() override { q_is_zero_ = settings_.Q.isZero(0.0); }

  Status predict(double t1, const double* u0, const double* u1) override {
    if (!(t1 > t_)) {
      return invalid_argument("predict to t = " + std::to_string(t1) + " is not after the filter's time " +
                              std::to_string(t_));
    }
    RICCATI_RETURN_IF_ERROR(draw_sigma_points());
    const int nx = model_->nx();
    hold_.set_interval(t_, t1, u0, u1);
    // Columns 0..nx-1 of X (the states of every point) are contiguous.
    Status s = integrator_->integrate(rhs_, t_, t1, std::span<double>(X_.data(), std::size_t(npts_) * nx));
    if (!s.is_ok()) return s.with_context("UKF prediction from t = " + std::to_string(t_));
    const double dt = t1 - t_;
    t_ = t1;
    weighted_mean_and_covariance();
    if (!q_is_zero_) P_ += settings_.Q * dt;
    if (settings_.smoothing) {
      // D from sqrtP_, still the square root the points were drawn with (see the top).
      const Eigen::Index nz = model_->nz();
      prediction_.z = z_;
      prediction_.P = P_;
      dW_ = wdX_.middleRows(1, nz) - wdX_.middleRows(1 + nz, nz);
      prediction_.C.noalias() = spread_ * sqrtP_ * dW_;
    }
    return check_estimate("UKF prediction");
  }

  Status update(const double* y, const double* u) override {
    RICCATI_RETURN_IF_ERROR(draw_sigma_points());
    const int nx = model_->nx(), ny = model_->ny();
    RICCATI_RETURN_IF_ERROR(
        model_->g(t_, u, npts_, npts_, X_.data(), X_.data() + std::size_t(npts_) * nx, Ypts_.data())
            .with_context("UKF update"));
    y_pred_.noalias() = Ypts_.transpose().lazyProduct(wm_);
    dY_ = Ypts_.rowwise() - y_pred_.transpose();
    dX_ = X_.rowwise() - z_.transpose();
    // The weighted deviations once, so that each product is one (no temporary).
    // Products of these small matrices coefficient by coefficient (lazyProduct):
    // Eigen's blocked kernel costs more in packing than it saves here.
    wdY_.noalias() = wc_.asDiagonal() * dY_;
    S_.noalias() = dY_.transpose().lazyProduct(wdY_);
    S_ += settings_.R;
    C_.noalias() = dX_.transpose().lazyProduct(wdY_);
    for (int i = 0; i < ny; ++i) innovation_[i] = y[i] - y_pred_[i];
    RICCATI_RETURN_IF_ERROR(gain_and_nis(C_));
    z_.noalias() += K_ * innovation_;
    // P - K S K^T = P - K C^T (as K S = C).
    Pnew_ = P_;
    Pnew_.noalias() -= K_.lazyProduct(C_.transpose());
    P_ = 0.5 * (Pnew_ + Pnew_.transpose());
    return check_estimate("UKF update");
  }

 private:
  class Rhs final : public OdeRhs {
   public:
    explicit Rhs(Ukf* ukf) : ukf_(ukf) {}
    Status eval(double t, const double* y, double* ydot) override {
      Ukf& u = *ukf_;
      const std::size_t ld = u.npts_;
      const double* theta = u.X_.data() + ld * u.model_->nx();  // constant over the interval
      return u.model_->f(t, u.hold_.at(t), u.npts_, ld, y, theta, ydot);
    }

   private:
    Ukf* ukf_;
  };

  // X = [z, z + c s_1 .. z + c s_n, z - c s_1 .. z - c s_n] (rows), c = spread.
  Status draw_sigma_points() {
    const Eigen::Index nz = model_->nz();
    if (!psd_square_root_(static_cast<int>(nz), P_.data(), work_.data(), perm_.data(), sqrtP_.data())) {
      return failed_precondition("UKF covariance is not positive semi-definite at t = " + std::to_string(t_) +
                                 ": the filter diverged");
    }
    // Column i of X holds variable i of every point (contiguous).
    for (Eigen::Index i = 0; i < nz; ++i) {
      double* column = X_.col(i).data();
      const double zi = z_[i];
      column[0] = zi;
      for (Eigen::Index j = 0; j < nz; ++j) {
        const double d = spread_ * sqrtP_(i, j);
        column[1 + j] = zi + d;
        column[1 + nz + j] = zi - d;
      }
    }
    return Status::ok();
  }

  void weighted_mean_and_covariance() {
    z_.noalias() = X_.transpose().lazyProduct(wm_);
    dX_ = X_.rowwise() - z_.transpose();
    wdX_.noalias() = wc_.asDiagonal() * dX_;
    P_.noalias() = dX_.transpose().lazyProduct(wdX_);
  }

  std::unique_ptr<Integrator> integrator_;
  Rhs rhs_;
  int npts_ = 0;
  double spread_ = 1.0;
  Eigen::VectorXd wm_, wc_;
  bool q_is_zero_ = false;
  // Sigma points [npts x nz] and outputs [npts x ny]: one column per variable.
  Eigen::MatrixXd X_, Ypts_, dX_, dY_;
  Eigen::MatrixXd wdX_, wdY_;  // the deviations times the covariance weights Wc
  Eigen::MatrixXd sqrtP_, C_, Pnew_;
  Eigen::MatrixXd dW_;  // Dplus - Dminus, when smoothing
  Eigen::MatrixXd work_;
  Eigen::VectorXi perm_;
  PsdSquareRootFn psd_square_root_ = nullptr;  // the kernel for this nz
};

}  // namespace

Status validate_ukf(const FilterSettings& s, const Model& model) {
  RICCATI_RETURN_IF_ERROR(validate_noise_covariances(s, model));
  const bool scaled = s.ukf.weights == SigmaWeights::kScaled;
  if (!std::isnan(s.ukf.kappa) && !std::isfinite(s.ukf.kappa)) return invalid_argument("UKF kappa must be finite");
  if (scaled && !(s.ukf.alpha > 0.0 && s.ukf.alpha <= 1.0)) return invalid_argument("UKF alpha must be in (0, 1]");
  if (scaled && !std::isfinite(s.ukf.beta)) return invalid_argument("UKF beta must be finite");
  const double n = model.nz();
  const double lambda = sigma_lambda(s.ukf, n);
  if (!(n + lambda > 0.0)) {
    return invalid_argument("UKF spread n + lambda = " + std::to_string(n + lambda) +
                            " must be positive (n = " + std::to_string(model.nz()) + "): raise kappa");
  }
  return Status::ok();
}

std::unique_ptr<Filter> make_ukf(ModelPtr model, const FilterSettings& settings,
                                 std::unique_ptr<Integrator> integrator) {
  return std::make_unique<Ukf>(std::move(model), settings, std::move(integrator));
}

}  // namespace riccati
