// Continuous-discrete extended Kalman filter (Hensen 1999, ch. 2).
//
// Between samples the state and its covariance are integrated together:
//     x' = f(x, theta, u, t),   theta' = 0
//     P' = F P + P F^T + Q,     F = d[f; 0] / d[x; theta] = [Jx Jth; 0 0]
// Because theta' = 0, the blocks of P' are
//     Pxx'   = Jx Pxx + Jth Pthx + (Jx Pxx + Jth Pthx)^T + Qxx
//     Pxth'  = Jx Pxth + Jth Pthth + Qxth
//     Pthth' = Qthth, so Pthth(t) = Pthth(t0) + Qthth (t - t0) exactly,
// and only [x; Pxx; Pxth] (nx + nx^2 + nx ntheta values, against nx + nz^2
// for the whole P) go through the integrator. The result is the same P.
// With the parameters held (no covariance and no process noise on them, as
// maximum likelihood's predictor has them) Pxth and Pthth stay zero, and
// [x; Pxx] alone is integrated.
// At a sample, with G = dg/d[x; theta] at the prior:
//     S = G P G^T + R,  K = P G^T S^-1,  z += K (y - g),
//     P = (I - K G) P (I - K G)^T + K R K^T   (Joseph form, or (I - K G) P)
//
// For a smoother (FilterSettings::smoothing) the prediction also gives the
// transition matrix over the step, Phi' = F Phi from Phi(t_k) = I, and with it
// C_k = Cov(z_k|k, z_k+1|k) = P_k|k Phi^T (the RTS smoother's gain is
// G_k = C_k P_k+1|k^-1). Its parameter rows stay [0 I], so only the nx rows
// Phi_x = [Phi_xx Phi_xth] are integrated, with the rest:
//     Phi_x' = Jx Phi_x + [0 Jth]   (the variational equations, models/variational.hpp).
#include <Eigen/Core>
#include <algorithm>
#include <string>
#include <vector>

#include "engine/filters/fixed_size.hpp"
#include "engine/filters/kalman_filter.hpp"
#include "engine/models/variational.hpp"

namespace riccati {

namespace {

// The derivatives of Pxx and Pxth (see above) at one point. J = [Jx Jth] is
// nx x nz; Pxx nx x nx, Pxth nx x nth and Pthth nth x nth (at time t); Q
// nz x nz; A nx x nx scratch; all column-major. This runs at every stage of
// every integration step: NX and NTH fix nx and nth at compile time
// (fixed_size.hpp) so the loops unroll; kDynamicSize is the general case.
template <int NX, int NTH>
void covariance_derivative(int nx_runtime, int nth_runtime, const double* __restrict J,
                           const double* __restrict Pxx, const double* __restrict Pxth,
                           const double* __restrict Pthth, const double* __restrict Q, double* __restrict A,
                           double* __restrict dPxx, double* __restrict dPxth) {
  const int nx = size_or<NX>(nx_runtime);
  const int nth = size_or<NTH>(nth_runtime);
  const int nz = nx + nth;
  const double* Jth = J + nx * nx;
  // A = Jx Pxx + Jth Pthx, built column by column (Pthx(m, c) = Pxth(c, m)).
  for (int c = 0; c < nx; ++c) {
    double* a = A + c * nx;
    for (int i = 0; i < nx; ++i) a[i] = 0.0;
    for (int k = 0; k < nx; ++k) {
      const double p = Pxx[k + c * nx];
      for (int i = 0; i < nx; ++i) a[i] += J[i + k * nx] * p;
    }
    for (int m = 0; m < nth; ++m) {
      const double p = Pxth[c + m * nx];
      for (int i = 0; i < nx; ++i) a[i] += Jth[i + m * nx] * p;
    }
  }
  for (int c = 0; c < nx; ++c) {
    for (int r = 0; r < nx; ++r) dPxx[r + c * nx] = A[r + c * nx] + A[c + r * nx] + Q[r + c * nz];
  }
  // dPxth = Jx Pxth + Jth Pthth + Qxth, column by column.
  for (int c = 0; c < nth; ++c) {
    double* d = dPxth + c * nx;
    const double* q = Q + (nx + c) * nz;
    for (int i = 0; i < nx; ++i) d[i] = q[i];
    for (int k = 0; k < nx; ++k) {
      const double p = Pxth[k + c * nx];
      for (int i = 0; i < nx; ++i) d[i] += J[i + k * nx] * p;
    }
    for (int m = 0; m < nth; ++m) {
      const double p = Pthth[m + c * nth];
      for (int i = 0; i < nx; ++i) d[i] += Jth[i + m * nx] * p;
    }
  }
}

using CovarianceDerivativeFn = void (*)(int, int, const double*, const double*, const double*, const double*,
                                        const double*, double*, double*, double*);

// The kernel for nx states and nth parameters: fixed sizes while
// nx + nth <= kMaxFixedSize.
CovarianceDerivativeFn covariance_derivative_for(int nx, int nth) {
  if (nx + nth > kMaxFixedSize) return &covariance_derivative<kDynamicSize, kDynamicSize>;
  return kernel_for<1, kMaxFixedSize>(nx, [nth]<int NX>() {
    if constexpr (NX == kDynamicSize) {
      return &covariance_derivative<kDynamicSize, kDynamicSize>;
    } else {
      return kernel_for<0, kMaxFixedSize - NX>(nth, []<int NTH>() { return &covariance_derivative<NX, NTH>; });
    }
  });
}

// The Joseph form of the covariance update, P = (I - K G) P (I - K G)^T +
// K R K^T, symmetrised: exact for any gain, and positive semi-definite by
// construction. P nz x nz, K nz x ny, G ny x nz, R ny x ny, all column-major;
// `work` holds 3 nz^2 + nz ny. The loops run over columns of nz values, so
// NZ (fixed_size.hpp) unrolls them; ny is small and stays a run-time value.
template <int NZ>
void joseph_update(int nz_runtime, int ny, const double* __restrict K, const double* __restrict G,
                   const double* __restrict R, double* __restrict P, double* __restrict work) {
  const int nz = size_or<NZ>(nz_runtime);
  double* __restrict IKG = work;
  double* __restrict IKGP = IKG + nz * nz;
  double* __restrict Pnew = IKGP + nz * nz;
  double* __restrict KR = Pnew + nz * nz;
  for (int j = 0; j < nz; ++j) {  // I - K G
    double* c = IKG + j * nz;
    for (int i = 0; i < nz; ++i) c[i] = i == j ? 1.0 : 0.0;
    for (int m = 0; m < ny; ++m) {
      const double g = G[m + j * ny];
      for (int i = 0; i < nz; ++i) c[i] -= K[i + m * nz] * g;
    }
  }
  for (int j = 0; j < nz; ++j) {  // (I - K G) P
    double* c = IKGP + j * nz;
    for (int i = 0; i < nz; ++i) c[i] = 0.0;
    for (int k = 0; k < nz; ++k) {
      const double p = P[k + j * nz];
      for (int i = 0; i < nz; ++i) c[i] += IKG[i + k * nz] * p;
    }
  }
  for (int j = 0; j < ny; ++j) {  // K R
    double* c = KR + j * nz;
    for (int i = 0; i < nz; ++i) c[i] = 0.0;
    for (int m = 0; m < ny; ++m) {
      const double r = R[m + j * ny];
      for (int i = 0; i < nz; ++i) c[i] += K[i + m * nz] * r;
    }
  }
  for (int j = 0; j < nz; ++j) {  // (I - K G) P (I - K G)^T + K R K^T
    double* c = Pnew + j * nz;
    for (int i = 0; i < nz; ++i) c[i] = 0.0;
    for (int k = 0; k < nz; ++k) {
      const double a = IKG[j + k * nz];
      for (int i = 0; i < nz; ++i) c[i] += IKGP[i + k * nz] * a;
    }
    for (int m = 0; m < ny; ++m) {
      const double k = K[j + m * nz];
      for (int i = 0; i < nz; ++i) c[i] += KR[i + m * nz] * k;
    }
  }
  for (int j = 0; j < nz; ++j) {
    for (int i = 0; i < nz; ++i) P[i + j * nz] = 0.5 * (Pnew[i + j * nz] + Pnew[j + i * nz]);
  }
}

using JosephUpdateFn = void (*)(int, int, const double*, const double*, const double*, double*, double*);

class Ekf final : public KalmanFilter {
 public:
  Ekf(ModelPtr model, const FilterSettings& settings, std::unique_ptr<Integrator> integrator)
      : KalmanFilter(std::move(model), settings),
        integrator_(std::move(integrator)),
        rhs_(this),
        smoothing_rhs_(this),
        held_rhs_(this) {
    const int nx = model_->nx(), nz = model_->nz(), ny = model_->ny();
    const int nth = nz - nx;
    // [x; Pxx; Pxth], and Phi_x when smoothing.
    y_.resize(nx + nx * nx + nx * nth + (settings_.smoothing ? nx * nz : 0));
    if (settings_.smoothing) {
      transition_derivative_ = variational_derivative_for(nx);
      P_start_.resize(nz, nz);
    }
    jac_f_.resize(nx, nz);
    A_.resize(nx, nx);
    Pthth0_.resize(nth, nth);
    Pthth_.resize(nth, nth);
    noise_changed();
    covariance_derivative_ = covariance_derivative_for(nx, nth);
    held_covariance_derivative_ = covariance_derivative_for(nx, 0);
    joseph_update_ = kernel_for<1, kMaxFixedSize>(nz, []<int NZ>() { return &joseph_update<NZ>; });
    G_.resize(ny, nz);
    PGt_.resize(nz, ny);
    joseph_work_.resize(3 * nz * nz + nz * ny);
    Pnew_.resize(nz, nz);
  }

  // What the prediction takes from Q: its parameters' block's zero pattern, and its states' block.
  void noise_changed() override {
    const int nx = model_->nx(), nth = model_->nz() - nx;
    q_thth_is_zero_ = settings_.Q.bottomRightCorner(nth, nth).isZero(0.0);
    q_theta_is_zero_ = settings_.Q.rightCols(nth).isZero(0.0);
    Qxx_ = settings_.Q.topLeftCorner(nx, nx);
  }

  Status predict(double t1, const double* u0, const double* u1) override {
    if (!(t1 > t_)) {
      return invalid_argument("predict to t = " + std::to_string(t1) + " is not after the filter's time " +
                              std::to_string(t_));
    }
    const int nx = model_->nx(), nz = model_->nz(), nth = nz - nx;
    // Parameters held (no covariance, no process noise: maximum likelihood's
    // predictor): Pxth' = Jx Pxth + Jth Pthth + Qxth = 0 keeps Pxth and Pthth
    // zero, so only [x; Pxx] is integrated, and Pxx' loses only terms that
    // were exact zeros: the same P.
    const bool held = !settings_.smoothing && q_theta_is_zero_ && P_.rightCols(nth).isZero(0.0);
    double* y = y_.data();
    Eigen::Map<Eigen::VectorXd>(y, nx) = z_.head(nx);
    Eigen::Map<Eigen::MatrixXd>(y + nx, nx, nx) = P_.topLeftCorner(nx, nx);
    if (!held) {
      Eigen::Map<Eigen::MatrixXd>(y + nx + nx * nx, nx, nth) = P_.topRightCorner(nx, nth);
      Pthth0_ = P_.bottomRightCorner(nth, nth);
      Pthth_ = Pthth0_;
    }
    double* Phi_x = y + nx + nx * nx + nx * nth;
    if (settings_.smoothing) {
      P_start_ = P_;
      Eigen::Map<Eigen::MatrixXd>(Phi_x, nx, nz).setIdentity();  // Phi_x(t_k) = [I 0]
    }
    hold_.set_interval(t_, t1, u0, u1);
    Status s = held                  ? integrator_->integrate(held_rhs_, t_, t1, {y, std::size_t(nx + nx * nx)})
               : settings_.smoothing ? integrator_->integrate(smoothing_rhs_, t_, t1, y_)
                                     : integrator_->integrate(rhs_, t_, t1, y_);
    if (!s.is_ok()) return s.with_context("EKF prediction from t = " + std::to_string(t_));
    z_.head(nx) = Eigen::Map<const Eigen::VectorXd>(y, nx);
    const Eigen::Map<const Eigen::MatrixXd> Pxx(y + nx, nx, nx);
    P_.topLeftCorner(nx, nx) = 0.5 * (Pxx + Pxx.transpose());
    if (!held) {
      P_.topRightCorner(nx, nth) = Eigen::Map<const Eigen::MatrixXd>(y + nx + nx * nx, nx, nth);
      P_.bottomLeftCorner(nth, nx) = P_.topRightCorner(nx, nth).transpose();
      P_.bottomRightCorner(nth, nth) = Pthth0_ + settings_.Q.bottomRightCorner(nth, nth) * (t1 - t_);
    }
    t_ = t1;
    if (settings_.smoothing) {
      // C = P_k|k Phi^T with Phi = [Phi_x; 0 I]: P_k|k Phi_x^T, then P_k|k's parameter columns.
      prediction_.z = z_;
      prediction_.P = P_;
      prediction_.C.leftCols(nx).noalias() = P_start_ * Eigen::Map<const Eigen::MatrixXd>(Phi_x, nx, nz).transpose();
      prediction_.C.rightCols(nth) = P_start_.rightCols(nth);
    }
    return check_estimate("EKF prediction");
  }

  Status update(const double* y, const double* u) override {
    const int nx = model_->nx(), ny = model_->ny();
    RICCATI_RETURN_IF_ERROR(model_->g_jacobian(t_, u, z_.data(), z_.data() + nx, y_pred_.data(), G_.data())
                                .with_context("EKF update"));
    for (int i = 0; i < ny; ++i) innovation_[i] = y[i] - y_pred_[i];
    // Products of these small matrices coefficient by coefficient: Eigen's
    // blocked kernel costs more in packing than it saves here.
    PGt_.noalias() = P_.lazyProduct(G_.transpose());
    S_.noalias() = G_.lazyProduct(PGt_);
    S_ += settings_.R;
    RICCATI_RETURN_IF_ERROR(gain_and_nis(PGt_));
    z_.noalias() += K_ * innovation_;
    if (settings_.joseph) {
      joseph_update_(static_cast<int>(P_.rows()), ny, K_.data(), G_.data(), settings_.R.data(), P_.data(),
                     joseph_work_.data());
    } else {
      Pnew_ = P_;
      Pnew_.noalias() -= K_.lazyProduct(PGt_.transpose());
      P_ = 0.5 * (Pnew_ + Pnew_.transpose());
    }
    return check_estimate("EKF update");
  }

 private:
  // What is integrated between two samples: the joint system [x; vec(Pxx);
  // vec(Pxth)] (kJoint), with Phi_x after it (kTransition: smoothing; a system
  // of its own, so that the filter without it evaluates exactly what it did
  // before), or [x; vec(Pxx)] alone with the parameters held (kHeld).
  enum class System { kJoint, kTransition, kHeld };
  template <System kSystem>
  class Rhs final : public OdeRhs {
   public:
    explicit Rhs(Ekf* ekf) : ekf_(ekf) {}
    Status eval(double t, const double* y, double* ydot) override {
      return ekf_->derivatives<kSystem>(t, y, ydot);
    }

   private:
    Ekf* ekf_;
  };

  template <System kSystem>
  Status derivatives(double t, const double* y, double* ydot) {
    const int nx = model_->nx(), nth = model_->ntheta();
    const double* theta = z_.data() + nx;  // constant over the interval
    RICCATI_RETURN_IF_ERROR(model_->f_jacobian(t, hold_.at(t), y, theta, ydot, jac_f_.data()));
    const double* Pxx = y + nx;
    if constexpr (kSystem == System::kHeld) {
      held_covariance_derivative_(nx, 0, jac_f_.data(), Pxx, nullptr, nullptr, Qxx_.data(), A_.data(), ydot + nx,
                                  nullptr);
      return Status::ok();
    }
    if (!q_thth_is_zero_) Pthth_ = Pthth0_ + settings_.Q.bottomRightCorner(nth, nth) * (t - hold_.t0());
    const double* Pxth = Pxx + nx * nx;
    covariance_derivative_(nx, nth, jac_f_.data(), Pxx, Pxth, Pthth_.data(), settings_.Q.data(), A_.data(),
                          ydot + nx, ydot + nx + nx * nx);
    if constexpr (kSystem == System::kTransition) {
      const int offset = nx + nx * nx + nx * nth;
      transition_derivative_(nx, nx + nth, nx, jac_f_.data(), y + offset, ydot + offset);
    }
    return Status::ok();
  }

  std::unique_ptr<Integrator> integrator_;
  Rhs<System::kJoint> rhs_;
  Rhs<System::kTransition> smoothing_rhs_;
  Rhs<System::kHeld> held_rhs_;
  bool q_thth_is_zero_ = true;
  bool q_theta_is_zero_ = true;  // Q's parameter rows and columns: no process noise on them
  Eigen::MatrixXd Qxx_;          // Q's states' block, alone (for kHeld: a covariance kernel with nth = 0)
  CovarianceDerivativeFn covariance_derivative_ = nullptr;       // for [x; Pxx; Pxth]
  CovarianceDerivativeFn held_covariance_derivative_ = nullptr;  // for [x; Pxx] (nth = 0)
  JosephUpdateFn joseph_update_ = nullptr;
  VariationalDerivativeFn transition_derivative_ = nullptr;  // Phi_x' = Jx Phi_x + [0 Jth]
  Eigen::MatrixXd P_start_;  // P_k|k, kept over the prediction when smoothing
  // Work space, sized once.
  std::vector<double> y_;
  Eigen::MatrixXd jac_f_, A_, G_, PGt_, Pnew_;
  std::vector<double> joseph_work_;
  Eigen::MatrixXd Pthth0_, Pthth_;  // parameter covariance at the start of the interval, and at time t
};

}  // namespace

Status validate_ekf(const FilterSettings& settings, const Model& model) {
  return validate_noise_covariances(settings, model);
}

std::unique_ptr<Filter> make_ekf(ModelPtr model, const FilterSettings& settings,
                                 std::unique_ptr<Integrator> integrator) {
  return std::make_unique<Ekf>(std::move(model), settings, std::move(integrator));
}

}  // namespace riccati
