#include "service/jobs/identification_job.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "engine/estimation/binding.hpp"
#include "engine/filters/filter_kinds.hpp"
#include "service/convert.hpp"
#include "service/jobs/job_convert.hpp"
#include "service/run_settings.hpp"

namespace riccati::service {
namespace {


// The index of parameter `name`, or an error naming the field and the choices.
Result<Eigen::Index> parameter(const Model& model, const std::string& name, const std::string& field) {
  const int i = model.param_index(name);
  if (i < 0) {
    return invalid_argument(field + ": model " + model.name() + " has no parameter \"" + name + "\" (its parameters: " +
                            parameter_list(model) + ")");
  }
  return static_cast<Eigen::Index>(i);
}

}  // namespace

Result<std::vector<bool>> estimated_states(const v1::InitialState& s, const Model& model, const std::string& field) {
  std::vector<bool> out(static_cast<std::size_t>(model.nx()), false);
  for (const std::string& name : s.estimate()) {
    if (name == "all") {
      out.assign(out.size(), true);
      continue;
    }
    const int i = model.state_index(name);
    if (i < 0) {
      return invalid_argument(field + ".estimate: model " + model.name() + " has no state \"" + name +
                              "\" (its states: " + join_names(model.state_names()) + ", or all)");
    }
    out[static_cast<std::size_t>(i)] = true;
  }
  return out;
}

namespace {

Result<ExperimentSpec> experiment_from_proto(const std::string& dataset_id, const v1::InitialState& initial,
                                             const v1::SampleMask& mask, const Model& model, const std::string& field) {
  // `field`: where the experiment is in the spec ("experiments[0]"); empty
  // for experiment 1, whose fields are the spec's own.
  const auto at = [&](const std::string& name) { return field.empty() ? name : field + "." + name; };
  ExperimentSpec e;
  e.dataset_id = dataset_id;
  if (dataset_id.empty()) return invalid_argument(at("dataset_id") + ": a dataset id is needed");
  initial_state_from_proto(initial, &e.mode, &e.x0);
  if (e.x0.size() != 0 || e.mode == InitialState::kGiven) {
    RICCATI_RETURN_IF_ERROR(from_values(initial.x0(), model.nx(), at("initial_state.x0")).status());
  }
  RICCATI_ASSIGN_OR_RETURN(e.estimate_x0, estimated_states(initial, model, at("initial_state")));
  for (const v1::OutputLimit& limit : mask.limits()) {
    if (model.output_index(limit.output()) < 0) {
      return invalid_argument(at("mask") + ": model " + model.name() + " has no output \"" + limit.output() +
                              "\" (its outputs: " + join_names(model.output_names()) + ")");
    }
    if ((limit.has_lower() && !std::isfinite(limit.lower())) || (limit.has_upper() && !std::isfinite(limit.upper()))) {
      return invalid_argument(at("mask") + ": the limits of output " + limit.output() + " must be finite");
    }
  }
  for (const v1::SampleRange& range : mask.excluded()) {
    if (range.end() <= range.first()) {
      return invalid_argument(at("mask") + ": the excluded range [" + std::to_string(range.first()) + ", " +
                              std::to_string(range.end()) + ") is empty");
    }
  }
  e.mask = mask;
  return e;
}

// The parameters: theta0, the model's bounds narrowed by the spec's,
// fixed ones, log scales.
Result<ParameterSettings> parameters_from_proto(const v1::IdentificationSpec& spec, const Eigen::VectorXd& theta0,
                                                const Model& model) {
  ParameterSettings p = default_parameters(model, theta0);
  for (const v1::ParameterBound& b : spec.bounds()) {
    RICCATI_ASSIGN_OR_RETURN(const Eigen::Index i, parameter(model, b.name(), "bounds"));
    if (b.has_lower()) p.lower[i] = b.lower();
    if (b.has_upper()) p.upper[i] = b.upper();
  }
  for (const v1::FixedParameter& f : spec.fixed()) {
    RICCATI_ASSIGN_OR_RETURN(const Eigen::Index i, parameter(model, f.name(), "fixed"));
    p.fixed[static_cast<std::size_t>(i)] = true;
    if (f.has_value()) p.theta0[i] = f.value();
  }
  for (const std::string& name : spec.log_scale()) {
    RICCATI_ASSIGN_OR_RETURN(const Eigen::Index i, parameter(model, name, "log_scale"));
    p.log_scale[static_cast<std::size_t>(i)] = true;
  }
  RICCATI_RETURN_IF_ERROR(validate(p, model));
  return p;
}

OptimizerSettings optimizer_from_proto(const v1::EstimationSettings& e) {
  OptimizerSettings o;
  if (e.max_iterations() != 0) o.max_iterations = static_cast<int>(std::min<uint32_t>(e.max_iterations(), 100000));
  if (e.function_tolerance() > 0.0) o.function_tolerance = e.function_tolerance();
  if (e.gradient_tolerance() > 0.0) o.gradient_tolerance = e.gradient_tolerance();
  if (e.parameter_tolerance() > 0.0) o.parameter_tolerance = e.parameter_tolerance();
  return o;
}

// Output error: the model simulated with the filter's hold and integrator.
Status output_error_from_proto(const v1::EstimationSettings& est, const OptimizerSettings& optimizer,
                               const Model& model, IdentificationJob* job) {
  job->output_error.simulation.hold = job->filter.filter.hold;
  job->output_error.simulation.integrator = job->filter.filter.integrator;
  if (est.output_sigma_size() != 0) {
    RICCATI_ASSIGN_OR_RETURN(job->output_error.output_sigma,
                             from_values(est.output_sigma(), model.ny(), "estimation.output_sigma"));
    if (!(job->output_error.output_sigma.array() > 0.0).all()) {
      return invalid_argument("estimation.output_sigma must be positive");
    }
  }
  job->output_error.optimizer = optimizer;
  return enum_from_proto(est.covariance(), *v1::ParameterCovariance_descriptor(), &parse_covariance_choice,
                         "estimation.covariance", &job->output_error.covariance);
}

// Maximum likelihood: the filter is the predictor.
Status max_likelihood_from_proto(const v1::EstimationSettings& est, const OptimizerSettings& optimizer,
                                 const Model& model, IdentificationJob* job) {
  if (job->filter.filter.kind != FilterKind::kEkf && job->filter.filter.kind != FilterKind::kUkf) {
    return invalid_argument("method ml predicts with the EKF or the UKF, not the " +
                            std::string(filter_kind_name(job->filter.filter.kind)) + " filter");
  }
  MaxLikelihoodSettings& ml = job->max_likelihood;
  ml.filter = job->filter.filter;
  ml.P0x = job->filter.initial.P0.topLeftCorner(model.nx(), model.nx());
  ml.estimate_process_noise = est.estimate_process_noise();
  ml.estimate_measurement_noise = est.estimate_measurement_noise();
  ml.optimizer = optimizer;
  if (ml.estimate_process_noise && !(ml.filter.Q.diagonal().head(model.nx()).array() > 0.0).all()) {
    return invalid_argument("estimation.estimate_process_noise needs filter.q with a positive start for every state");
  }
  return Status::ok();
}

// The likelihood's predictor filters the states alone (the parameters are
// not augmented), so its filter.q may be the states' nx intensities, a
// diagonal or an nx x nx matrix: made the nz x nz the filter settings take,
// the parameters' part zero (also for the iterated filter's passes before).
Status states_q_to_augmented(const Model& model, v1::FilterSettings* filter) {
  if (!filter->has_q()) return Status::ok();
  const int nx = model.nx(), nz = model.nz();
  v1::Covariance* q = filter->mutable_q();
  if (q->has_diagonal()) {
    const int given = q->diagonal().values_size();
    if (given == nx) {
      for (int i = nx; i < nz; ++i) q->mutable_diagonal()->add_values(0.0);
    } else if (given != nz) {
      return invalid_argument("filter.q.diagonal needs " + std::to_string(nx) +
                              " values (the states': method ml filters the states alone) or " + std::to_string(nz) +
                              ", got " + std::to_string(given));
    }
  } else if (q->has_full() && q->full().rows() == static_cast<uint32_t>(nx) &&
             q->full().cols() == static_cast<uint32_t>(nx) && q->full().values_size() == nx * nx) {
    const v1::Matrix states = q->full();
    v1::Matrix* full = q->mutable_full();
    full->set_rows(static_cast<uint32_t>(nz));
    full->set_cols(static_cast<uint32_t>(nz));
    full->clear_values();
    for (int c = 0; c < nz; ++c) {
      for (int r = 0; r < nz; ++r) full->add_values(r < nx && c < nx ? states.values(c * nx + r) : 0.0);
    }
  }
  return Status::ok();
}

Status refuse(bool given, const std::string& what, IdentificationMethod method) {
  if (!given) return Status::ok();
  return invalid_argument(what + " does not apply to method " + identification_method_name(method));
}

}  // namespace

std::string parameter_list(const Model& model) { return join_names(model.param_names()); }

Result<IdentificationJob> identification_from_proto(const v1::IdentificationSpec& given, const Model& model) {
  IdentificationJob job;
  RICCATI_RETURN_IF_ERROR(enum_from_proto(given.method(), *v1::IdentificationMethod_descriptor(),
                                          &parse_identification_method, "method", &job.method));
  // What the proto's schema says of where each setting applies.
  RICCATI_RETURN_IF_ERROR(check_settings_apply(given));
  const IdentificationMethodInfo& method = identification_method_info(job.method);
  const bool filter_method = method.iterated_filter;
  const bool runs_filter = filter_method || given.init_passes() > 0 || method.filter_predictor;
  v1::IdentificationSpec spec = given;
  if (!filter_method && !given.has_p0() && !given.filter().optimal().has_r0()) {
    // Output error and the likelihood take P0 only for the filter passes
    // before them (and ML for its states' block): absent, the states are known.
    spec.mutable_p0()->set_scalar(0.0);
  }
  if (!runs_filter && !given.filter().has_r()) {
    // Output error alone runs no filter: its noise settings are not used.
    spec.mutable_filter()->mutable_r()->set_scalar(1.0);
  }
  if (method.filter_predictor) RICCATI_RETURN_IF_ERROR(states_q_to_augmented(model, spec.mutable_filter()));
  RICCATI_ASSIGN_OR_RETURN(job.filter, from_proto(spec, model));
  RICCATI_ASSIGN_OR_RETURN(job.parameters, parameters_from_proto(spec, job.filter.initial.theta0, model));
  job.filter.initial.theta0 = job.parameters.theta0;  // fixed values included

  // Experiment 1, then the others.
  RICCATI_ASSIGN_OR_RETURN(ExperimentSpec first,
                           experiment_from_proto(spec.dataset_id(), spec.initial_state(), spec.mask(), model, ""));
  job.experiments.push_back(std::move(first));
  for (int e = 0; e < spec.experiments_size(); ++e) {
    const v1::Experiment& x = spec.experiments(e);
    RICCATI_ASSIGN_OR_RETURN(ExperimentSpec more,
                             experiment_from_proto(x.dataset_id(), x.initial_state(), x.mask(), model,
                                                   "experiments[" + std::to_string(e) + "]"));
    job.experiments.push_back(std::move(more));
  }
  const bool any_x0_estimated = std::any_of(job.experiments.begin(), job.experiments.end(), [](const ExperimentSpec& e) {
    return std::find(e.estimate_x0.begin(), e.estimate_x0.end(), true) != e.estimate_x0.end();
  });

  if (filter_method) {
    // The iterated filter: bounds hold its estimate, a fixed parameter has
    // no variance (in P0 or Q) to move by.
    RICCATI_RETURN_IF_ERROR(refuse(spec.experiments_size() > 0, "more than one experiment", job.method));
    RICCATI_RETURN_IF_ERROR(refuse(any_x0_estimated, "initial_state.estimate (the filter estimates the states with their P0)",
                                   job.method));
    // (Of the estimation settings only the covariance applies; the schema's
    // check refused the others.)
    RICCATI_RETURN_IF_ERROR(enum_from_proto(spec.estimation().covariance(), *v1::ParameterCovariance_descriptor(),
                                            &parse_covariance_choice, "estimation.covariance",
                                            &job.filter.covariance));
    // The 1999 toolbox's filter as it is, unless bounds are asked for: then
    // the estimate is held within them (the model's, narrowed by the spec's).
    if (spec.bounds_size() > 0) {
      job.filter.theta_lower = job.parameters.lower;
      job.filter.theta_upper = job.parameters.upper;
    }
    const int nx = model.nx();
    for (int i = 0; i < model.ntheta(); ++i) {
      if (!job.parameters.fixed[static_cast<std::size_t>(i)]) continue;
      job.filter.initial.P0.row(nx + i).setZero();
      job.filter.initial.P0.col(nx + i).setZero();
      if (job.filter.filter.Q.size() != 0) {
        job.filter.filter.Q.row(nx + i).setZero();
        job.filter.filter.Q.col(nx + i).setZero();
      }
    }
    return job;
  }

  job.init_passes = static_cast<int>(std::min<uint32_t>(spec.init_passes(), 1u << 20));
  if (job.init_passes > 0) {
    job.filter.passes = job.init_passes;
    job.filter.theta_lower = job.parameters.lower;
    job.filter.theta_upper = job.parameters.upper;
  }
  const v1::EstimationSettings& est = spec.estimation();
  const OptimizerSettings optimizer = optimizer_from_proto(est);
  switch (job.method) {
    case IdentificationMethod::kOutputError:
      RICCATI_RETURN_IF_ERROR(output_error_from_proto(est, optimizer, model, &job));
      return job;
    case IdentificationMethod::kMaxLikelihood:
      RICCATI_RETURN_IF_ERROR(max_likelihood_from_proto(est, optimizer, model, &job));
      return job;
    case IdentificationMethod::kFilter:
      break;
  }
  return internal_error(std::string("method ") + identification_method_name(job.method) + " has no optimiser");
}

Status dataset_fits_model(const DatasetRecord& record, const Model& model) {
  return check_columns(model, record.input_names, record.output_names);
}

Status check_against_datasets(const IdentificationJob& job, const std::vector<DatasetRecord>& records,
                              const Model& model) {
  for (std::size_t e = 0; e < job.experiments.size(); ++e) {
    const ExperimentSpec& spec = job.experiments[e];
    const DatasetRecord& record = records[e];
    const std::string which = "experiment " + std::to_string(e + 1) + " (" + record.id + ")";
    RICCATI_RETURN_IF_ERROR(dataset_fits_model(record, model).with_context(which));
    for (const v1::SampleRange& range : spec.mask.excluded()) {
      if (range.end() > static_cast<uint64_t>(record.samples)) {
        return invalid_argument(which + ": the excluded range [" + std::to_string(range.first()) + ", " +
                                std::to_string(range.end()) + ") goes past its " + std::to_string(record.samples) +
                                " samples");
      }
    }
    if (spec.mode == InitialState::kFirstMeasurement) {
      bool any = false;
      for (const std::string& state : model.state_names()) any |= model.output_index(state) >= 0;
      if (!any) {
        return invalid_argument(which + ": x0 = first measurement needs outputs named as states; model " +
                                model.name() + " has states (" + join_names(model.state_names()) + ") and outputs (" +
                                join_names(model.output_names()) + ")");
      }
    }
  }
  const Eigen::Index end = job.filter.end_sample < 0 ? records.front().samples : job.filter.end_sample;
  if (end > records.front().samples || end - job.filter.first_sample < 2) {
    return invalid_argument("the sample range [" + std::to_string(job.filter.first_sample) + ", " +
                            std::to_string(end) + ") must hold at least two of the dataset's " +
                            std::to_string(records.front().samples) + " samples");
  }
  return Status::ok();
}

namespace {

// The doubles of one experiment's fit (ExperimentFit): t, y measured and
// modelled, residuals and mask per sample; the initial states; and the
// residual diagnostics (diagnostics.hpp), whose cross-correlation of every
// output with every input at lags -h..h is (ny nu) x (2h + 1): with many
// inputs and outputs it outgrows the samples themselves.
double experiment_fit_values(double samples, double nx, double ny, double nu) {
  const double h = std::min(20.0, std::floor(samples / 4));
  const double per_sample = samples * (1 + 4 * ny);
  const double fits = 8 * ny;                                            // OutputFit per output
  // (statistic, limit, p-value and dof: each a double's worth at most)
  const double diagnostics = ny * h + 2 * ny + ny * nu * (2 * h + 1) + 5 * ny * nu + 11;
  const double summary = (ny + ny * nu + 1) * 16;  // a line per test, ~128 bytes: in doubles' worth
  return per_sample + 3 * nx + fits + diagnostics + summary;
}

}  // namespace

ResultSize estimated_result_size(const IdentificationJob& job, const std::vector<DatasetRecord>& records,
                                 const Model& model) {
  // The first experiment within its sample range (checked by check_against_datasets).
  const Eigen::Index end = job.filter.end_sample < 0 ? records.front().samples : job.filter.end_sample;
  const double first = static_cast<double>(end - job.filter.first_sample);
  const double ny = model.ny(), nx = model.nx(), nu = model.nu(), ntheta = model.ntheta();
  // Each name once, in bytes as doubles' worth (8 a double), with its tag.
  double name_values = 0;
  for (const auto* names : {&model.state_names(), &model.param_names(), &model.output_names()}) {
    for (const std::string& name : *names) name_values += static_cast<double>(name.size() + 2) / 8;
  }
  ResultSize size;
  size.smaller = "fewer passes, or a shorter sample range (first_sample, end_sample)";
  double values = name_values;
  const IdentificationMethodInfo& method = identification_method_info(job.method);
  if (method.iterated_filter || job.init_passes > 0) {
    const int passes = method.iterated_filter ? job.filter.passes : job.init_passes;
    // Each pass's theta trace and summary (final, mean, std, innovation RMS);
    // t, x_trace, y_model and innovations once.
    values += passes * (ntheta * first + 3 * ntheta + ny) + first * (1 + nx + 2 * ny) + 3 * ntheta;
    size.what = std::to_string(passes) + " passes x " + std::to_string(model.ntheta()) + " parameters x " +
                std::to_string(end - job.filter.first_sample) + " samples of estimate traces";
  }
  if (method.optimiser) {
    // The estimate: values, deviations, intervals, covariance and
    // correlation, the cost after each iteration, noise levels (ML).
    const int iterations = job.method == IdentificationMethod::kOutputError
                               ? job.output_error.optimizer.max_iterations
                               : job.max_likelihood.optimizer.max_iterations;
    values += 6 * ntheta + 2 * ntheta * ntheta + std::max(iterations, 0) + 2 + 4 * (nx + ny) + 16;
    // Each experiment's fit, its residuals' diagnostics included.
    double samples = first;
    values += experiment_fit_values(first, nx, ny, nu);
    for (std::size_t e = 1; e < records.size(); ++e) {
      const auto n = static_cast<double>(records[e].samples);
      samples += n;
      values += experiment_fit_values(n, nx, ny, nu);
    }
    if (size.what.empty()) size.smaller = "a shorter sample range (first_sample, end_sample), or fewer experiments";
    size.what += (size.what.empty() ? "" : ", and ") + std::to_string(static_cast<std::int64_t>(samples)) +
                 " samples x " + std::to_string(1 + 4 * model.ny()) + " values of fitted outputs in " +
                 std::to_string(records.size()) + " experiments, with residual diagnostics of " +
                 std::to_string(model.ny()) + " outputs x " + std::to_string(model.nu()) + " inputs";
  }
  size.bytes = 8 * values + kFixedResultBytes + kResultBytesPerName * (nx + ntheta + ny + nu);
  return size;
}

Result<Eigen::ArrayXXd> make_mask(const v1::SampleMask& mask, const Dataset& bound, const Model& model) {
  const Eigen::Index ny = model.ny(), N = bound.size();
  Eigen::ArrayXXd m = Eigen::ArrayXXd::Ones(ny, N);
  for (const v1::OutputLimit& limit : mask.limits()) {
    const int i = model.output_index(limit.output());
    if (i < 0) return invalid_argument("the mask names an output \"" + limit.output() + "\" the model has not");
    for (Eigen::Index k = 0; k < N; ++k) {
      const double y = bound.y(i, k);
      if ((limit.has_lower() && y <= limit.lower()) || (limit.has_upper() && y >= limit.upper())) m(i, k) = 0.0;
    }
  }
  for (const v1::SampleRange& range : mask.excluded()) {
    const auto first = static_cast<Eigen::Index>(range.first());
    const auto end = std::min(static_cast<Eigen::Index>(range.end()), N);
    if (first < end) m.middleCols(first, end - first).setZero();
  }
  if ((m == 1.0).all()) return Eigen::ArrayXXd();
  return m;
}

Result<Experiment> make_experiment(const ExperimentSpec& spec, const Dataset& bound, const Model& model) {
  Experiment e;
  e.data = bound;
  const Eigen::Map<const Eigen::VectorXd> first(bound.y.col(0).data(), bound.y.rows());
  RICCATI_ASSIGN_OR_RETURN(e.x0, initial_state(model, spec.mode, spec.x0,
                                               {first.data(), static_cast<std::size_t>(first.size())}));
  e.estimate_x0 = spec.estimate_x0;
  RICCATI_ASSIGN_OR_RETURN(e.mask, make_mask(spec.mask, bound, model));
  return e;
}

}  // namespace riccati::service
