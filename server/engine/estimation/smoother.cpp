#include "engine/estimation/smoother.hpp"

#include <cmath>
#include <string>
#include <utility>

#include "engine/estimation/binding.hpp"
#include "engine/filters/filter_kinds.hpp"

namespace riccati {

namespace {

// The smoother's gain G = C P^-1 (smoother.hpp) for a prior covariance P that
// may be singular, without an inverse. P is scaled, R = S P S with S =
// diag(v)^-1/2 and v_i the largest variance z_i has anywhere in the record
// (so that what counts as negligible does not depend on z's units, nor on a
// variance that happens to be near zero at k, which is then mostly
// rounding; variables that never have variance have S = 0), and factorised
// by Cholesky with diagonal pivoting, stopped once every remaining variance
// is below kNegligible: the remaining variables are then, to rounding,
// functions of the pivots already taken. With the r pivots I and R_II = L L^T,
//     G_I = C_I S_I (L L^T)^-1 S_I,   G's other columns 0,
// that is G = C P^g with P^g a generalised inverse of P (P P^g P = P). It is
// P^-1 when P is regular, and when it is not it gives the smoother any other
// would: what the gain is applied to lies in the range of P.
class SmootherGain {
 public:
  // `variance_scale` [nz]: v above.
  explicit SmootherGain(const Eigen::VectorXd& variance_scale)
      : R_(variance_scale.size(), variance_scale.size()),
        s_(variance_scale.size()),
        perm_(variance_scale.size()),
        B_(variance_scale.size(), variance_scale.size()) {
    for (Eigen::Index i = 0; i < s_.size(); ++i) {
      s_[i] = variance_scale[i] > 0.0 ? 1.0 / std::sqrt(variance_scale[i]) : 0.0;
    }
  }

  void compute(const Eigen::Ref<const Eigen::MatrixXd>& C, const Eigen::Ref<const Eigen::MatrixXd>& P,
               Eigen::MatrixXd& G) {
    R_ = P;
    R_.array().colwise() *= s_.array();
    R_.array().rowwise() *= s_.transpose().array();
    const Eigen::Index r = pivoted_cholesky();
    // B = (C_I S_I)^T, then (L L^T)^-1 B by two triangular solves.
    auto B = B_.topRows(r);
    for (Eigen::Index a = 0; a < r; ++a) B.row(a) = s_[perm_[a]] * C.col(perm_[a]).transpose();
    const auto L = R_.topLeftCorner(r, r);
    L.triangularView<Eigen::Lower>().solveInPlace(B);
    L.transpose().triangularView<Eigen::Upper>().solveInPlace(B);
    G.setZero();
    for (Eigen::Index a = 0; a < r; ++a) G.col(perm_[a]) = s_[perm_[a]] * B.row(a).transpose();
  }

 private:
  // A fraction of the largest variance a variable has in the record: below
  // it, a variance is rounding (P's entries carry a few eps of that scale).
  static constexpr double kNegligible = 1e-12;

  // R_ = Pi^T L L^T Pi in place (L in R_'s lower triangle, in pivoted order,
  // perm_ the pivots), stopped at the numerical rank, which it returns.
  Eigen::Index pivoted_cholesky() {
    const Eigen::Index n = R_.rows();
    for (Eigen::Index i = 0; i < n; ++i) perm_[i] = static_cast<int>(i);
    for (Eigen::Index k = 0; k < n; ++k) {
      Eigen::Index pivot;
      if (R_.diagonal().tail(n - k).maxCoeff(&pivot) <= kNegligible) return k;
      pivot += k;
      if (pivot != k) {
        R_.row(k).swap(R_.row(pivot));
        R_.col(k).swap(R_.col(pivot));
        std::swap(perm_[k], perm_[pivot]);
      }
      const double lkk = std::sqrt(R_(k, k));
      R_.col(k).tail(n - k) /= lkk;
      // The whole trailing block (both triangles), so that later swaps stay consistent.
      R_.bottomRightCorner(n - k - 1, n - k - 1).noalias() -=
          R_.col(k).tail(n - k - 1) * R_.col(k).tail(n - k - 1).transpose();
    }
    return n;
  }

  Eigen::MatrixXd R_;
  Eigen::VectorXd s_;
  Eigen::VectorXi perm_;
  Eigen::MatrixXd B_;
};


FilterSettings with_smoothing(FilterSettings filter) {
  filter.smoothing = true;
  return filter;
}

}  // namespace

Status validate(const SmootherSettings& s, const Model& model) {
  RICCATI_RETURN_IF_ERROR(validate(with_smoothing(s.filter), model));
  return validate(s.initial, model);
}

Result<SmootherResult> smooth(ModelPtr model, const Dataset& data, const SmootherSettings& settings,
                              const SmootherHooks& hooks) {
  if (model == nullptr) return invalid_argument("no model given");
  RICCATI_RETURN_IF_ERROR(validate(settings, *model));
  RICCATI_ASSIGN_OR_RETURN(const Dataset bound, bind_dataset(*model, data));
  RICCATI_ASSIGN_OR_RETURN(const SampleRange range, sample_range(settings.first_sample, settings.end_sample, bound));
  RICCATI_ASSIGN_OR_RETURN(OnlineRunner runner,
                           OnlineRunner::create(model, with_smoothing(settings.filter), settings.initial));
  const Eigen::Index N = range.size();
  const int nx = model->nx(), nz = model->nz(), nu = model->nu(), ny = model->ny();
  const auto where = [&](Eigen::Index k) {
    return "sample " + std::to_string(k + 1) + " (t = " + std::to_string(bound.t[range.first + k]) + ")";
  };

  SmootherResult result;
  result.names = model->state_names();
  result.names.insert(result.names.end(), model->param_names().begin(), model->param_names().end());
  result.t = bound.t.segment(range.first, N);
  result.z_filtered.resize(nz, N);
  result.std_filtered.resize(nz, N);
  result.innovations.resize(ny, N);
  // What the backward pass needs, sized once: P_k|k (then P_k|N, in place),
  // and of the prediction to sample k, z_k|k-1 and P_k|k-1 (k >= 1) and
  // C_k-1 (in block k - 1).
  Eigen::MatrixXd& P = result.P_smoothed;
  P.resize(nz, nz * N);
  Eigen::MatrixXd z_prior(nz, N), P_prior(nz, nz * N), C(nz, nz * (N - 1));
  const auto block = [nz](Eigen::MatrixXd& M, Eigen::Index k) { return M.middleCols(k * nz, nz); };

  // The largest variance each of z has along the record: the gain's scale.
  Eigen::VectorXd variance_scale = Eigen::VectorXd::Zero(nz);
  SmootherProgress report{SmootherProgress::Pass::kForward, 0, N};
  for (Eigen::Index k = 0; k < N; ++k) {
    if (hooks.stop.stop_requested()) {
      return cancelled("smoothing cancelled in the forward pass at " + where(k));
    }
    const Eigen::Index s = range.first + k;
    // The context is built only on an error: this runs at every sample.
    const Status advanced = runner.advance(bound.t[s], {bound.u.col(s).data(), static_cast<std::size_t>(nu)},
                                           {bound.y.col(s).data(), static_cast<std::size_t>(ny)});
    if (!advanced.is_ok()) return advanced.with_context(where(k));
    const Filter& filter = runner.filter();
    result.z_filtered.col(k) = filter.state();
    block(P, k) = filter.covariance();
    variance_scale = variance_scale.cwiseMax(filter.covariance().diagonal());
    result.innovations.col(k) = filter.innovation();
    if (k > 0) {
      const Prediction& prediction = filter.prediction();
      if (prediction.C.rows() != nz || prediction.C.cols() != nz || prediction.P.rows() != nz ||
          prediction.z.size() != nz) {
        // A kind that neither keeps its prediction nor refuses the setting.
        return internal_error(std::string("the ") + filter_kind_name(settings.filter.kind) +
                              " filter gives no prediction for a smoother");
      }
      z_prior.col(k) = prediction.z;
      block(P_prior, k) = prediction.P;
      variance_scale = variance_scale.cwiseMax(prediction.P.diagonal());
      block(C, k - 1) = prediction.C;
    }
    if (hooks.progress) {
      report.sample = k + 1;
      hooks.progress(report);
    }
  }
  for (Eigen::Index k = 0; k < N; ++k) {
    result.std_filtered.col(k) = block(P, k).diagonal().cwiseMax(0.0).cwiseSqrt();
  }

  // Backward (smoother.hpp), from z_N-1|N = z_N-1|N-1.
  result.z_smoothed.resize(nz, N);
  result.z_smoothed.col(N - 1) = result.z_filtered.col(N - 1);
  SmootherGain gain(variance_scale);
  Eigen::MatrixXd G(nz, nz), dP(nz, nz), GdP(nz, nz), P_sym(nz, nz);
  Eigen::VectorXd dz(nz);
  report.pass = SmootherProgress::Pass::kBackward;
  for (Eigen::Index k = N - 2; k >= 0; --k) {
    if (hooks.stop.stop_requested()) {
      return cancelled("smoothing cancelled in the backward pass at " + where(k));
    }
    gain.compute(block(C, k), block(P_prior, k + 1), G);
    dz = result.z_smoothed.col(k + 1) - z_prior.col(k + 1);
    result.z_smoothed.col(k) = result.z_filtered.col(k);
    result.z_smoothed.col(k).noalias() += G * dz;
    dP = block(P, k + 1) - block(P_prior, k + 1);
    GdP.noalias() = G * dP;
    auto P_k = block(P, k);
    P_k.noalias() += GdP * G.transpose();
    P_sym = 0.5 * (P_k + P_k.transpose());
    P_k = P_sym;
    if (!result.z_smoothed.col(k).allFinite() || !P_k.allFinite()) {
      return failed_precondition("smoother diverged: the smoothed estimate is not finite at " + where(k));
    }
    if (hooks.progress) {
      report.sample = k + 1;
      hooks.progress(report);
    }
  }

  result.std_smoothed.resize(nz, N);
  result.y_model.resize(ny, N);
  for (Eigen::Index k = 0; k < N; ++k) {
    result.std_smoothed.col(k) = block(P, k).diagonal().cwiseMax(0.0).cwiseSqrt();
    const Eigen::Index s = range.first + k;
    const double* z = result.z_smoothed.col(k).data();
    const Status evaluated = model->g(bound.t[s], bound.u.col(s).data(), 1, 1, z, z + nx, result.y_model.col(k).data());
    if (!evaluated.is_ok()) return evaluated.with_context("model outputs at the smoothed estimate, " + where(k));
  }
  return result;
}

}  // namespace riccati
