// What the identification methods that find an optimum share (output error,
// maximum likelihood; docs/identification.md): the unknowns and their bounds, the
// experiments, the optimiser's settings, how a run is watched and stopped,
// and the result with its uncertainty.
//
// Unknowns are the free parameters theta (some fixed by name, each within
// [lower, upper], positive ones optionally on a log scale) shared by every
// experiment, and each experiment's initial states that are estimated. The
// optimiser moves in solver coordinates: phi = log(theta) for a log-scaled
// parameter, theta otherwise.
#pragma once

#include <Eigen/Core>
#include <functional>
#include <span>
#include <stop_token>
#include <string>
#include <vector>

#include "engine/data/dataset.hpp"
#include "engine/estimation/diagnostics.hpp"
#include "engine/estimation/fit_metrics.hpp"
#include "engine/models/model.hpp"
#include "engine/status.hpp"

namespace riccati {

// How an identification finds the parameters: the iterated filter of the
// 1999 toolbox (identification.hpp), output error (output_error.hpp) or
// maximum likelihood (max_likelihood.hpp). Named "filter", "oe", "ml" (the
// API's and the CLI's names).
enum class IdentificationMethod { kFilter, kOutputError, kMaxLikelihood };

// The methods, described once (as filter_kinds() describes the filters):
// what the service sizes, runs and reports follows from a method's row, not
// from switches on the method in several files.
struct IdentificationMethodInfo {
  IdentificationMethod method;
  std::string_view name;     // "filter", "oe", "ml": the API's short names
  std::string_view summary;  // what it is, in a line
  // Its estimate is the iterated filter's passes (else passes may only find
  // an optimiser's start: init_passes).
  bool iterated_filter;
  // An optimiser over the records: iterations, a cost, an EstimationResult.
  bool optimiser;
  // The optimiser's criterion runs a filter as the predictor (the filter
  // settings are the model of the noise, not only of a start).
  bool filter_predictor;
};

std::span<const IdentificationMethodInfo> identification_methods();
const IdentificationMethodInfo& identification_method_info(IdentificationMethod method);
const char* identification_method_name(IdentificationMethod method);
Result<IdentificationMethod> parse_identification_method(std::string_view name);

struct ParameterSettings {
  Eigen::VectorXd theta0;        // [ntheta] start (the value of a fixed parameter)
  Eigen::VectorXd lower, upper;  // [ntheta] bounds; -inf / +inf: none
  std::vector<bool> fixed;       // [ntheta] held at theta0
  std::vector<bool> log_scale;   // [ntheta] estimated as log(theta): needs a positive lower bound
};

// Bounds from the model's own (Model::theta_lower/upper) where none is given,
// nothing fixed, nothing log-scaled.
ParameterSettings default_parameters(const Model& model, Eigen::VectorXd theta0);

// Sizes, theta0 finite and within its bounds, lower <= upper, log-scaled
// parameters with a positive lower bound; errors name the parameter.
Status validate(const ParameterSettings& parameters, const Model& model);

// theta <-> solver coordinates phi, and d theta / d phi, for parameter i.
double to_solver(const ParameterSettings& p, Eigen::Index i, double theta);
double from_solver(const ParameterSettings& p, Eigen::Index i, double phi);
double theta_per_phi(const ParameterSettings& p, Eigen::Index i, double theta);

// One record of the system: its data (bound to the model) and where it starts.
struct Experiment {
  Dataset data;                    // bound to the model (bind_dataset)
  Eigen::VectorXd x0;              // [nx] the initial states, or the start of those estimated
  std::vector<bool> estimate_x0;   // [nx] empty: none estimated
  Eigen::ArrayXXd mask;            // [ny x N] 1 for a sample used, 0 for one excluded; empty: all used
};

Status validate(const Experiment& experiment, const Model& model, std::size_t index);

struct OptimizerSettings {
  int max_iterations = 200;
  double function_tolerance = 1e-14;   // relative change of the cost
  double gradient_tolerance = 1e-14;   // largest gradient entry, relative
  double parameter_tolerance = 1e-12;  // relative change of the unknowns
};

struct EstimationProgress {
  int iteration = 0;
  double cost = 0.0;
};

struct EstimationHooks {
  std::function<void(const EstimationProgress&)> progress;  // after every iteration
  std::stop_token stop;  // checked at every iteration (and evaluation): kCancelled
};

struct ExperimentResult {
  Eigen::VectorXd x0;              // [nx] the initial states (the estimate where estimated)
  Eigen::VectorXd x0_std;          // [nx] standard errors (0 where given)
  std::vector<bool> x0_estimated;  // [nx]
  Eigen::VectorXd t;               // [N]
  Eigen::MatrixXd y_measured;      // [ny x N]
  Eigen::MatrixXd y_model;         // [ny x N] the model's prediction (OE: simulated; ML: one step ahead)
  Eigen::MatrixXd residuals;       // [ny x N] normalised (see each method); 0 where masked out
  Eigen::ArrayXXd mask;            // [ny x N] as used (all ones when none was given)
  std::vector<OutputFit> fits;     // per output, over the samples used
  // Of the residuals over the samples where every output is used (ML: with
  // the one-step NIS).
  ResidualDiagnostics diagnostics;
};

// The fit of each output over the samples the mask [ny x N] uses.
Result<std::vector<OutputFit>> fits_over_mask(const Eigen::MatrixXd& y, const Eigen::MatrixXd& y_model,
                                              const Eigen::ArrayXXd& mask, const std::vector<std::string>& names);

// The diagnostics of an experiment's residuals over the samples where every
// output is used, against its inputs; `nis` [N] per sample when the method has one.
Result<ResidualDiagnostics> diagnose(const ExperimentResult& experiment, const Eigen::MatrixXd& inputs,
                                     const Eigen::VectorXd* nis = nullptr);

struct InformationCriteria {
  double log_likelihood = 0.0;   // ln L (ML: of the innovations; OE: of Gaussian residuals, docs/identification.md)
  int estimated_quantities = 0;  // k: free parameters, estimated initial states and noise levels
  double samples = 0.0;          // n: the scalar residuals (outputs x samples) the fit used
  double aic = 0.0;
  double aicc = 0.0;
  double bic = 0.0;
};

struct EstimationResult {
  std::vector<std::string> param_names;
  Eigen::VectorXd theta;             // [ntheta] the estimate
  Eigen::VectorXd theta_std;         // [ntheta] standard errors (0 for fixed; +inf where not identifiable)
  Eigen::VectorXd ci_lower, ci_upper;  // [ntheta] 95 % confidence intervals
  std::vector<bool> fixed;           // [ntheta]
  Eigen::MatrixXd covariance;        // [ntheta x ntheta] (zero rows and columns for fixed ones)
  Eigen::MatrixXd correlation;       // [ntheta x ntheta]
  std::vector<std::string> warnings;  // parameters that are not identifiable, bounds that are active
  double cost = 0.0;                 // the criterion at the estimate
  double sigma2 = 1.0;               // the residual variance the covariance is scaled by (1: noise known)
  std::string covariance_method;     // which covariance theta_std comes from, in words
  std::vector<double> cost_history;  // the criterion after each iteration
  int iterations = 0;
  int evaluations = 0;               // simulations (OE) or filter runs (ML) of the whole record set
  int jacobian_evaluations = 0;
  bool converged = false;
  std::string termination;           // the optimiser's reason for stopping
  std::string gradient;              // how the gradient was had: exact sensitivities, or central differences
  std::vector<ExperimentResult> experiments;
  // The likelihood at the estimate and the criteria that weigh it against the
  // number of quantities estimated, to compare models fitted to the same data
  // (set_information_criteria).
  InformationCriteria criteria;
};

// Sets `result`'s criteria from the log-likelihood ln L at its estimate, the
// number k of quantities estimated and the number n of scalar residuals:
// AIC = 2k - 2 ln L, AICc = AIC + 2k(k + 1)/(n - k - 1) (+inf when n <= k + 1),
// BIC = k ln n - 2 ln L.
void set_information_criteria(double log_likelihood, int estimated_quantities, double samples,
                              EstimationResult* result);

// P(chi-square(dof) >= x), in closed form for whole degrees of freedom: the
// p-value of a likelihood-ratio test. NaN for dof = 0.
double chi_square_survival(double x, unsigned dof);

// The parameters' part of an uncertainty over the unknowns (uncertainty.hpp):
// `columns` [ntheta] gives each parameter's index among the unknowns (-1:
// fixed). Fills theta_std, covariance, correlation, the 95 % intervals and
// the warnings of `result` (its theta set).
struct Uncertainty;
void set_parameter_uncertainty(const ParameterSettings& parameters, const Uncertainty& uncertainty,
                               const std::vector<Eigen::Index>& columns, EstimationResult* result);
// A warning for each free parameter that ended on a bound: the best fit may lie beyond it.
void warn_active_bounds(const ParameterSettings& parameters, EstimationResult* result);

}  // namespace riccati
