// Run settings of `riccati identify`, `stream`, `validate`, `simulate` and
// `smooth`: from a YAML job file (identify, stream and smooth), then from
// flags (flags win), turned into API requests. Each setting is declared once,
// in the table in settings.cpp, which gives its job-file key, its flag, its
// help and its type; the job-file reader and the flags are made from it.
//
// The requests carry what the user gave and nothing more: riccatid checks
// sizes (a single value is Covariance.scalar, whatever the model's size),
// names (parameters, states, outputs), bounds and which settings apply to
// which filter and method, and its defaults stand for what was left out. The
// CLI checks only its own syntax. The choices of enum settings (filter, hold,
// integrator.kind, inversion, ukf.weights, optimal.form, method, estimate)
// come from the API's enums (riccati/enum_names.hpp, in the proto library):
// `riccati identify --help` lists them.
//
// Job file keys (all optional; the flag of the same name overrides each):
//
//   model: two_tank
//   data: ds-... | path/to/file.csv
//   inputs: [F1, F2]
//   outputs: [h1, h2]
//   filter: ekf
//   passes: 10
//   x0: first | [0.4, 0.15]
//   theta0: [20, 20, 1, 1]
//   P0: 10 | [0, 0, 10, 10, 10, 10] | [[...], ...]   (one value: the whole diagonal; list: diagonal; rows: full)
//   Q: 0 | [...] | [[...]]
//   R: 1e-3 | [...] | [[...]]
//   hold: zoh
//   integrator: {kind: rk4, substeps: 10, rtol: 1e-8, atol: 1e-10}   (or integrator: rk4)
//   inversion: cholesky
//   joseph: true
//   ukf: {weights: julier, alpha: 1, beta: 2, kappa: -3}
//   optimal:                           (the optimal filter's weights, instead of Q and R)
//     V: [1e6, 1e6, 1e4, 1e6, 1e6]     (equations of motion, measured inputs, measured outputs)
//     W: [1e4, ..., 1e10]              (states and parameters; W^-1 is the process noise)
//     R0: [1e12, ..., 5e3]             (confidence in x0, theta0: P0 = R0^-1; instead of P0)
//     form: continuous
//     hold_outputs: false              (true: outputs held over a step, for strict real time)
//   first_sample: 0
//   end_sample: 0
//   truth: [10, 5, 0.0791, 0.1342]     (printed beside the estimates)
//
// Output error and maximum likelihood (identify --method oe|ml); the lists
// take the flags' own texts:
//
//   method: oe                         (filter, the default; oe; ml)
//   init_passes: 2                     (passes of the iterated filter first: the optimiser's start)
//   bounds: [A1=1:100, "k1=0.01:"]     (NAME=LO:HI, either side empty: the model's bound)
//   fixed: [A2, k2=0.1342]             (NAME: at its theta0; NAME=VALUE)
//   log_scale: [k1, k2]
//   estimate_x0: all                   (or [h1, h2])
//   experiments: [ds-..., other.csv]   (more records: experiment 2, 3, ...)
//   exclude: ["100:200", "2@0:50"]     ([EXPERIMENT@]FIRST:END: samples FIRST .. END-1 left out)
//   output_limits: ["h1=:0.6"]         (NAME=LO:HI: samples at or beyond a limit left out)
//   estimation: {output_sigma: [0.005, 0.005], estimate_q: false, estimate_r: true, max_iterations: 200,
//                function_tolerance: 1e-14, gradient_tolerance: 1e-14, parameter_tolerance: 1e-12}
//
// smooth: which estimate of an iterated-filter job --params takes:
//
//   estimate: last-pass-mean           (or final)
#pragma once

#include <google/protobuf/descriptor.h>

#include <CLI/CLI.hpp>

#include <cstdint>
#include <deque>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "riccati/v1/jobs.pb.h"
#include "riccati/v1/models.pb.h"
#include "riccati/v1/sessions.pb.h"

namespace riccati::cli {

// NAME=LO:HI, a parameter's bounds or an output's limits; an empty side is
// none given.
struct NamedRange {
  std::string name;
  std::optional<double> lower, upper;
  bool operator==(const NamedRange&) const = default;
};

// NAME or NAME=VALUE: a parameter held at its theta0, or at VALUE.
struct NamedValue {
  std::string name;
  std::optional<double> value;
  bool operator==(const NamedValue&) const = default;
};

// [EXPERIMENT@]FIRST:END: samples FIRST .. END-1 (0-based) of experiment
// EXPERIMENT (1-based: 1 is --data, 2 on the --experiment datasets in order).
struct SampleSpan {
  std::uint64_t experiment = 1, first = 0, end = 0;
  bool operator==(const SampleSpan&) const = default;
};

// What was given; empty: not given. Enum settings hold the API enum's number.
struct RunSettings {
  std::optional<std::string> model, data;
  std::vector<std::string> inputs, outputs;
  std::optional<int> filter, hold, integrator, inversion, weights, form;
  std::optional<v1::InitialState> x0;
  std::optional<std::vector<double>> theta0, truth;
  std::optional<v1::Covariance> p0, q, r;
  std::optional<v1::Covariance> v, w, r0;  // the optimal filter's weights
  std::optional<bool> joseph, hold_outputs;
  std::optional<std::uint64_t> passes, substeps, first_sample, end_sample;
  std::optional<double> rtol, atol, alpha, beta, kappa;
  // Output error and maximum likelihood (identify --method oe|ml).
  std::optional<int> method;  // IdentificationMethod
  std::optional<std::uint64_t> init_passes, max_iterations;
  std::optional<std::vector<NamedRange>> bounds, output_limits;
  std::optional<std::vector<NamedValue>> fixed;
  std::optional<std::vector<SampleSpan>> exclude;
  std::vector<std::string> log_scale, estimate_x0, experiments;  // experiments: dataset ids or local files
  std::optional<std::vector<double>> output_sigma;
  std::optional<bool> estimate_q, estimate_r;
  std::optional<double> function_tolerance, gradient_tolerance, parameter_tolerance;
  // Which estimate of an identification job --params takes (EstimateChoice),
  // and the samples validate fits every initial state on.
  std::optional<int> estimate;
  std::optional<std::uint64_t> x0_samples;
};

// Reads a job file into `out`; errors name the file, the key and its line.
bool load_job_file(const std::string& path, RunSettings* out, std::string* error);

// The commands whose flags the settings table makes.
// kRetune: `sessions retune` (the noise settings a running session can change).
enum class Command : unsigned { kIdentify = 1, kStream = 2, kValidate = 4, kSimulate = 8, kSmooth = 16, kRetune = 32 };

// The flags of the settings that `command` takes, on `cmd`.
class RunFlags {
 public:
  RunFlags(CLI::App* cmd, Command command);
  ~RunFlags();
  RunFlags(const RunFlags&) = delete;  // CLI11 holds the addresses of its flags
  RunFlags& operator=(const RunFlags&) = delete;

  // Puts the flags given over `out` (read from a job file first, if any);
  // errors name the flag.
  bool apply(RunSettings* out, std::string* error) const;
  // Makes the flag of `key` required (for commands without a job file).
  void require(std::string_view key);

 private:
  struct Flag;
  std::deque<Flag> flags_;  // a deque: adding a flag moves none of the others
};

// Parses "1,2,3" (a flag's list).
bool parse_list(const std::string& text, std::vector<double>* out, std::string* error);
// Parses "A1=10,k1=0.08" (named values).
bool parse_named_list(const std::string& text, std::map<std::string, double>* out, std::string* error);

// What the flags' syntax cannot say alone: an --exclude of an experiment
// that is not given. Everything else is riccatid's to check.
bool check_identification(const RunSettings& s, std::string* error);

// Requests: the settings given, and x0 "first" when it was not.
// `more_datasets`: the ids of the experiments after the first (s.experiments
// uploaded where they are files), in order.
v1::IdentificationSpec to_identification_spec(const RunSettings& s, const std::string& dataset_id,
                                              const std::vector<std::string>& more_datasets = {});
v1::SmoothingSpec to_smoothing_spec(const RunSettings& s, const std::string& dataset_id);
v1::CreateSessionRequest to_session_request(const RunSettings& s);
v1::ValidationSpec to_validation_spec(const RunSettings& s, const std::string& dataset_id);
v1::FilterSettings to_filter_settings(const RunSettings& s);
std::optional<v1::IntegratorSettings> to_integrator(const RunSettings& s);  // nothing when none is given

// The value of enum `type` named `name`, or nothing with an error that
// lists the choices: "\"ZERO\" is unknown (zoh, foh)".
std::optional<int> parse_choice(const google::protobuf::EnumDescriptor& type, std::string_view name,
                                std::string* error);

}  // namespace riccati::cli
