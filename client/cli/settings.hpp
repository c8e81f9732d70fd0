// Run settings for `riccati identify` and `riccati stream`: from a YAML job
// file, then from flags (flags win), turned into API requests once the
// model's sizes are known.
//
// Job file keys (all optional; a flag of the same name overrides each):
//
//   model: two_tank
//   data: ds-... | path/to/file.csv
//   inputs: [F1, F2]
//   outputs: [h1, h2]
//   filter: ekf | ukf | optimal
//   passes: 10
//   x0: first | [0.4, 0.15]
//   theta0: [20, 20, 1, 1]
//   P0: 10 | [0, 0, 10, 10, 10, 10] | [[...], ...]   (scalar: all; list: diagonal; list of lists: full)
//   Q: 0 | [...] | [[...]]
//   R: 1e-3 | [...] | [[...]]
//   hold: zoh | foh
//   integrator: {kind: rk4, substeps: 10, rtol: 1e-8, atol: 1e-10}
//   inversion: cholesky | pinv
//   joseph: true
//   ukf: {weights: julier, alpha: 1, beta: 2, kappa: -3}
//   optimal:                           (the optimal filter's weights; it takes no Q and R)
//     V: [1e6, 1e6, 1e4, 1e6, 1e6]     (equations of motion, measured inputs, measured outputs)
//     W: [1e4, ..., 1e10]              (states and parameters; W^-1 is the process noise)
//     R0: [1e12, ..., 5e3]             (confidence in x0, theta0: P0 = R0^-1; instead of P0)
//     form: continuous | split-step
//     hold_outputs: false              (true: outputs held over a step, for strict real time)
//   first_sample: 0
//   end_sample: 0
//   truth: [10, 5, 0.0791, 0.1342]     (printed beside the estimates)
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "riccati/v1/jobs.pb.h"
#include "riccati/v1/models.pb.h"
#include "riccati/v1/sessions.pb.h"

namespace riccati::cli {

// A covariance as written: one value (all the diagonal), a list (the
// diagonal) or rows (the full matrix).
struct MatrixSetting {
  std::vector<std::vector<double>> rows;  // one row: scalar or diagonal
  bool full = false;
};

struct RunSettings {
  std::optional<std::string> model, data, filter, hold, integrator, inversion, weights;
  std::vector<std::string> inputs, outputs;
  std::optional<std::string> x0;  // "first" or comma-separated values
  std::optional<std::vector<double>> theta0, truth;
  std::optional<MatrixSetting> p0, q, r;
  std::optional<MatrixSetting> v, w, r0;  // the optimal filter
  std::optional<std::string> form;
  std::optional<bool> hold_outputs;
  std::optional<int> passes, substeps;
  std::optional<double> rtol, atol, alpha, beta, kappa;
  std::optional<bool> joseph;
  std::optional<long long> first_sample, end_sample;
};

// Reads a job file; errors name the key and what was expected.
bool load_job_file(const std::string& path, RunSettings* out, std::string* error);
// Overlays every setting `flags` has onto `base`.
void overlay(const RunSettings& flags, RunSettings* base);
// Parses "1,2,3" (a flag's list).
bool parse_list(const std::string& text, std::vector<double>* out, std::string* error);
MatrixSetting matrix_from_list(const std::vector<double>& values);

// Requests for the model `info`; errors name the setting at fault.
bool to_identification_spec(const RunSettings& s, const v1::ModelInfo& info, const std::string& dataset_id,
                            v1::IdentificationSpec* out, std::string* error);
bool to_session_request(const RunSettings& s, const v1::ModelInfo& info, v1::CreateSessionRequest* out,
                        std::string* error);
bool to_filter_settings(const RunSettings& s, const v1::ModelInfo& info, v1::FilterSettings* out, std::string* error);
bool to_initial_state(const std::string& x0, v1::InitialState* out, std::string* error);
bool to_integrator(const RunSettings& s, v1::IntegratorSettings* out, std::string* error);
bool to_hold(const std::optional<std::string>& hold, v1::HoldOrder* out, std::string* error);

}  // namespace riccati::cli
