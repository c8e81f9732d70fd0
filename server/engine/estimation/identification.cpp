#include "engine/estimation/identification.hpp"

#include "engine/estimation/estimate.hpp"
#include "engine/estimation/point_uncertainty.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>

namespace riccati {

namespace {

// A checkpoint must come from a run of these settings over these samples.
Status check_checkpoint(const IdentificationCheckpoint& c, int passes, int nz, int ntheta, Eigen::Index N) {
  const int done = static_cast<int>(c.passes.size());
  const bool fits = done >= 1 && done < passes && c.covariance.rows() == nz && c.covariance.cols() == nz &&
                    std::all_of(c.passes.begin(), c.passes.end(), [&](const PassResult& p) {
                      return p.theta_final.size() == ntheta && p.theta_trace.rows() == ntheta &&
                             p.theta_trace.cols() == N;
                    });
  if (fits) return Status::ok();
  return invalid_argument("checkpoint does not fit this run (" + std::to_string(done) + " of " +
                          std::to_string(passes) + " passes, a " + std::to_string(c.covariance.rows()) + " x " +
                          std::to_string(c.covariance.cols()) + " covariance for " + std::to_string(nz) +
                          " states and parameters)");
}

// Where a pass after the first starts (Hensen 1999, ch. 2): the states and
// their covariance as the first pass did, theta and its covariance as the
// previous pass ended.
InitialEstimate next_pass_start(const InitialEstimate& first, const Eigen::VectorXd& theta_end,
                                const Eigen::MatrixXd& P_end, int nx) {
  const Eigen::Index ntheta = theta_end.size();
  InitialEstimate next = first;
  next.theta0 = theta_end;
  next.P0.setZero();
  next.P0.topLeftCorner(nx, nx) = first.P0.topLeftCorner(nx, nx);
  next.P0.bottomRightCorner(ntheta, ntheta) = P_end.bottomRightCorner(ntheta, ntheta);
  return next;
}

// One pass over the samples. Fills `pass_result`, and for the last pass the
// traces of `result` (states, model outputs, innovations).
class Pass {
 public:
  Pass(OnlineRunner& runner, const Dataset& bound, const Eigen::ArrayXXd& mask, SampleRange range,
       const IdentificationHooks& hooks)
      : runner_(runner), bound_(bound), mask_(mask), range_(range), hooks_(hooks) {}

  Status run(int pass, int passes, PassResult* pass_result, IdentificationResult* result) {
    const Model& model = runner_.model();
    const Eigen::Index N = range_.size();
    const int nx = model.nx(), ntheta = model.ntheta(), ny = model.ny();
    const bool last = pass == passes;
    pass_result->theta_trace.resize(ntheta, N);
    Eigen::VectorXd innovation_sq = Eigen::VectorXd::Zero(ny);
    double nis_sum = 0.0;
    Eigen::Index used = 0;
    Eigen::VectorXd y_model(ny);
    IdentificationProgress report{pass, passes, 0, N, &runner_.filter().state()};
    for (Eigen::Index k = 0; k < N; ++k) {
      if (hooks_.stop.stop_requested()) {
        return cancelled("identification cancelled in pass " + std::to_string(pass) + " at sample " +
                         std::to_string(k + 1));
      }
      const Eigen::Index s = range_.first + k;
      const auto where = [&] {
        return "pass " + std::to_string(pass) + ", sample " + std::to_string(k + 1) + " (t = " +
               std::to_string(bound_.t[s]) + ")";
      };
      const double* u = bound_.u.col(s).data();
      const bool measured = mask_.size() == 0 || (mask_.col(s) != 0.0).all();
      Status st = measured ? runner_.advance(bound_.t[s], {u, static_cast<std::size_t>(model.nu())},
                                             {bound_.y.col(s).data(), static_cast<std::size_t>(ny)})
                           : runner_.advance_without_measurement(bound_.t[s], {u, static_cast<std::size_t>(model.nu())});
      if (!st.is_ok()) return failed_at(k, st.with_context(where()), report);

      const Filter& filter = runner_.filter();
      const Eigen::VectorXd& z = filter.state();
      pass_result->theta_trace.col(k) = z.tail(ntheta);
      if (measured) {
        innovation_sq += filter.innovation().cwiseAbs2();
        nis_sum += filter.nis();
        ++used;
      }
      if (last) {
        result->x_trace.col(k) = z.head(nx);
        // Not `measured ? innovation() : Zero(ny)`: the conditional's common type is a
        // new VectorXd, an allocation per sample.
        if (measured) {
          result->innovations.col(k) = filter.innovation();
        } else {
          result->innovations.col(k).setZero();
        }
        st = model.g(bound_.t[s], u, 1, 1, z.data(), z.data() + nx, y_model.data());
        if (!st.is_ok()) return failed_at(k, st.with_context(where()), report);
        result->y_model.col(k) = y_model;
      }
      if (hooks_.progress) {
        report.sample = k + 1;
        hooks_.progress(report);
      }
    }
    const Filter& filter = runner_.filter();
    pass_result->theta_final = filter.state().tail(ntheta);
    pass_result->theta_mean = pass_result->theta_trace.rowwise().mean();
    pass_result->theta_std = filter.covariance().diagonal().tail(ntheta).cwiseMax(0.0).cwiseSqrt();
    pass_result->innovation_rms = (innovation_sq / static_cast<double>(std::max<Eigen::Index>(used, 1))).cwiseSqrt();
    pass_result->nis_mean = nis_sum / static_cast<double>(std::max<Eigen::Index>(used, 1));
    return Status::ok();
  }

 private:
  // A pass that fails tells its progress first, `done` samples into the
  // pass the error names: a job's progress and its error agree on where it
  // stopped, even when that is the first sample of a pass.
  Status failed_at(Eigen::Index done, Status error, IdentificationProgress& report) const {
    if (hooks_.progress) {
      report.sample = done;
      hooks_.progress(report);
    }
    return error;
  }

  OnlineRunner& runner_;
  const Dataset& bound_;
  const Eigen::ArrayXXd& mask_;
  const SampleRange range_;
  const IdentificationHooks& hooks_;
};

// The uncertainty of the estimate the result reports (the mean over the
// last pass): output error's at that estimate, over the samples filtered,
// each output weighted by the filter's 1/sqrt(R_ii), the states with a
// prior variance counted as estimated. After a few passes the estimate has
// not settled (each pass moves it less, its P having counted the record
// once more): the interval is the simulation error optimum's, one
// Gauss-Newton step away, widened to hold the estimate. A model the
// simulation fails on (unstable without the filter's corrections) gets the
// filter's P times the passes: each pass has counted the record's
// information once.
void set_estimate_uncertainty(const ModelPtr& model, const Dataset& bound, SampleRange range,
                              const IdentificationSettings& settings, IdentificationResult* result) {
  const int nx = model->nx(), ntheta = model->ntheta(), ny = model->ny();
  const Eigen::MatrixXd& P0 = settings.initial.P0;
  const Eigen::MatrixXd& Q = settings.filter.Q;
  std::vector<bool> theta_free(static_cast<std::size_t>(ntheta)), x0_free(static_cast<std::size_t>(nx));
  for (int i = 0; i < ntheta; ++i) {
    const Eigen::Index z = nx + i;
    theta_free[static_cast<std::size_t>(i)] = P0(z, z) > 0.0 || (Q.rows() > z && Q(z, z) > 0.0);
  }
  Dataset data;
  data.t = bound.t.segment(range.first, range.size());
  data.u = bound.u.middleCols(range.first, range.size());
  data.y = bound.y.middleCols(range.first, range.size());
  // The states the filter started from; one taken from a (noisy) first
  // measurement is estimated too, as one with a prior variance is.
  const Result<Eigen::VectorXd> x0 = initial_state(*model, settings.initial.mode, settings.initial.x0,
                                                   {data.y.col(0).data(), static_cast<std::size_t>(ny)});
  for (int i = 0; i < nx; ++i) {
    const bool measured = settings.initial.mode == InitialState::kFirstMeasurement &&
                          model->output_index(model->state_names()[static_cast<std::size_t>(i)]) >= 0;
    x0_free[static_cast<std::size_t>(i)] = P0(i, i) > 0.0 || measured;
  }
  const Eigen::ArrayXXd mask =
      settings.mask.size() != 0 ? Eigen::ArrayXXd(settings.mask.middleCols(range.first, range.size())) : Eigen::ArrayXXd();
  Eigen::VectorXd weights(ny);
  // (The optimal filter has no R: its outputs weighted alike.)
  const Eigen::MatrixXd& R = settings.filter.R;
  for (int i = 0; i < ny; ++i) weights[i] = R.rows() > i && R(i, i) > 0.0 ? 1.0 / std::sqrt(R(i, i)) : 1.0;
  const Eigen::VectorXd& estimate = result->theta_mean;
  const Result<PointUncertainty> at =
      x0.is_ok() ? uncertainty_at(model, data, mask, x0.value(), x0_free, estimate, theta_free, weights,
                                  {settings.filter.hold, settings.filter.integrator}, settings.covariance)
                 : Result<PointUncertainty>(x0.status());
  if (at.is_ok()) {
    result->theta_std = at->theta_std;
    result->theta_covariance = at->covariance;
    result->theta_step = at->theta_step;
    result->covariance_method = "output error at the estimate: " + at->method;
    result->warnings.insert(result->warnings.end(), at->warnings.begin(), at->warnings.end());
  } else {
    const auto passes = static_cast<double>(result->passes.size());
    result->theta_covariance = passes * result->covariance.bottomRightCorner(ntheta, ntheta);
    result->theta_std = std::sqrt(passes) * result->filter_theta_std;
    result->theta_step = Eigen::VectorXd::Zero(ntheta);
    result->covariance_method = "the filter's P times the " + std::to_string(result->passes.size()) +
                                " passes (output error's covariance needs a simulation at the estimate: " +
                                at.status().message() + ")";
    result->warnings.push_back("the intervals are the filter's covariance times the passes, a rough correction: " +
                               at.status().message());
  }
  constexpr double kZ95 = 1.959963984540054;
  result->ci_lower.resize(ntheta);
  result->ci_upper.resize(ntheta);
  std::string unsettled;
  for (int i = 0; i < ntheta; ++i) {
    const double optimum = estimate[i] + result->theta_step[i], half = kZ95 * result->theta_std[i];
    result->ci_lower[i] = std::isfinite(half) ? std::min(estimate[i], optimum - half) : -std::numeric_limits<double>::infinity();
    result->ci_upper[i] = std::isfinite(half) ? std::max(estimate[i], optimum + half) : std::numeric_limits<double>::infinity();
    if (std::abs(result->theta_step[i]) > result->theta_std[i] && result->theta_std[i] > 0.0) {
      unsettled += (unsettled.empty() ? "" : ", ") + result->param_names[static_cast<std::size_t>(i)] + " by " +
                   message_number(std::abs(result->theta_step[i]) / result->theta_std[i], 2);
    }
  }
  if (!unsettled.empty()) {
    result->warnings.push_back(
        "the estimate has not settled after " + std::to_string(result->passes.size()) +
        " passes: it is more than a standard error from the simulation error's optimum (" + unsettled +
        " standard errors, one Gauss-Newton step away); the intervals hold both. More passes, or output error "
        "started from this estimate (--method oe --init-passes), settle it");
  }
}

}  // namespace

Status validate(const IdentificationSettings& s, const Model& model) {
  RICCATI_RETURN_IF_ERROR(validate(s.filter, model));
  RICCATI_RETURN_IF_ERROR(validate(s.initial, model));
  if (s.theta_lower.size() != 0 || s.theta_upper.size() != 0) {
    // theta0 within its bounds, the bounds intervals: as the optimisers check them.
    ParameterSettings bounds = default_parameters(model, s.initial.theta0);
    bounds.lower = s.theta_lower;
    bounds.upper = s.theta_upper;
    RICCATI_RETURN_IF_ERROR(validate(bounds, model));
  }
  constexpr int kMaxPasses = 100000;
  if (s.passes < 1 || s.passes > kMaxPasses) {
    return invalid_argument("passes must be between 1 and " + std::to_string(kMaxPasses) + ", got " +
                            std::to_string(s.passes));
  }
  return Status::ok();
}

Result<IdentificationResult> identify(ModelPtr model, const Dataset& data, const IdentificationSettings& settings,
                                      const IdentificationHooks& hooks) {
  if (model == nullptr) return invalid_argument("no model given");
  RICCATI_RETURN_IF_ERROR(validate(settings, *model));
  RICCATI_ASSIGN_OR_RETURN(const Dataset bound, bind_dataset(*model, data));
  RICCATI_ASSIGN_OR_RETURN(const SampleRange range, sample_range(settings.first_sample, settings.end_sample, bound));
  const Eigen::Index N = range.size();
  const int nx = model->nx(), ny = model->ny(), nz = model->nz();
  RICCATI_ASSIGN_OR_RETURN(OnlineRunner runner, OnlineRunner::create(model, settings.filter, settings.initial));
  RICCATI_RETURN_IF_ERROR(runner.set_parameter_bounds(settings.theta_lower, settings.theta_upper));

  IdentificationResult result;
  result.param_names = model->param_names();
  result.t = bound.t.segment(range.first, N);
  result.x_trace.resize(nx, N);
  result.y_model.resize(ny, N);
  result.innovations.resize(ny, N);

  int first_pass = 1;
  if (hooks.resume != nullptr) {
    const IdentificationCheckpoint& c = *hooks.resume;
    RICCATI_RETURN_IF_ERROR(check_checkpoint(c, settings.passes, nz, model->ntheta(), N));
    result.passes = c.passes;
    first_pass = static_cast<int>(c.passes.size()) + 1;
    RICCATI_RETURN_IF_ERROR(runner.restart(next_pass_start(settings.initial, c.passes.back().theta_final,
                                                           c.covariance, nx)));
  }
  if (settings.mask.size() != 0 && (settings.mask.rows() != ny || settings.mask.cols() != bound.size())) {
    return invalid_argument("the sample mask must be " + std::to_string(ny) + " x " + std::to_string(bound.size()));
  }
  Pass pass(runner, bound, settings.mask, range, hooks);
  for (int p = first_pass; p <= settings.passes; ++p) {
    if (p > first_pass) {
      const Status started = runner.restart(next_pass_start(settings.initial, result.passes.back().theta_final,
                                                            runner.filter().covariance(), nx));
      if (!started.is_ok()) {
        if (hooks.progress) hooks.progress({p, settings.passes, 0, N, &runner.filter().state()});
        return started.with_context("starting pass " + std::to_string(p));
      }
    }
    PassResult pass_result;
    RICCATI_RETURN_IF_ERROR(pass.run(p, settings.passes, &pass_result, &result));
    result.passes.push_back(std::move(pass_result));
    if (p < settings.passes && hooks.pass_done) {
      RICCATI_RETURN_IF_ERROR(hooks.pass_done(p, result.passes.back(), runner.filter().covariance())
                                  .with_context("checkpoint after pass " + std::to_string(p)));
    }
  }

  const Eigen::VectorXi& hits = runner.parameter_bound_hits();
  for (Eigen::Index i = 0; i < hits.size(); ++i) {
    if (hits[i] == 0) continue;
    result.warnings.push_back(result.param_names[static_cast<std::size_t>(i)] + " was held at a bound (" +
                              message_number(settings.theta_lower[i]) + " or " + message_number(settings.theta_upper[i]) + ") after " +
                              std::to_string(hits[i]) + " samples of the last pass");
  }
  const PassResult& last = result.passes.back();
  result.theta = last.theta_final;
  result.theta_mean = last.theta_mean;
  result.filter_theta_std = last.theta_std;
  result.covariance = runner.filter().covariance();
  set_estimate_uncertainty(model, bound, range, settings, &result);
  return result;
}

}  // namespace riccati
