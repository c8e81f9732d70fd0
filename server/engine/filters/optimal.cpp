// The optimal filter of van de Molengraft and van Kessel for mechanical
// models (specification: OPTIMAL_FILTER.md, equations 8-10 and sec. 3).
//
// With n degrees of freedom, x = [s; v; theta] (N = nz), p = [u; a]
// (P = nu + n) and the L = n + nu + ny equations
//     E z = f(x) + F(x) p + zeta,  f = [h; 0; g],  F = [-H M; I 0; R G],
//     E z = [0; u measured; y measured]
// taken as soft constraints weighted by V, and x' = A x + B p + xi weighted
// by W (A x = [v; 0; 0], B p = [0; a; 0]), at the estimate x^:
//     D = F(x^),  K = (D'VD)^-1,  r = E z - f(x^)
//     p^ = K D'V r,  zeta = r - D p^                                    (eq 9)
//     C = d(f + F p)/dx at (x^, p^),  A~ = A - B K D'V C,
//     V~ = V - V D K D' V
//     Q' = B K B' + W^-1 + A~ Q + Q A~' - Q C'V~C Q                     (eq 8)
//     x^' = A x^ + B p^ + Q C' V zeta                                   (eq 10)
// from x^(t0) = q0, Q(t0) = R0^-1 (the initial covariance P0). The
// accelerations and inputs are estimated by weighted least squares at every
// instant, so M is never inverted, only D'VD (by Cholesky).
//
// The split-step form integrates eq 8 and 10 without their measurement
// terms and then updates at each sample, over the interval dt (sec. 3):
//     V~ = U U',  Hm = U'C,  y = U'r,  S = Hm Q Hm' + I/dt,
//     G = Q Hm' S^-1,  x^ += G y,  Q = (I - G Hm) Q (I - G Hm)' + G G'/dt,
// which has the same continuous limit and is stable for any V.
//
// The matrices are small (N = 10 for the manipulator): their products are
// evaluated coefficient by coefficient (lazyProduct), which at these sizes
// costs far less than the blocked general product with its packing.
//
// In the Filter interface, predict() integrates with the outputs held at the
// last measurement; step() interpolates them up to the new one when the
// settings ask for it; update() takes the measurement (the split-step form
// updates, the continuous form only evaluates the residuals: its
// measurements act during the integration).
#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <string>
#include <vector>

#include "engine/filters/filter.hpp"

namespace riccati {

namespace {

class OptimalFilter final : public Filter {
 public:
  OptimalFilter(ModelPtr model, const FilterSettings& settings, std::unique_ptr<Integrator> integrator)
      : Filter(std::move(model), settings), integrator_(std::move(integrator)), rhs_(this) {
    n_ = model_->ndof();
    const int nu = model_->nu(), ny = model_->ny(), N = model_->nz();
    const int L = optimal_equation_count(*model_), P = nu + n_, Lp = n_ + ny;
    V_ = settings_.optimal.V;
    Winv_ = settings_.optimal.W.llt().solve(Eigen::MatrixXd::Identity(N, N));
    Winv_ = 0.5 * (Winv_ + Winv_.transpose());
    continuous_ = settings_.optimal.form == OptimalForm::kContinuous;
    c_.resize(Lp);
    Fc_.resize(Lp, P);
    c_jac_.resize(Lp, N);
    Fc_jac_.resize(Lp * P, N);
    D_ = Eigen::MatrixXd::Zero(L, P);
    D_.block(n_, 0, nu, nu).setIdentity();  // the measured inputs: u = I u
    r_.resize(L);
    C_ = Eigen::MatrixXd::Zero(L, N);  // the input rows stay zero
    VD_.resize(L, P);
    DVD_.resize(P, P);
    dvd_ = Eigen::LLT<Eigen::MatrixXd>(P);
    DVr_.resize(P);
    KDVC_.resize(P, N);
    K_pp_.resize(P, P);
    KDV_.resize(P, L);
    Vt_.resize(L, L);
    Vzeta_.resize(L);
    CtVzeta_.resize(N);
    Qs_.resize(N, N);
    AQ_.resize(N, N);
    CQ_.resize(L, N);
    VtCQ_.resize(L, N);
    p_hat_ = Eigen::VectorXd::Zero(P);
    zeta_ = Eigen::VectorXd::Zero(L);
    u0_.resize(nu);
    u1_.resize(nu);
    u_now_.resize(nu);
    y_last_.resize(ny);
    y_next_.resize(ny);
    y_now_.resize(ny);
    w_.resize(N + N * N);
    identity_P_ = Eigen::MatrixXd::Identity(P, P);
    // Split-step update.
    vt_ldlt_ = Eigen::LDLT<Eigen::MatrixXd>(L);
    Lfactor_.resize(L, L);
    U_.resize(L, L);
    Hm_.resize(L, N);
    yv_.resize(L);
    Syv_.resize(L);
    Sm_.resize(L, L);
    s_llt_ = Eigen::LLT<Eigen::MatrixXd>(L);
    HmQ_.resize(L, N);
    GainT_.resize(L, N);
    Gain_.resize(N, L);
    IGH_.resize(N, N);
    IGHP_.resize(N, N);
    Pnew_.resize(N, N);
    p_check_ = Eigen::LLT<Eigen::MatrixXd>(N);
  }

  // [has a measurement (0 or 1); the interval not yet followed by an
  // update; the last measurement y].
  Eigen::VectorXd carried_state() const override {
    Eigen::VectorXd c(2 + y_last_.size());
    c << (has_measurement_ ? 1.0 : 0.0), interval_, y_last_;
    return c;
  }

  Status predict(double t1, const double* u0, const double* u1) override {
    return propagate(t1, u0, u1, nullptr);
  }

  Status step(double t1, const double* u0, const double* u1, const double* y1) override {
    RICCATI_RETURN_IF_ERROR(propagate(t1, u0, u1, settings_.optimal.interpolate_outputs ? y1 : nullptr));
    return update(y1, u1);
  }

  Status update(const double* y, const double* u) override {
    const int ny = model_->ny();
    y_last_ = Eigen::Map<const Eigen::VectorXd>(y, ny);
    has_measurement_ = true;
    const Status evaluated = equations(t_, z_.data(), u, y);
    if (!evaluated.is_ok()) return evaluated.with_context("optimal filter at t = " + std::to_string(t_));
    innovation_ = zeta_.tail(ny);
    y_pred_ = y_last_ - innovation_;
    const double dt = interval_;
    interval_ = 0.0;  // consumed: a second update at the same time adds nothing
    if (continuous_ || dt <= 0.0) {
      // The weighted squared residual over the interval: with V = 1/(sigma^2
      // dt) per row, a chi-square with as many degrees of freedom as rows
      // that the least squares leave free.
      Vzeta_.noalias() = V_ * zeta_;
      nis_ = zeta_.dot(Vzeta_) * dt;
      return Status::ok();
    }
    return split_step_update(dt);
  }

 protected:
  void restarted() override {
    has_measurement_ = false;
    interval_ = 0.0;
  }

  bool restore_carried(const Eigen::VectorXd& c) override {
    if (c.size() != 2 + y_last_.size()) return false;
    has_measurement_ = c[0] != 0.0;
    interval_ = c[1];
    y_last_ = c.tail(y_last_.size());
    return true;
  }

 private:
  class Rhs final : public OdeRhs {
   public:
    explicit Rhs(OptimalFilter* filter) : filter_(filter) {}
    Status eval(double t, const double* y, double* ydot) override { return filter_->derivatives(t, y, ydot); }

   private:
    OptimalFilter* filter_;
  };

  // Integrates [x^; Q] from time() to t1 with the inputs held and the
  // outputs interpolated towards y1, or held at the last measurement when
  // y1 is null.
  Status propagate(double t1, const double* u0, const double* u1, const double* y1) {
    if (!has_measurement_) {
      return failed_precondition("the optimal filter needs a measurement at t = " + std::to_string(t_) +
                                 " before it can predict (update first)");
    }
    if (!(t1 > t_)) {
      return invalid_argument("predict to t = " + std::to_string(t1) + " is not after the filter's time " +
                              std::to_string(t_));
    }
    const int nu = model_->nu(), ny = model_->ny(), N = model_->nz();
    t0_ = t_;
    t1_ = t1;
    u0_ = Eigen::Map<const Eigen::VectorXd>(u0, nu);
    u1_ = Eigen::Map<const Eigen::VectorXd>(u1, nu);
    interpolating_ = y1 != nullptr;
    if (interpolating_) y_next_ = Eigen::Map<const Eigen::VectorXd>(y1, ny);
    Eigen::Map<Eigen::VectorXd>(w_.data(), N) = z_;
    Eigen::Map<Eigen::MatrixXd>(w_.data() + N, N, N) = P_;
    Status s = integrator_->integrate(rhs_, t_, t1, w_);
    if (!s.is_ok()) return s.with_context("optimal filter prediction from t = " + std::to_string(t_));
    z_ = Eigen::Map<const Eigen::VectorXd>(w_.data(), N);
    const Eigen::Map<const Eigen::MatrixXd> Q(w_.data() + N, N, N);
    P_ = 0.5 * (Q + Q.transpose());
    interval_ = t1 - t_;
    t_ = t1;
    return check("prediction");
  }

  // Equation 9 at (t, x) with the measurement [u; y]: D, r, p^, zeta, C,
  // the Cholesky factor of D'VD and what eq. 8 needs of K.
  Status equations(double t, const double* x, const double* u, const double* y) {
    const int nu = model_->nu(), ny = model_->ny(), nx = model_->nx();
    const int P = nu + n_, Lp = n_ + ny;
    RICCATI_RETURN_IF_ERROR(
        model_->mechanical(t, x, x + nx, c_.data(), Fc_.data(), c_jac_.data(), Fc_jac_.data()));
    // Rows: n equations of motion, nu measured inputs, ny measured outputs.
    D_.topRows(n_) = Fc_.topRows(n_);
    D_.bottomRows(ny) = Fc_.bottomRows(ny);
    r_.head(n_) = -c_.head(n_);
    r_.segment(n_, nu) = Eigen::Map<const Eigen::VectorXd>(u, nu);
    r_.tail(ny) = Eigen::Map<const Eigen::VectorXd>(y, ny) - c_.tail(ny);
    VD_.noalias() = V_.lazyProduct(D_);
    DVD_.noalias() = D_.transpose().lazyProduct(VD_);
    dvd_.compute(DVD_);
    if (dvd_.info() != Eigen::Success) {
      return failed_precondition(
          "D'VD is singular: the inputs and accelerations are not determined by the weighted equations (give "
          "the measured inputs, or outputs that see the accelerations, a positive weight in V)");
    }
    DVr_.noalias() = VD_.transpose() * r_;
    p_hat_ = dvd_.solve(DVr_);
    zeta_ = r_;
    zeta_.noalias() -= D_ * p_hat_;
    // C = d(f + F p)/dx with p held at p^; the input rows are constant.
    auto C_motion = C_.topRows(n_);
    auto C_output = C_.bottomRows(ny);
    C_motion = c_jac_.topRows(n_);
    C_output = c_jac_.bottomRows(ny);
    for (int j = 0; j < P; ++j) {
      const auto dF = Fc_jac_.middleRows(j * Lp, Lp);
      C_motion += p_hat_[j] * dF.topRows(n_);
      C_output += p_hat_[j] * dF.bottomRows(ny);
    }
    KDV_ = dvd_.solve(VD_.transpose());
    KDVC_.noalias() = KDV_.lazyProduct(C_);
    K_pp_ = dvd_.solve(identity_P_);
    Vt_ = V_;
    Vt_.noalias() -= VD_.lazyProduct(KDV_);
    return Status::ok();
  }

  // The right-hand side of [x^; vec Q] (eq 8 and 10; without their
  // measurement terms in the split-step form).
  Status derivatives(double t, const double* w, double* wdot) {
    const int N = model_->nz(), nth = N - 2 * n_, nu = model_->nu();
    hold_input(t, t0_, t1_, u0_.data(), u1_.data());
    u_now_ = u_hold_;
    if (interpolating_) {
      const double a = (t - t0_) / (t1_ - t0_);
      y_now_ = y_last_ + a * (y_next_ - y_last_);
    } else {
      y_now_ = y_last_;
    }
    const Eigen::Map<const Eigen::MatrixXd> Q(w + N, N, N);
    if (!Eigen::Map<const Eigen::VectorXd>(w, N).allFinite() || !Q.allFinite()) {
      // An explicit step past the stiffness limit blows up inside the step.
      return with_divergence_hint(failed_precondition("filter diverged: the estimate is not finite at t = " +
                                                      std::to_string(t) + " inside the step"));
    }
    RICCATI_RETURN_IF_ERROR(equations(t, w, u_now_.data(), y_now_.data()));
    Qs_ = 0.5 * (Q + Q.transpose());  // Q is symmetric but for rounding inside a step
    Eigen::Map<Eigen::VectorXd> xdot(wdot, N);
    Eigen::Map<Eigen::MatrixXd> Qdot(wdot + N, N, N);
    // A x^ + B p^ = [v; a^; 0]
    xdot.head(n_) = Eigen::Map<const Eigen::VectorXd>(w + n_, n_);
    xdot.segment(n_, n_) = p_hat_.segment(nu, n_);
    xdot.tail(nth).setZero();
    // A~ Q: the rows of s take the rows of v of Q; the rows of v take
    // -(K D'V C)_a Q; the rows of theta are zero.
    AQ_.topRows(n_) = Qs_.middleRows(n_, n_);
    AQ_.middleRows(n_, n_).noalias() = -KDVC_.bottomRows(n_).lazyProduct(Qs_);
    AQ_.bottomRows(nth).setZero();
    Qdot = AQ_ + AQ_.transpose() + Winv_;
    Qdot.block(n_, n_, n_, n_) += K_pp_.bottomRightCorner(n_, n_);  // B K B'
    if (continuous_) {
      Vzeta_.noalias() = V_ * zeta_;
      CtVzeta_.noalias() = C_.transpose() * Vzeta_;
      xdot.noalias() += Qs_ * CtVzeta_;
      CQ_.noalias() = C_.lazyProduct(Qs_);
      VtCQ_.noalias() = Vt_.lazyProduct(CQ_);
      Qdot.noalias() -= CQ_.transpose().lazyProduct(VtCQ_);
    }
    return Status::ok();
  }

  // The discrete update of the split-step form at time(), after equations()
  // was evaluated there with the measurement.
  Status split_step_update(double dt) {
    // V~ = U U' from its LDL' factorisation with pivoting (V~ is only
    // semi-definite: its rank is L - (nu + n)).
    vt_ldlt_.compute(Vt_);
    Lfactor_ = vt_ldlt_.matrixL();
    Lfactor_ = Lfactor_ * vt_ldlt_.vectorD().cwiseMax(0.0).cwiseSqrt().asDiagonal();
    U_.noalias() = vt_ldlt_.transpositionsP().transpose() * Lfactor_;
    Hm_.noalias() = U_.transpose().lazyProduct(C_);
    yv_.noalias() = U_.transpose() * r_;
    HmQ_.noalias() = Hm_.lazyProduct(P_);
    Sm_.noalias() = HmQ_.lazyProduct(Hm_.transpose());
    Sm_.diagonal().array() += 1.0 / dt;
    s_llt_.compute(Sm_);
    if (s_llt_.info() != Eigen::Success) {
      return failed_precondition("filter diverged: the update's S is not positive definite at t = " +
                                 std::to_string(t_));
    }
    GainT_ = s_llt_.solve(HmQ_);  // G' = S^-1 Hm Q, Q symmetric
    Gain_ = GainT_.transpose();
    Syv_ = s_llt_.solve(yv_);
    nis_ = yv_.dot(Syv_);
    z_.noalias() += Gain_ * yv_;
    IGH_.setIdentity();
    IGH_.noalias() -= Gain_.lazyProduct(Hm_);
    IGHP_.noalias() = IGH_.lazyProduct(P_);
    Pnew_.noalias() = IGHP_.lazyProduct(IGH_.transpose());
    Pnew_.noalias() += (1.0 / dt) * Gain_.lazyProduct(Gain_.transpose());
    P_ = 0.5 * (Pnew_ + Pnew_.transpose());
    return check("update");
  }

  // A diverged filter: non-finite estimate, or Q no longer positive definite.
  Status check(const char* where) {
    Status s = check_estimate(where);
    if (s.is_ok()) {
      p_check_.compute(P_);
      if (p_check_.info() == Eigen::Success) return Status::ok();
      s = failed_precondition(std::string("filter diverged: Q lost positive definiteness after the ") + where +
                              " at t = " + std::to_string(t_));
    }
    return with_divergence_hint(s);
  }

  static Status with_divergence_hint(const Status& s) {
    return Status(s.code(), s.message() + kDivergenceHint);
  }
  static constexpr const char* kDivergenceHint =
      ": the step is too large for the weights V (use more substeps or the split-step form)";

  std::unique_ptr<Integrator> integrator_;
  Rhs rhs_;
  int n_ = 0;  // degrees of freedom
  bool continuous_ = true;
  Eigen::MatrixXd V_, Winv_;
  // The interval being integrated (valid during propagate()).
  double t0_ = 0.0, t1_ = 0.0;
  bool interpolating_ = false;
  Eigen::VectorXd u0_, u1_, u_now_, y_last_, y_next_, y_now_;
  bool has_measurement_ = false;  // y_last_ holds the measurement at time()
  double interval_ = 0.0;         // length of the prediction not yet followed by an update
  // Work space, sized once.
  std::vector<double> w_;  // [x^; vec Q]
  Eigen::VectorXd c_, r_, DVr_, Vzeta_, CtVzeta_, yv_, Syv_;
  Eigen::MatrixXd Fc_, c_jac_, Fc_jac_, D_, C_, VD_, DVD_, KDV_, KDVC_, K_pp_, Vt_, identity_P_;
  Eigen::MatrixXd Qs_, AQ_, CQ_, VtCQ_;
  Eigen::MatrixXd Lfactor_, U_, Hm_, Sm_, HmQ_, GainT_, Gain_, IGH_, IGHP_, Pnew_;
  Eigen::LLT<Eigen::MatrixXd> dvd_, s_llt_, p_check_;
  Eigen::LDLT<Eigen::MatrixXd> vt_ldlt_;
};

}  // namespace

std::unique_ptr<Filter> make_optimal_filter(ModelPtr model, const FilterSettings& settings,
                                            std::unique_ptr<Integrator> integrator) {
  return std::make_unique<OptimalFilter>(std::move(model), settings, std::move(integrator));
}

}  // namespace riccati
