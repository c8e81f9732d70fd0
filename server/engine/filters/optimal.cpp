// The optimal filter of van de Molengraft and van Kessel for mechanical
// models (specification: docs/optimal-filter.md, equations 8-10 and sec. 3;
// the members are named after its symbols: x_hat_ is x^, Q_ is Q, K_ is
// K = (D'VD)^-1, V_tilde_ is V~, G_ the split-step gain G, and so on).
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
// The matrices are small (N = 10, L = 5, P = 3 for the manipulator): the
// products of equations 8-10 are plain loops whose sums stay in registers,
// those of N x N instantiated per N (fixed_size.hpp), and D'VD is solved by
// a Cholesky factorisation instantiated per P. At these sizes Eigen's
// products (blocked, with packing, or coefficient-wise) and its triangular
// solves cost several times the arithmetic (docs/benchmarks-log.md). The
// split-step update, once a sample, keeps Eigen's coefficient-wise products.
//
// In the Filter interface, predict() integrates with the outputs held at the
// last measurement; step() interpolates them up to the new one when the
// settings ask for it; update() takes the measurement (the split-step form
// updates, the continuous form only evaluates the residuals: its
// measurements act during the integration).
#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <bit>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "engine/filters/filter.hpp"
#include "engine/filters/fixed_size.hpp"
#include "engine/filters/small_cholesky.hpp"
#include "engine/scalar_loops.hpp"

namespace riccati {

namespace {

// out = a b, for matrices of a few rows and columns: each coefficient a
// sum kept in a register (Eigen's products, coefficient-wise or blocked,
// and a column-wise accumulation through memory all cost more than the
// arithmetic at these sizes). Not vectorised: loops of 3 to 5 run faster
// scalar than through the vectoriser's set-up and remainders (measured:
// this and equations() scalar took the step from 5.5 to 4.9 us).
RICCATI_SCALAR_LOOPS void multiply(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b, Eigen::MatrixXd& out) {
  const int rows = static_cast<int>(a.rows()), inner = static_cast<int>(a.cols()), cols = static_cast<int>(b.cols());
  const double* __restrict A = a.data();
  const double* __restrict B = b.data();
  double* __restrict O = out.data();
  for (int j = 0; j < cols; ++j) {
    for (int i = 0; i < rows; ++i) {
      double s = 0.0;
      for (int k = 0; k < inner; ++k) s += A[i + k * rows] * B[k + j * inner];
      O[i + j * rows] = s;
    }
  }
}

// out(:, j) (+)= alpha sum_k a(:, k) b(k, j) for j < cols, with a n x inner
// (column-major) and b(k, j) = b[k * row_stride + j * col_stride] (so that
// b can be a transpose or a row). For n fixed at compile time the column
// is summed in registers; the stores of a sum through memory otherwise
// chain each term to the last.
template <int NN>
void product_columns(int n_runtime, int inner, int cols, const double* __restrict a, const double* __restrict b,
                     int row_stride, int col_stride, double alpha, bool accumulate, double* __restrict out) {
  const int n = size_or<NN>(n_runtime);
  for (int j = 0; j < cols; ++j) {
    double* o = out + j * n;
    if constexpr (NN != kDynamicSize) {
      double sum[NN] = {};
      for (int k = 0; k < inner; ++k) {
        const double c = b[k * row_stride + j * col_stride];
        for (int i = 0; i < NN; ++i) sum[i] += a[i + k * NN] * c;
      }
      for (int i = 0; i < NN; ++i) o[i] = accumulate ? o[i] + alpha * sum[i] : alpha * sum[i];
    } else {
      for (int i = 0; i < n; ++i) {
        double sum = 0.0;
        for (int k = 0; k < inner; ++k) sum += a[i + k * n] * b[k * row_stride + j * col_stride];
        o[i] = accumulate ? o[i] + alpha * sum : alpha * sum;
      }
    }
  }
}

class OptimalFilter final : public Filter {
 public:
  OptimalFilter(ModelPtr model, const FilterSettings& settings, std::unique_ptr<Integrator> integrator)
      : Filter(std::move(model), settings), x_hat_(z_), Q_(P_), integrator_(std::move(integrator)), rhs_(this) {
    n_ = model_->ndof();
    const int nu = model_->nu(), ny = model_->ny(), N = model_->nz();
    const int L = optimal_equation_count(*model_), P = nu + n_, Lp = n_ + ny;
    noise_changed();
    continuous_ = settings_.optimal.form == OptimalForm::kContinuous;
    f_.resize(Lp);
    F_.resize(Lp, P);
    df_dx_.resize(Lp, N);
    dF_dx_.resize(Lp * P, N);
    D_ = Eigen::MatrixXd::Zero(L, P);
    D_.block(n_, 0, nu, nu).setIdentity();  // the measured inputs: u = I u
    r_.resize(L);
    C_ = Eigen::MatrixXd::Zero(L, N);  // the input rows stay zero
    VD_.resize(L, P);
    DVD_.resize(P, P);
    DVD_factor_.resize(P, P);
    KDVC_ = Eigen::MatrixXd::Zero(P, N);  // the input rows stay zero (not used)
    K_.resize(P, P);
    KDV_.resize(P, L);
    V_tilde_.resize(L, L);
    Vzeta_.resize(L);
    CtVzeta_.resize(N);
    Q_sym_.resize(N, N);
    AtQ_cols_.resize(N, 2 * n_);
    QCt_.resize(N, L);
    QCtV_tilde_.resize(N, L);
    p_hat_ = Eigen::VectorXd::Zero(P);
    zeta_ = Eigen::VectorXd::Zero(L);
    u_now_.resize(nu);
    y_last_.resize(ny);
    y_next_.resize(ny);
    y_now_.resize(ny);
    x_hat_Q_.resize(N + N * N);
    evaluated_at_.resize(1 + N + nu + ny);
    derivatives_ = kernel_for<1, kMaxFixedSize>(N, []<int NN>() { return &OptimalFilter::derivatives_for<NN>; });
    cholesky_solve_ = cholesky_solve_for(P);
    // Split-step update.
    V_tilde_ldlt_ = Eigen::LDLT<Eigen::MatrixXd>(L);
    L_factor_.resize(L, L);
    U_.resize(L, L);
    Hm_.resize(L, N);
    Ut_r_.resize(L);
    S_inv_Ut_r_.resize(L);
    S_update_.resize(L, L);
    S_update_llt_ = Eigen::LLT<Eigen::MatrixXd>(L);
    HmQ_.resize(L, N);
    Gt_.resize(L, N);
    G_.resize(N, L);
    I_GHm_.resize(N, N);
    I_GHm_Q_.resize(N, N);
    Q_new_.resize(N, N);
    Q_llt_ = Eigen::LLT<Eigen::MatrixXd>(N);
  }

  // [has a measurement (0 or 1); the interval not yet followed by an
  // update; the last measurement y].
  Eigen::VectorXd carried_state() const override {
    Eigen::VectorXd c(2 + y_last_.size());
    c << (has_measurement_ ? 1.0 : 0.0), interval_, y_last_;
    return c;
  }

  // The weights as the steps use them: V, and W^-1 (symmetric to the bit).
  void noise_changed() override {
    const int N = model_->nz();
    V_ = settings_.optimal.V;
    evaluated_ = false;  // equations() depends on V
    W_inv_ = settings_.optimal.W.llt().solve(Eigen::MatrixXd::Identity(N, N));
    W_inv_ = 0.5 * (W_inv_ + W_inv_.transpose());
  }

  Status predict(double t1, const double* u0, const double* u1) override {
    return propagate(t1, u0, u1, nullptr);
  }

  const Eigen::VectorXd& estimated_inputs() const override { return p_hat_; }
  const Eigen::VectorXd& equation_residuals() const override { return zeta_; }

  Status step(double t1, const double* u0, const double* u1, const double* y1) override {
    RICCATI_RETURN_IF_ERROR(propagate(t1, u0, u1, settings_.optimal.interpolate_outputs ? y1 : nullptr));
    return update(y1, u1);
  }

  Status update(const double* y, const double* u) override {
    const int ny = model_->ny();
    y_last_ = Eigen::Map<const Eigen::VectorXd>(y, ny);
    has_measurement_ = true;
    const Status evaluated = equations(t_, x_hat_.data(), u, y);
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
    evaluated_ = false;
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
    Status eval(double t, const double* y, double* ydot) override {
      return (filter_->*(filter_->derivatives_))(t, y, ydot);
    }

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
    const int ny = model_->ny(), N = model_->nz();
    hold_.set_interval(t_, t1, u0, u1);
    interpolating_ = y1 != nullptr;
    if (interpolating_) y_next_ = Eigen::Map<const Eigen::VectorXd>(y1, ny);
    Eigen::Map<Eigen::VectorXd>(x_hat_Q_.data(), N) = x_hat_;
    Eigen::Map<Eigen::MatrixXd>(x_hat_Q_.data() + N, N, N) = Q_;
    Status s = integrator_->integrate(rhs_, t_, t1, x_hat_Q_);
    if (!s.is_ok()) return s.with_context("optimal filter prediction from t = " + std::to_string(t_));
    x_hat_ = Eigen::Map<const Eigen::VectorXd>(x_hat_Q_.data(), N);
    const Eigen::Map<const Eigen::MatrixXd> Q(x_hat_Q_.data() + N, N, N);
    Q_ = 0.5 * (Q + Q.transpose());
    interval_ = t1 - t_;
    t_ = t1;
    return check("prediction");
  }

  // Equation 9 at (t, x) with the measurement [u; y]: D, r, p^, zeta, C,
  // the Cholesky factor of D'VD and what eq. 8 needs of K. Scalar, as
  // multiply() (its innermost loops run over L or P: a few each).
  RICCATI_SCALAR_LOOPS Status equations(double t, const double* x, const double* u, const double* y) {
    const int nu = model_->nu(), ny = model_->ny(), nx = model_->nx();
    const int P = nu + n_, Lp = n_ + ny;
    if (already_evaluated(t, x, u, y)) return Status::ok();
    RICCATI_RETURN_IF_ERROR(
        model_->mechanical(t, x, x + nx, f_.data(), F_.data(), df_dx_.data(), dF_dx_.data()));
    // Rows: n equations of motion, nu measured inputs, ny measured outputs.
    D_.topRows(n_) = F_.topRows(n_);
    D_.bottomRows(ny) = F_.bottomRows(ny);
    r_.head(n_) = -f_.head(n_);
    r_.segment(n_, nu) = Eigen::Map<const Eigen::VectorXd>(u, nu);
    r_.tail(ny) = Eigen::Map<const Eigen::VectorXd>(y, ny) - f_.tail(ny);
    // The products below are of a few rows and columns (L = 5, P = 3 for
    // the manipulator): plain loops, column by column.
    const int L = static_cast<int>(r_.size());
    multiply(V_, D_, VD_);
    for (int j = 0; j < P; ++j) {  // D'VD, symmetric: the lower triangle, mirrored
      for (int i = j; i < P; ++i) DVD_(i, j) = DVD_(j, i) = D_.col(i).dot(VD_.col(j));
    }
    if (!cholesky(P, DVD_.data(), DVD_factor_.data())) {
      return failed_precondition(
          "D'VD is singular: the inputs and accelerations are not determined by the weighted equations (give "
          "the measured inputs, or outputs that see the accelerations, a positive weight in V)");
    }
    // K D'V = (D'VD)^-1 (VD)' and K = (D'VD)^-1, by the Cholesky factor.
    for (int l = 0; l < L; ++l) {
      for (int i = 0; i < P; ++i) KDV_(i, l) = VD_(l, i);
    }
    cholesky_solve_(P, DVD_factor_.data(), KDV_.data(), L);
    K_.setIdentity();
    cholesky_solve_(P, DVD_factor_.data(), K_.data(), P);
    // Each coefficient below is a sum kept in a register.
    for (int i = 0; i < P; ++i) {  // p^ = K D'V r
      double s = 0.0;
      for (int l = 0; l < L; ++l) s += KDV_(i, l) * r_[l];
      p_hat_[i] = s;
    }
    for (int l = 0; l < L; ++l) {  // zeta = r - D p^
      double s = r_[l];
      for (int j = 0; j < P; ++j) s -= D_(l, j) * p_hat_[j];
      zeta_[l] = s;
    }
    // C = d(f + F p)/dx with p held at p^; the input rows are constant.
    const int N = static_cast<int>(C_.cols());
    for (int k = 0; k < N; ++k) {
      const double* df = df_dx_.col(k).data();
      const double* dF = dF_dx_.col(k).data();  // P blocks of Lp rows
      double* c = C_.col(k).data();
      for (int i = 0; i < Lp; ++i) {
        double s = df[i];
        for (int j = 0; j < P; ++j) s += p_hat_[j] * dF[j * Lp + i];
        c[i < n_ ? i : i + nu] = s;  // rows of motion, then (after the inputs') of the outputs
      }
    }
    // K D'V C, the rows of the accelerations only: eq 8 uses no other. The
    // input rows of C are zero.
    for (int k = 0; k < N; ++k) {
      const double* c = C_.col(k).data();
      for (int a = nu; a < P; ++a) {
        double s = 0.0;
        for (int l = 0; l < n_; ++l) s += KDV_(a, l) * c[l];
        for (int l = n_ + nu; l < L; ++l) s += KDV_(a, l) * c[l];
        KDVC_(a, k) = s;
      }
    }
    for (int j = 0; j < L; ++j) {  // V~ = V - VD K D'V, symmetric: the lower triangle, mirrored
      for (int i = j; i < L; ++i) {
        double s = V_(i, j);
        for (int k = 0; k < P; ++k) s -= VD_(i, k) * KDV_(k, j);
        V_tilde_(i, j) = V_tilde_(j, i) = s;
      }
    }
    evaluated_ = true;
    return Status::ok();
  }

  // Whether equations() last ran at exactly (t, x, u, y), bit for bit, and
  // succeeded: then its results stand. In the continuous form the first
  // stage of a prediction is where the update before it evaluated (the
  // estimate, the held input and the last measurement at the same time):
  // one evaluation in five of an RK4 step. (The split-step form's update
  // moves the estimate, so no evaluation repeats there.) Otherwise records
  // (t, x, u, y) for the next call, as not yet evaluated.
  bool already_evaluated(double t, const double* x, const double* u, const double* y) {
    if (!continuous_) return false;
    const int N = static_cast<int>(C_.cols()), nu = model_->nu(), ny = model_->ny();
    std::uint64_t* key = evaluated_at_.data();
    const auto same = [](const std::uint64_t* a, const double* b, int n) {
      for (int i = 0; i < n; ++i) {
        if (a[i] != std::bit_cast<std::uint64_t>(b[i])) return false;
      }
      return true;
    };
    if (evaluated_ && same(key, &t, 1) && same(key + 1, x, N) && same(key + 1 + N, u, nu) &&
        same(key + 1 + N + nu, y, ny)) {
      return true;
    }
    evaluated_ = false;
    const auto record = [](std::uint64_t* a, const double* b, int n) {
      for (int i = 0; i < n; ++i) a[i] = std::bit_cast<std::uint64_t>(b[i]);
    };
    record(key, &t, 1);
    record(key + 1, x, N);
    record(key + 1 + N, u, nu);
    record(key + 1 + N + nu, y, ny);
    return false;
  }

  // The right-hand side of [x^; vec Q] (eq 8 and 10; without their
  // measurement terms in the split-step form), for N = nz fixed at compile
  // time (fixed_size.hpp): its N x N loops are most of a step.
  template <int NN>
  Status derivatives_for(double t, const double* w, double* wdot) {
    const int N = size_or<NN>(model_->nz()), nu = model_->nu(), L = static_cast<int>(r_.size());
    const int n = n_;
    u_now_ = Eigen::Map<const Eigen::VectorXd>(hold_.at(t), u_now_.size());
    if (interpolating_) {
      const double a = (t - hold_.t0()) / (hold_.t1() - hold_.t0());
      y_now_ = y_last_ + a * (y_next_ - y_last_);
    } else {
      y_now_ = y_last_;
    }
    const double* Q = w + N;
    if (!Eigen::Map<const Eigen::VectorXd>(w, N + N * N).allFinite()) {
      // An explicit step past the stiffness limit blows up inside the step.
      return with_divergence_hint(failed_precondition("filter diverged: the estimate is not finite at t = " +
                                                      std::to_string(t) + " inside the step"));
    }
    RICCATI_RETURN_IF_ERROR(equations(t, w, u_now_.data(), y_now_.data()));
    double* Qs = Q_sym_.data();  // Q is symmetric but for rounding inside a step
    for (int j = 0; j < N; ++j) {
      for (int i = 0; i < N; ++i) Qs[i + j * N] = 0.5 * (Q[i + j * N] + Q[j + i * N]);
    }
    double* xdot = wdot;
    double* Qdot = wdot + N;
    // A x^ + B p^ = [v; a^; 0]
    for (int i = 0; i < n; ++i) {
      xdot[i] = w[n + i];
      xdot[n + i] = p_hat_[nu + i];
    }
    for (int i = 2 * n; i < N; ++i) xdot[i] = 0.0;
    // Q' = A~Q + (A~Q)' + W^-1 + B K B'. A~Q has 2n rows that are not zero:
    // those of s take the rows of v of Q, those of v take -(K D'V C)_a Q.
    // Its rows are kept as columns (Q is symmetric).
    const double* W_inv = W_inv_.data();
    for (int i = 0; i < N * N; ++i) Qdot[i] = W_inv[i];
    for (int b = 0; b < n; ++b) {
      for (int a = 0; a < n; ++a) Qdot[(n + a) + (n + b) * N] += K_(nu + a, nu + b);
    }
    double* rows = AtQ_cols_.data();
    const int P = nu + n;
    for (int a = 0; a < n; ++a) {
      for (int i = 0; i < N; ++i) rows[i + a * N] = Qs[i + (n + a) * N];
    }
    // The rows of v: -Q (K D'V C)_a', column a of it -Q KDVC(nu + a, :)'.
    product_columns<NN>(N, N, n, Qs, KDVC_.data() + nu, P, 1, -1.0, false, rows + n * N);
    for (int r = 0; r < 2 * n; ++r) {
      const double* row = rows + r * N;
      for (int i = 0; i < N; ++i) {
        Qdot[r + i * N] += row[i];
        Qdot[i + r * N] += row[i];
      }
    }
    if (continuous_) {
      // x^' += Q C'V zeta;  Q' -= Q C' V~ C Q, as (Q C') (Q C' V~)'.
      for (int i = 0; i < L; ++i) {
        double sum = 0.0;
        for (int l = 0; l < L; ++l) sum += V_(i, l) * zeta_[l];
        Vzeta_[i] = sum;
      }
      for (int k = 0; k < N; ++k) {
        double sum = 0.0;
        for (int l = 0; l < L; ++l) sum += C_(l, k) * Vzeta_[l];
        CtVzeta_[k] = sum;
      }
      product_columns<NN>(N, N, 1, Qs, CtVzeta_.data(), 1, 0, 1.0, true, xdot);
      double* QCt = QCt_.data();
      double* QCtV = QCtV_tilde_.data();
      product_columns<NN>(N, N, L, Qs, C_.data(), L, 1, 1.0, false, QCt);                   // Q C'
      product_columns<NN>(N, L, L, QCt, V_tilde_.data(), 1, L, 1.0, false, QCtV);            // Q C' V~
      product_columns<NN>(N, L, N, QCt, QCtV, N, 1, -1.0, true, Qdot);                       // -(Q C')(Q C' V~)'
    }
    return Status::ok();
  }

  // The discrete update of the split-step form at time(), after equations()
  // was evaluated there with the measurement.
  Status split_step_update(double dt) {
    // V~ = U U' from its LDL' factorisation with pivoting (V~ is only
    // semi-definite: its rank is L - (nu + n)).
    V_tilde_ldlt_.compute(V_tilde_);
    L_factor_ = V_tilde_ldlt_.matrixL();
    L_factor_ = L_factor_ * V_tilde_ldlt_.vectorD().cwiseMax(0.0).cwiseSqrt().asDiagonal();
    U_.noalias() = V_tilde_ldlt_.transpositionsP().transpose() * L_factor_;
    Hm_.noalias() = U_.transpose().lazyProduct(C_);
    Ut_r_.noalias() = U_.transpose() * r_;
    HmQ_.noalias() = Hm_.lazyProduct(Q_);
    S_update_.noalias() = HmQ_.lazyProduct(Hm_.transpose());
    S_update_.diagonal().array() += 1.0 / dt;
    S_update_llt_.compute(S_update_);
    if (S_update_llt_.info() != Eigen::Success) {
      return failed_precondition("filter diverged: the update's S is not positive definite at t = " +
                                 std::to_string(t_));
    }
    Gt_ = S_update_llt_.solve(HmQ_);  // G' = S^-1 Hm Q, Q symmetric
    G_ = Gt_.transpose();
    S_inv_Ut_r_ = S_update_llt_.solve(Ut_r_);
    nis_ = Ut_r_.dot(S_inv_Ut_r_);
    x_hat_.noalias() += G_ * Ut_r_;
    I_GHm_.setIdentity();
    I_GHm_.noalias() -= G_.lazyProduct(Hm_);
    I_GHm_Q_.noalias() = I_GHm_.lazyProduct(Q_);
    Q_new_.noalias() = I_GHm_Q_.lazyProduct(I_GHm_.transpose());
    Q_new_.noalias() += (1.0 / dt) * G_.lazyProduct(G_.transpose());
    Q_ = 0.5 * (Q_new_ + Q_new_.transpose());
    return check("update");
  }

  // A diverged filter: non-finite estimate, or Q no longer positive definite.
  Status check(const char* where) {
    Status s = check_estimate(where);
    if (s.is_ok()) {
      Q_llt_.compute(Q_);
      if (Q_llt_.info() == Eigen::Success) return Status::ok();
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

  // The specification's x^ and Q are the Filter's estimate and covariance.
  Eigen::VectorXd& x_hat_;
  Eigen::MatrixXd& Q_;
  Eigen::VectorXd p_hat_;  // p^ = [u^; a^]: the estimated inputs and accelerations (eq 9)
  Eigen::VectorXd zeta_;   // the residuals of the L equations at p^ (eq 9)
  std::unique_ptr<Integrator> integrator_;
  Rhs rhs_;
  int n_ = 0;  // degrees of freedom
  bool continuous_ = true;
  Eigen::MatrixXd V_, W_inv_;
  bool interpolating_ = false;  // outputs interpolated over the interval being integrated
  Eigen::VectorXd u_now_, y_last_, y_next_, y_now_;
  bool has_measurement_ = false;  // y_last_ holds the measurement at time()
  double interval_ = 0.0;         // length of the prediction not yet followed by an update
  // Work space, sized once.
  std::vector<double> x_hat_Q_;  // [x^; vec Q]
  std::vector<std::uint64_t> evaluated_at_;  // the bits of [t; x; u; y] at the last equations()
  bool evaluated_ = false;                   // equations() succeeded there: its results stand
  Eigen::VectorXd f_, r_, Vzeta_, CtVzeta_, Ut_r_, S_inv_Ut_r_;
  Eigen::MatrixXd F_, df_dx_, dF_dx_, D_, C_, VD_, DVD_, DVD_factor_, KDV_, KDVC_, K_, V_tilde_;
  Eigen::MatrixXd Q_sym_, AtQ_cols_, QCt_, QCtV_tilde_;
  using Derivatives = Status (OptimalFilter::*)(double, const double*, double*);
  Derivatives derivatives_ = nullptr;      // derivatives_for<nz>, or the general one
  CholeskySolveFn cholesky_solve_ = nullptr;  // for P = nu + n
  Eigen::MatrixXd L_factor_, U_, Hm_, S_update_, HmQ_, Gt_, G_, I_GHm_, I_GHm_Q_, Q_new_;
  Eigen::LLT<Eigen::MatrixXd> S_update_llt_, Q_llt_;
  Eigen::LDLT<Eigen::MatrixXd> V_tilde_ldlt_;
};

}  // namespace

Status validate_optimal_filter(const FilterSettings& s, const Model& model) {
  if (s.smoothing) {
    return invalid_argument(
        "the optimal filter does not support smoothing: a fixed-interval smoother runs after "
        "the EKF or the UKF");
  }
  if (!model.has_mechanical_form()) {
    return invalid_argument("model " + model.name() +
                            " has no mechanical form (M a + h = H u): the optimal filter needs one");
  }
  if (s.Q.size() != 0 || s.R.size() != 0) {
    return invalid_argument("the optimal filter takes its weights from V and W, not from Q and R");
  }
  const int L = optimal_equation_count(model);
  RICCATI_RETURN_IF_ERROR(check_covariance(s.optimal.V, L,
                                           "optimal filter weights V (" + std::to_string(model.ndof()) +
                                               " equations of motion, " + std::to_string(model.nu()) + " inputs, " +
                                               std::to_string(model.ny()) + " outputs)"));
  RICCATI_RETURN_IF_ERROR(check_covariance(s.optimal.W, model.nz(), "optimal filter weights W"));
  Eigen::LLT<Eigen::MatrixXd> llt(s.optimal.W);
  if (llt.info() != Eigen::Success) {
    return invalid_argument("optimal filter weights W must be positive definite (W^-1 is the process noise)");
  }
  return Status::ok();
}

std::unique_ptr<Filter> make_optimal_filter(ModelPtr model, const FilterSettings& settings,
                                            std::unique_ptr<Integrator> integrator) {
  return std::make_unique<OptimalFilter>(std::move(model), settings, std::move(integrator));
}

}  // namespace riccati
