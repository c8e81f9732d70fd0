#include "engine/estimation/identification.hpp"

#include <algorithm>

#include <cmath>
#include <string>

namespace riccati {

namespace {

// Row order of `wanted` names inside `have`, or an empty vector if some are missing.
std::vector<Eigen::Index> order_by_name(const std::vector<std::string>& wanted, const std::vector<std::string>& have) {
  std::vector<Eigen::Index> order;
  for (const auto& w : wanted) {
    Eigen::Index found = -1;
    for (std::size_t i = 0; i < have.size(); ++i) {
      if (have[i] == w) found = static_cast<Eigen::Index>(i);
    }
    if (found < 0) return {};
    order.push_back(found);
  }
  return order;
}

std::string join(const std::vector<std::string>& names) {
  std::string out;
  for (const auto& n : names) out += (out.empty() ? "" : ", ") + n;
  return out;
}

// Reorders the rows of m (one variable per row) as `wanted` says they are
// named in `have`; positional when the names do not all match.
Status bind_rows(const char* what, const std::vector<std::string>& wanted, const std::vector<std::string>& have,
                 const std::string& model_name, Eigen::MatrixXd* m, std::vector<std::string>* names) {
  if (have.size() != wanted.size()) {
    return invalid_argument("model " + model_name + " has " + std::to_string(wanted.size()) + " " + what + " (" +
                            join(wanted) + "), the dataset has " + std::to_string(have.size()) + " (" + join(have) +
                            ")");
  }
  const auto order = order_by_name(wanted, have);
  if (!order.empty()) {
    Eigen::MatrixXd reordered(m->rows(), m->cols());
    for (std::size_t i = 0; i < order.size(); ++i) reordered.row(i) = m->row(order[i]);
    *m = std::move(reordered);
  }
  *names = wanted;
  return Status::ok();
}

}  // namespace

Result<Dataset> bind_dataset(const Model& model, const Dataset& data) {
  RICCATI_RETURN_IF_ERROR(validate_dataset(data));
  Dataset bound = data;
  RICCATI_RETURN_IF_ERROR(
      bind_rows("inputs", model.input_names(), data.input_names, model.name(), &bound.u, &bound.input_names));
  RICCATI_RETURN_IF_ERROR(
      bind_rows("outputs", model.output_names(), data.output_names, model.name(), &bound.y, &bound.output_names));
  return bound;
}

Result<Eigen::VectorXd> initial_state(const Model& model, const Dataset& bound, InitialState mode,
                                      const Eigen::VectorXd& x0, Eigen::Index first_sample) {
  const int nx = model.nx();
  if (x0.size() != 0 && x0.size() != nx) {
    return invalid_argument("x0 has " + std::to_string(x0.size()) + " entries, model " + model.name() + " has " +
                            std::to_string(nx) + " states (" + join(model.state_names()) + ")");
  }
  if (mode == InitialState::kGiven && x0.size() != nx) {
    return invalid_argument("x0 is required (" + std::to_string(nx) + " values: " + join(model.state_names()) +
                            ") unless the initial state is the first measurement");
  }
  Eigen::VectorXd x = x0.size() == nx ? x0 : Eigen::VectorXd::Zero(nx);
  if (mode == InitialState::kFirstMeasurement) {
    int matched = 0;
    for (int i = 0; i < nx; ++i) {
      const int out = model.output_index(model.state_names()[i]);
      if (out >= 0) {
        x[i] = bound.y(out, first_sample);
        ++matched;
      }
    }
    if (matched == 0) {
      return invalid_argument("x0 = first measurement needs outputs named as states; model " + model.name() +
                              " has states (" + join(model.state_names()) + ") and outputs (" +
                              join(model.output_names()) + ")");
    }
  }
  if (!x.allFinite()) return invalid_argument("x0 has a NaN or infinite entry");
  return x;
}

Status validate(const IdentificationSettings& s, const Model& model) {
  RICCATI_RETURN_IF_ERROR(validate(s.filter, model));
  if (s.theta0.size() != model.ntheta()) {
    return invalid_argument("theta0 has " + std::to_string(s.theta0.size()) + " entries, model " + model.name() +
                            " has " + std::to_string(model.ntheta()) + " parameters (" + join(model.param_names()) +
                            ")");
  }
  if (!s.theta0.allFinite()) return invalid_argument("theta0 has a NaN or infinite entry");
  if (s.P0.rows() != model.nz() || s.P0.cols() != model.nz()) {
    return invalid_argument("P0 must be " + std::to_string(model.nz()) + " x " + std::to_string(model.nz()) +
                            " (states and parameters)");
  }
  RICCATI_RETURN_IF_ERROR(check_covariance(s.P0, model.nz(), "initial covariance P0"));
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

  const Eigen::Index first = settings.first_sample;
  const Eigen::Index end = settings.end_sample < 0 ? bound.size() : settings.end_sample;
  if (first < 0 || end > bound.size() || end - first < 2) {
    return invalid_argument("sample range [" + std::to_string(first) + ", " + std::to_string(end) +
                            ") must hold at least two of the dataset's " + std::to_string(bound.size()) + " samples");
  }
  const Eigen::Index N = end - first;
  const int nx = model->nx(), ntheta = model->ntheta(), ny = model->ny(), nz = model->nz();

  RICCATI_ASSIGN_OR_RETURN(const Eigen::VectorXd x0,
                           initial_state(*model, bound, settings.initial_state, settings.x0, first));
  RICCATI_ASSIGN_OR_RETURN(std::unique_ptr<Filter> filter, make_filter(model, settings.filter));

  IdentificationResult result;
  result.param_names = model->param_names();
  result.t = bound.t.segment(first, N);
  result.x_trace.resize(nx, N);
  result.y_model.resize(ny, N);
  result.innovations.resize(ny, N);
  Eigen::VectorXd z(nz);
  Eigen::MatrixXd P = settings.P0;
  z << x0, settings.theta0;
  Eigen::VectorXd y_post(ny);

  // Theta and its covariance at the end of the previous pass.
  Eigen::VectorXd theta_end;
  Eigen::MatrixXd P_end;
  int first_pass = 1;
  if (hooks.resume != nullptr) {
    const IdentificationCheckpoint& c = *hooks.resume;
    const int done = static_cast<int>(c.passes.size());
    const bool fits = done >= 1 && done < settings.passes && c.covariance.rows() == nz && c.covariance.cols() == nz &&
                      std::all_of(c.passes.begin(), c.passes.end(), [&](const PassResult& p) {
                        return p.theta_final.size() == ntheta && p.theta_trace.rows() == ntheta &&
                               p.theta_trace.cols() == N;
                      });
    if (!fits) {
      return invalid_argument("checkpoint does not fit this run (" + std::to_string(done) + " of " +
                              std::to_string(settings.passes) + " passes, a " + std::to_string(c.covariance.rows()) +
                              " x " + std::to_string(c.covariance.cols()) + " covariance for " + std::to_string(nz) +
                              " states and parameters)");
    }
    result.passes = c.passes;
    theta_end = c.passes.back().theta_final;
    P_end = c.covariance;
    first_pass = done + 1;
  }
  const std::stop_token& stop = hooks.stop;
  const ProgressCallback& progress = hooks.progress;

  for (int pass = first_pass; pass <= settings.passes; ++pass) {
    if (pass > 1) {
      // Restart the states and their covariance, keep theta and its covariance.
      z << x0, theta_end;
      P.setZero();
      P.topLeftCorner(nx, nx) = settings.P0.topLeftCorner(nx, nx);
      P.bottomRightCorner(ntheta, ntheta) = P_end.bottomRightCorner(ntheta, ntheta);
    }
    RICCATI_RETURN_IF_ERROR(filter->reset(bound.t[first], z, P));

    PassResult pr;
    pr.theta_trace.resize(ntheta, N);
    Eigen::VectorXd innovation_sq = Eigen::VectorXd::Zero(ny);
    double nis_sum = 0.0;
    IdentificationProgress report{pass, settings.passes, 0, N, &filter->state()};
    for (Eigen::Index k = 0; k < N; ++k) {
      if (stop.stop_requested()) {
        return cancelled("identification cancelled in pass " + std::to_string(pass) + " at sample " +
                         std::to_string(k + 1));
      }
      const Eigen::Index s = first + k;
      auto where = [&] {
        return "pass " + std::to_string(pass) + ", sample " + std::to_string(k + 1) + " (t = " +
               std::to_string(bound.t[s]) + ")";
      };
      Status st = k == 0 ? filter->update(bound.y.col(s).data(), bound.u.col(s).data())
                         : filter->step(bound.t[s], bound.u.col(s - 1).data(), bound.u.col(s).data(),
                                        bound.y.col(s).data());
      if (!st.is_ok()) return st.with_context(where());

      const Eigen::VectorXd& zk = filter->state();
      pr.theta_trace.col(k) = zk.tail(ntheta);
      innovation_sq += filter->innovation().cwiseAbs2();
      nis_sum += filter->nis();
      if (pass == settings.passes) {
        result.x_trace.col(k) = zk.head(nx);
        result.innovations.col(k) = filter->innovation();
        st = model->g(bound.t[s], bound.u.col(s).data(), 1, 1, zk.data(), zk.data() + nx, y_post.data());
        if (!st.is_ok()) return st.with_context(where());
        result.y_model.col(k) = y_post;
      }
      if (progress) {
        report.sample = k + 1;
        progress(report);
      }
    }
    pr.theta_final = filter->state().tail(ntheta);
    pr.theta_mean = pr.theta_trace.rowwise().mean();
    pr.theta_std = filter->covariance().diagonal().tail(ntheta).cwiseMax(0.0).cwiseSqrt();
    pr.innovation_rms = (innovation_sq / static_cast<double>(N)).cwiseSqrt();
    pr.nis_mean = nis_sum / static_cast<double>(N);
    result.passes.push_back(std::move(pr));
    theta_end = filter->state().tail(ntheta);
    P_end = filter->covariance();
    if (pass < settings.passes && hooks.pass_done) {
      RICCATI_RETURN_IF_ERROR(
          hooks.pass_done(pass, result.passes.back(), P_end).with_context("checkpoint after pass " + std::to_string(pass)));
    }
  }

  const PassResult& last = result.passes.back();
  result.theta = last.theta_final;
  result.theta_mean = last.theta_mean;
  result.theta_std = last.theta_std;
  result.covariance = filter->covariance();
  return result;
}

}  // namespace riccati
