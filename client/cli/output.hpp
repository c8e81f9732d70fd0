// What the commands print, apart from the commands: JSON, the tables of
// jobs, parameters and fits, the CSV of a result.
#pragma once

#include <google/protobuf/message.h>

#include <cstdint>
#include <string>
#include <vector>

#include "riccati/v1/jobs.pb.h"

namespace riccati::cli {

std::string to_json(const google::protobuf::Message& m);
// One number with a printf format ("%.3g").
std::string format(const char* fmt, double v);
// "a, b, c"
std::string join(const google::protobuf::RepeatedPtrField<std::string>& names);
double element(const v1::Matrix& m, uint32_t i, uint32_t j);

// "queued", "running", ... (the API's names).
std::string state_name(v1::JobState state);
// id, kind, state, model and progress on one line of `riccati jobs`.
std::string job_line(const v1::Job& job);

// The identified parameters with their initial values and std (and the
// error against `truth`, when it has one value per parameter).
std::string parameter_table(const v1::IdentificationResult& r, const std::vector<double>& initial,
                            const std::vector<double>& truth);
std::string fit_table(const v1::ValidationResult& r);
// `riccati result --format table`: the parameter table and the innovations
// of the last pass, or the fit table.
std::string result_table(const v1::JobResult& r, const v1::Job& job, const std::vector<double>& truth);
// `riccati result --format csv`: the traces, model outputs and innovations
// of an identification, or the measured and simulated outputs of a validation.
std::string result_csv(const v1::JobResult& r);

}  // namespace riccati::cli
