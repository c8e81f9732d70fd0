// An identification as a job runs it: the IdentificationSpec checked against
// the model (and, at submit, against its datasets' records), so that a job
// that is accepted can run, and the experiments made from the loaded data
// when it does. Every field is checked here, at submit: names of parameters,
// states and outputs, bounds, fixed values, log scales, sample ranges, and
// which settings apply to which method.
#pragma once

#include <string>
#include <vector>

#include "engine/estimation/estimate.hpp"
#include "engine/estimation/identification.hpp"
#include "engine/estimation/max_likelihood.hpp"
#include "engine/estimation/output_error.hpp"
#include "engine/models/model.hpp"
#include "riccati/v1/jobs.pb.h"
#include "store/store.hpp"

namespace riccati::service {

// One record as the spec gives it; the data come when the job runs.
struct ExperimentSpec {
  std::string dataset_id;
  InitialState mode = InitialState::kGiven;
  Eigen::VectorXd x0;              // [nx], or empty with the first measurement
  std::vector<bool> estimate_x0;   // [nx]
  v1::SampleMask mask;
};

struct IdentificationJob {
  IdentificationMethod method = IdentificationMethod::kFilter;
  // The iterated filter (its passes; for OE and ML, init_passes of it first).
  IdentificationSettings filter;
  int init_passes = 0;
  ParameterSettings parameters;  // theta0, bounds, fixed, log scales
  std::vector<ExperimentSpec> experiments;
  OutputErrorSettings output_error;     // parameters set from `parameters` when run
  MaxLikelihoodSettings max_likelihood;  // likewise
};

// The spec against the model; errors name the field.
Result<IdentificationJob> identification_from_proto(const v1::IdentificationSpec& spec, const Model& model);

// What needs the datasets' records: each experiment's dataset (records[e])
// has the samples its mask and the trial range name, and the outputs its
// "first measurement" takes.
// The dataset's input and output columns against the model's (their counts,
// as bind_dataset() needs them; names are matched, or taken by position, when
// the job runs): INVALID_ARGUMENT naming both, so a mismatch is refused at
// submit instead of failing the job. Every submit (identification, smoothing,
// validation) checks it.
Status dataset_fits_model(const DatasetRecord& record, const Model& model);

Status check_against_datasets(const IdentificationJob& job, const std::vector<DatasetRecord>& records,
                              const Model& model);

// A job's result as estimated at submit: its doubles' bytes, what makes
// them ("650 passes x 4 parameters x 50000 samples"), and what would make
// it smaller, for the message that refuses it.
struct ResultSize {
  double bytes = 0;
  std::string what;
  std::string smaller;
};

// What a result holds besides its doubles: fields' tags and lengths,
// names, warnings, a termination message. Added to every job's estimate,
// with kResultBytesPerName for each name of the model (a warning or a test's
// line may name each).
inline constexpr double kFixedResultBytes = 64 * 1024;
inline constexpr double kResultBytesPerName = 512;

// An identification's result (job_convert.cpp's to_proto): each filter pass's
// parameter trace, the last pass's state trace and outputs; for output error
// and maximum likelihood, each experiment's outputs and residuals.
ResultSize estimated_result_size(const IdentificationJob& job, const std::vector<DatasetRecord>& records,
                                 const Model& model);

// The engine's experiment from its spec and its data bound to the model.
Result<Experiment> make_experiment(const ExperimentSpec& spec, const Dataset& bound, const Model& model);

// The mask [ny x N] a SampleMask makes of the bound data (empty when it
// leaves nothing out).
Result<Eigen::ArrayXXd> make_mask(const v1::SampleMask& mask, const Dataset& bound, const Model& model);

// Which states an InitialState's `estimate` names ("all", or names) [nx];
// errors name `field`.
Result<std::vector<bool>> estimated_states(const v1::InitialState& initial, const Model& model,
                                           const std::string& field);

// The parameter names of `model`, for messages: "A1, A2, k1, k2".
std::string parameter_list(const Model& model);

}  // namespace riccati::service
