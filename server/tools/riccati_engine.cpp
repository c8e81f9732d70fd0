// riccati-engine: the estimation engine on the command line, without a daemon.
//
//   riccati-engine models
//   riccati-engine identify --model two_tank --data two_tank.csv --inputs F1,F2 --outputs h1,h2
//       --theta0 20,20,1,1 --p0 0,0,10,10,10,10 --r 1e-3,1e-3 --passes 10 --x0 first --validate
//   riccati-engine validate --model two_tank --data two_tank.csv --inputs F1,F2 --outputs h1,h2
//       --theta 10,5,0.0791,0.1342
//
// Exit codes: 0 success, 1 the run failed (bad data, divergence, ...), 2 usage.
#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdio>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include "engine/estimation/identification.hpp"
#include "engine/filters/filter_kinds.hpp"
#include "engine/models/plugin_loader.hpp"
#include "engine/estimation/validation.hpp"

namespace {

using namespace riccati;

constexpr int kExitFailure = 1;
constexpr int kExitUsage = 2;

struct CommonOptions {
  std::string models_dir = default_models_dir();
  std::string model;
  std::string data;
  std::vector<std::string> inputs, outputs;
  std::string time_column = "t";
  std::string integrator = "rk4";
  int substeps = 10;
  double rtol = 1e-8, atol = 1e-10;
  std::string hold = "zoh";
  std::string x0 = "first";  // "first" (measurement) or a comma-separated list
};

struct IdentifyOptions {
  std::string filter = "ekf";
  std::vector<double> theta0, p0, q = {0.0}, r, truth;
  int passes = 1;
  std::string inversion = "cholesky";
  std::string weights = "julier";
  double alpha = 1.0, beta = 2.0, kappa = std::numeric_limits<double>::quiet_NaN();
  bool no_joseph = false;
  bool validate = false;
};

// A diagonal from a list: one value is broadcast to all n.
Result<Eigen::MatrixXd> diagonal(const std::vector<double>& values, Eigen::Index n, const char* what) {
  if (values.size() == 1) return Eigen::MatrixXd(Eigen::VectorXd::Constant(n, values[0]).asDiagonal());
  if (static_cast<Eigen::Index>(values.size()) != n) {
    return invalid_argument(std::string(what) + " needs " + std::to_string(n) + " values (or one for all), got " +
                            std::to_string(values.size()));
  }
  return Eigen::MatrixXd(Eigen::Map<const Eigen::VectorXd>(values.data(), n).asDiagonal());
}

Eigen::VectorXd to_vector(const std::vector<double>& v) {
  return Eigen::Map<const Eigen::VectorXd>(v.data(), static_cast<Eigen::Index>(v.size()));
}

Result<ModelPtr> find_model(const CommonOptions& o, ModelRegistry* keep) {
  RICCATI_ASSIGN_OR_RETURN(*keep, ModelRegistry::load_directory(o.models_dir));
  ModelPtr m = keep->find(o.model);
  if (m == nullptr) {
    std::string names;
    for (const auto& x : keep->models()) names += (names.empty() ? "" : ", ") + x->name();
    return not_found("no model \"" + o.model + "\" in " + o.models_dir + " (available: " + names + ")");
  }
  return m;
}

Status initial_state_option(const std::string& x0, InitialState* mode, Eigen::VectorXd* values) {
  if (x0 == "first") {
    *mode = InitialState::kFirstMeasurement;
    return Status::ok();
  }
  *mode = InitialState::kGiven;
  std::vector<double> v;
  std::stringstream ss(x0);
  std::string item;
  while (std::getline(ss, item, ',')) {
    try {
      std::size_t used = 0;
      v.push_back(std::stod(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      return invalid_argument("--x0: \"" + item + "\" is not a number (give \"first\" or a list of numbers)");
    }
  }
  *values = to_vector(v);
  return Status::ok();
}

Result<IntegratorSettings> integrator_settings(const CommonOptions& o) {
  IntegratorSettings s;
  RICCATI_ASSIGN_OR_RETURN(s.kind, parse_integrator_kind(o.integrator));
  s.substeps = o.substeps;
  s.rtol = o.rtol;
  s.atol = o.atol;
  return s;
}

void print_fit_table(const std::vector<OutputFit>& fits) {
  std::printf("\n%-12s %12s %10s %10s %12s\n", "output", "RMSE", "fit %", "VAF %", "RRSE");
  for (const auto& f : fits) {
    std::printf("%-12s %12.4g %10.3f %10.3f %12.4g\n", f.name.c_str(), f.rmse, f.fit_percent, f.vaf_percent, f.rrse);
  }
}

Status run_validation(const Model& model, const Dataset& data, const CommonOptions& o, const Eigen::VectorXd& theta) {
  ValidationSettings vs;
  RICCATI_ASSIGN_OR_RETURN(vs.simulation.integrator, integrator_settings(o));
  RICCATI_ASSIGN_OR_RETURN(vs.simulation.hold, parse_hold_order(o.hold));
  RICCATI_RETURN_IF_ERROR(initial_state_option(o.x0, &vs.initial_state, &vs.x0));
  vs.theta = theta;
  RICCATI_ASSIGN_OR_RETURN(const ValidationResult vr, validate_model(model, data, vs));
  std::printf("\nValidation: simulation with these parameters over %s (%lld samples)", data.name.c_str(),
              static_cast<long long>(data.size()));
  print_fit_table(vr.fits);
  return Status::ok();
}

Status identify_command(const CommonOptions& o, const IdentifyOptions& io) {
  ModelRegistry registry;
  RICCATI_ASSIGN_OR_RETURN(const ModelPtr model, find_model(o, &registry));
  RICCATI_ASSIGN_OR_RETURN(const Dataset data,
                           read_dataset_file(o.data, ColumnMapping{o.time_column, o.inputs, o.outputs}));

  IdentificationSettings s;
  FilterSettings& f = s.filter;
  RICCATI_ASSIGN_OR_RETURN(f.kind, parse_filter_kind(io.filter));
  RICCATI_ASSIGN_OR_RETURN(f.hold, parse_hold_order(o.hold));
  RICCATI_ASSIGN_OR_RETURN(f.integrator, integrator_settings(o));
  RICCATI_ASSIGN_OR_RETURN(f.inversion, parse_gain_inversion(io.inversion));
  RICCATI_ASSIGN_OR_RETURN(f.ukf.weights, parse_sigma_weights(io.weights));
  f.ukf.alpha = io.alpha;
  f.ukf.beta = io.beta;
  f.ukf.kappa = io.kappa;
  f.joseph = !io.no_joseph;
  RICCATI_ASSIGN_OR_RETURN(f.Q, diagonal(io.q, model->nz(), "--q"));
  if (io.r.empty()) return invalid_argument("--r (measurement noise variances) is required");
  RICCATI_ASSIGN_OR_RETURN(f.R, diagonal(io.r, model->ny(), "--r"));
  RICCATI_ASSIGN_OR_RETURN(s.initial.P0, diagonal(io.p0, model->nz(), "--p0"));
  s.initial.theta0 = io.theta0.empty() ? model->theta_default() : to_vector(io.theta0);
  s.passes = io.passes;
  RICCATI_RETURN_IF_ERROR(initial_state_option(o.x0, &s.initial.mode, &s.initial.x0));

  const auto start = std::chrono::steady_clock::now();
  RICCATI_ASSIGN_OR_RETURN(const IdentificationResult r, identify(model, data, s));
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  std::printf("Identification of %s on %s: %s, %d passes over %lld samples (%.3f s)\n\n", model->name().c_str(),
              data.name.c_str(), filter_kind_name(f.kind), s.passes, static_cast<long long>(r.t.size()), seconds);
  const bool with_truth = io.truth.size() == static_cast<std::size_t>(model->ntheta());
  std::printf("%-10s %12s %14s %12s %12s", "parameter", "initial", "estimate", "std", "final");
  if (with_truth) std::printf(" %12s %9s", "true", "error %");
  std::printf("\n");
  for (int i = 0; i < model->ntheta(); ++i) {
    std::printf("%-10s %12.6g %14.8g %12.4g %12.6g", model->param_names()[i].c_str(), s.initial.theta0[i], r.theta_mean[i],
                r.theta_std[i], r.theta[i]);
    if (with_truth) {
      std::printf(" %12.6g %9.3f", io.truth[i], 100.0 * (r.theta_mean[i] - io.truth[i]) / io.truth[i]);
    }
    std::printf("\n");
  }
  std::printf("(estimate: mean over the last pass, as the 1999 toolbox reports; std: at the end)\n");
  std::printf("innovation RMS (last pass):");
  for (int i = 0; i < model->ny(); ++i) {
    std::printf(" %s %.3g", model->output_names()[i].c_str(), r.passes.back().innovation_rms[i]);
  }
  std::printf("; mean NIS %.3g\n", r.passes.back().nis_mean);
  if (io.validate) RICCATI_RETURN_IF_ERROR(run_validation(*model, data, o, r.theta_mean));
  return Status::ok();
}

Status validate_command(const CommonOptions& o, const std::vector<double>& theta) {
  ModelRegistry registry;
  RICCATI_ASSIGN_OR_RETURN(const ModelPtr model, find_model(o, &registry));
  RICCATI_ASSIGN_OR_RETURN(const Dataset data,
                           read_dataset_file(o.data, ColumnMapping{o.time_column, o.inputs, o.outputs}));
  return run_validation(*model, data, o, theta.empty() ? model->theta_default() : to_vector(theta));
}

Status models_command(const std::string& dir) {
  RICCATI_ASSIGN_OR_RETURN(const ModelRegistry registry, ModelRegistry::load_directory(dir));
  std::printf("%-22s %4s %7s %4s %4s  %s\n", "model", "nx", "ntheta", "nu", "ny", "description");
  for (const auto& m : registry.models()) {
    std::printf("%-22s %4d %7d %4d %4d  %s\n", m->name().c_str(), m->nx(), m->ntheta(), m->nu(), m->ny(),
                m->description().c_str());
  }
  for (const auto& r : registry.refused()) std::fprintf(stderr, "refused: %s\n", r.reason.c_str());
  return Status::ok();
}

void add_common(CLI::App* cmd, CommonOptions* o) {
  cmd->add_option("--models-dir", o->models_dir, "Directory of model plugins")->capture_default_str();
  cmd->add_option("--model,-m", o->model, "Model name")->required();
  cmd->add_option("--data,-d", o->data, "Dataset file (.csv with a header row, or .mat with T, U, Y)")->required();
  cmd->add_option("--inputs", o->inputs, "Input columns, in the model's order")->delimiter(',');
  cmd->add_option("--outputs", o->outputs, "Output columns, in the model's order")->delimiter(',')->required();
  cmd->add_option("--time", o->time_column, "Time column")->capture_default_str();
  cmd->add_option("--integrator", o->integrator, "rk4, rk3, cvode-bdf, cvode-adams or arkode-erk")
      ->capture_default_str();
  cmd->add_option("--substeps", o->substeps, "Fixed-step integrators: steps per sample")->capture_default_str();
  cmd->add_option("--rtol", o->rtol, "Adaptive integrators: relative tolerance")->capture_default_str();
  cmd->add_option("--atol", o->atol, "Adaptive integrators: absolute tolerance")->capture_default_str();
  cmd->add_option("--hold", o->hold, "Input hold between samples: zoh or foh")->capture_default_str();
  cmd->add_option("--x0", o->x0, "Initial state: \"first\" (first measurement) or comma-separated values")
      ->capture_default_str();
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"riccati-engine: identification and validation of continuous-time models, offline"};
  app.require_subcommand(1);

  std::string models_dir = default_models_dir();
  auto* models = app.add_subcommand("models", "List the model plugins");
  models->add_option("--models-dir", models_dir, "Directory of model plugins")->capture_default_str();

  CommonOptions id_common;
  IdentifyOptions io;
  auto* identify_cmd = app.add_subcommand("identify", "Multi-pass identification of a model's parameters");
  add_common(identify_cmd, &id_common);
  identify_cmd->add_option("--filter", io.filter, "Filter: " + filter_kind_names())->capture_default_str();
  identify_cmd->add_option("--theta0", io.theta0, "Initial parameters (default: the model's defaults)")
      ->delimiter(',');
  identify_cmd->add_option("--p0", io.p0, "Initial variances of [x; theta] (one value: all)")
      ->delimiter(',')
      ->required();
  identify_cmd->add_option("--q", io.q, "Process noise intensities of [x; theta] (one value: all)")
      ->delimiter(',')
      ->capture_default_str();
  identify_cmd->add_option("--r", io.r, "Measurement noise variances (one value: all)")->delimiter(',')->required();
  identify_cmd->add_option("--passes", io.passes, "Passes over the data")->capture_default_str();
  identify_cmd->add_option("--inversion", io.inversion, "Gain solve: cholesky or pinv")->capture_default_str();
  identify_cmd->add_flag("--no-joseph", io.no_joseph, "EKF: short covariance update instead of Joseph form");
  identify_cmd->add_option("--weights", io.weights, "UKF sigma-point weights: julier or scaled")->capture_default_str();
  identify_cmd->add_option("--alpha", io.alpha, "UKF scaled weights: alpha")->capture_default_str();
  identify_cmd->add_option("--beta", io.beta, "UKF scaled weights: beta")->capture_default_str();
  identify_cmd->add_option("--kappa", io.kappa, "UKF kappa (default 3 - n for julier, 0 for scaled)");
  identify_cmd->add_option("--truth", io.truth, "True parameters, to print the error")->delimiter(',');
  identify_cmd->add_flag("--validate", io.validate, "Then simulate the identified model against the data");

  CommonOptions val_common;
  std::vector<double> theta;
  auto* validate_cmd = app.add_subcommand("validate", "Simulate a model against measured data and report the fit");
  add_common(validate_cmd, &val_common);
  validate_cmd->add_option("--theta", theta, "Parameters (default: the model's defaults)")->delimiter(',');

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : kExitUsage;
  }

  Status status;
  if (*models) status = models_command(models_dir);
  if (*identify_cmd) status = identify_command(id_common, io);
  if (*validate_cmd) status = validate_command(val_common, theta);
  if (!status.is_ok()) {
    std::fprintf(stderr, "riccati-engine: %s\n", status.to_string().c_str());
    return status.code() == StatusCode::kInvalidArgument ? kExitUsage : kExitFailure;
  }
  return 0;
}
