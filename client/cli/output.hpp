// What the commands print, apart from the commands: JSON, the tables of
// jobs, parameters and fits, the CSV of a result (the tables of output
// error, likelihood and smoothing results are in estimation_output.hpp).
#pragma once

#include <google/protobuf/message.h>

#include <nlohmann/json.hpp>

#include <cstdint>
#include <string>
#include <vector>

#include "estimation_output.hpp"
#include "riccati/v1/jobs.pb.h"

namespace riccati::cli {

// What --json prints: the API's JSON mapping (field names as in the .proto,
// enums by name, Timestamps as RFC 3339) with every field present, zeros and
// empty lists included, and 64-bit integers as numbers (not strings).
nlohmann::json json_of(const google::protobuf::Message& m);
std::string to_json(const google::protobuf::Message& m);
// Indented, as every command prints it.
std::string to_json(const nlohmann::json& j);
// One number with a printf format ("%.3g").
std::string format(const char* fmt, double v);
// A count and its noun, singular for 1: "1 state", "2 states"; `plural`
// when adding "s" is wrong ("passes").
std::string counted(unsigned long long n, const std::string& noun, const std::string& plural = "");
// "a, b, c"
std::string join(const google::protobuf::RepeatedPtrField<std::string>& names);
// "[0.4, 0.15]" (6 digits)
std::string values_list(const google::protobuf::RepeatedField<double>& values);
double element(const v1::Matrix& m, uint32_t i, uint32_t j);

// "queued", "running", ... (the API's names).
std::string state_name(v1::JobState state);
// "identification", "validation" or "smoothing".
std::string job_kind(const v1::Job& job);
// How far a job is: "pass 3/10", or the optimiser's "iteration 12, cost
// 0.0153" (OE and ML); empty before it starts.
std::string progress_text(const v1::JobProgress& p);
// "2026-11-24T13:20:08Z"; "-" when unset.
std::string utc_time(const google::protobuf::Timestamp& t);
// id, kind, state, created (UTC), model, dataset and progress on one line
// of `riccati jobs`, under job_header().
std::string job_header();
std::string job_line(const v1::Job& job);

// The identified parameters with their initial values and std (and the
// error against `truth`, when it has one value per parameter).
std::string parameter_table(const v1::IdentificationResult& r, const std::vector<double>& initial,
                            const std::vector<double>& truth);
// Per output: RMSE, fit %, VAF %, RRSE; each line after `indent`.
std::string fit_table(const google::protobuf::RepeatedPtrField<v1::OutputFit>& fits, const std::string& indent = "");
// A validation: where its parameters and initial states came from, and the fits.
std::string fit_table(const v1::ValidationResult& r);
// `riccati result --format table`: the parameter table and the innovations
// of the last pass, the fit table, the estimation table (OE, ML) or the
// smoothing table. `initial`: the parameters the job started from.
std::string result_table(const v1::JobResult& r, const std::vector<double>& initial, const std::vector<double>& truth,
                         const ModelNames& names);
// `riccati result --format csv` (columns named by column(), docs/results.md):
// an identification's t, states and parameters (the last pass's trace),
// y_model.o and innovation.o; a validation's t, y.o (measured), y_model.o
// (simulated) and residual.o (y - y_model); estimation_csv or smoothing_csv.
std::string result_csv(const v1::JobResult& r, const ModelNames& names);

}  // namespace riccati::cli
