// Jobs between the API and the engine: specs into settings, results both
// ways (a stored result or checkpoint is an encoded v1 result), and the job
// record as the API shows it.
#pragma once

#include "engine/estimation/estimate.hpp"
#include "engine/estimation/identification.hpp"
#include "engine/estimation/smoother.hpp"
#include "engine/estimation/validation.hpp"
#include "engine/models/model.hpp"
#include "riccati/v1/jobs.pb.h"
#include "store/store.hpp"

namespace riccati::service {

Result<IdentificationSettings> from_proto(const v1::IdentificationSpec& spec, const Model& model);
// Everything of a validation spec except where the parameters come from.
Result<ValidationSettings> from_proto(const v1::ValidationSpec& spec);

v1::IdentificationResult to_proto(const IdentificationResult& r);
// The inverse of to_proto (a stored result or checkpoint).
Result<IdentificationResult> from_proto(const v1::IdentificationResult& r);
v1::ValidationResult to_proto(const ValidationResult& r, const Eigen::VectorXd& theta);
v1::OutputFit to_proto(const OutputFit& fit);
v1::Diagnostics to_proto(const ResidualDiagnostics& d);

Result<SmootherSettings> from_proto(const v1::SmoothingSpec& spec, const Model& model);
v1::SmoothingResult to_proto(const SmootherResult& r, bool full_covariance);

// An output-error or likelihood result; experiment e's dataset is dataset_ids[e].
v1::EstimationResult to_proto(const EstimationResult& r, IdentificationMethod method,
                              const std::vector<std::string>& dataset_ids);

v1::JobState to_proto(JobState state);
// The job as the API shows it (its spec decoded from the store's bytes).
v1::Job to_proto(const JobRecord& job);

}  // namespace riccati::service
