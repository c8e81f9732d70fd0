// Run settings of `riccati identify`, `stream`, `validate`, `simulate`,
// `smooth` and `sessions retune`: from a YAML job file (identify, stream and
// smooth), then from flags (flags win), turned into API requests.
//
// The settings of the requests are the proto's (riccati.v1.setting on the
// request's fields, read by riccati/settings_schema.hpp): a command's flags
// are its request's settings, with their flags, help, defaults and where
// they apply taken from there, so a field added to the proto with the
// option is a flag and a job-file key with no change here. What only the
// CLI has (where the data come from, the columns, the truth to print, more
// experiments and their masks) is the small table in settings.cpp.
//
// The requests carry what the user gave and nothing more: riccatid checks
// sizes, names, bounds and which settings apply to which filter and method,
// and its defaults stand for what was left out. The CLI checks only its own
// syntax.
//
// A job file is the request in YAML: a key is a setting's path in the
// request (`filter.q`, `estimation.output_sigma`), and a map groups keys
// (`filter: {kind: ukf, q: 0}`); the filter's settings may leave out
// `filter.`, and the keys of earlier job files stay (P0, Q, R, x0, joseph,
// estimate_x0, estimation.estimate_q/_r). A key that another command's
// request takes is left for it (one file serves identify, stream and smooth).
//
//   model: two_tank                    (the CLI's own keys)
//   data: ds-... | path/to/file.csv
//   inputs: [F1, F2]
//   outputs: [h1, h2]
//   truth: [10, 5, 0.0791, 0.1342]     (printed beside the estimates)
//   experiments: [ds-..., other.csv]   (more records: experiment 2, 3, ...)
//   exclude: ["100:200", "2@0:50"]     ([EXPERIMENT@]FIRST:END: samples FIRST .. END-1 left out)
//   output_limits: ["h1=:0.6"]         (NAME=LO:HI: samples at or beyond a limit left out)
//
//   filter: ekf                        (the request's settings: `riccati identify --help` lists them)
//   passes: 10
//   x0: first | [0.4, 0.15]
//   theta0: [20, 20, 1, 1]
//   P0: 10 | [0, 0, 10, 10, 10, 10] | [[...], ...]   (one value: the whole diagonal; list: diagonal; rows: full)
//   R: 1e-3
//   integrator: {kind: rk4, substeps: 10}
//   method: oe
//   bounds: [A1=1:100, "k1=0.01:"]
//   estimation: {output_sigma: [0.005, 0.005], max_iterations: 200}
#pragma once

#include <google/protobuf/descriptor.h>

#include <CLI/CLI.hpp>
#include <yaml-cpp/yaml.h>

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

// What was given; empty: not given.
struct RunSettings {
  // The CLI's own: where the data come from and what to print.
  std::optional<std::string> model, data;
  std::vector<std::string> inputs, outputs;
  std::optional<std::vector<double>> truth;
  std::vector<std::string> experiments;  // dataset ids or local files
  std::optional<std::vector<NamedRange>> output_limits;
  std::optional<std::vector<SampleSpan>> exclude;
  // The requests' settings given, by flag ("--q": filter.q of a job, q of a
  // retuning), as written (a flag's text read as a job file's value).
  std::map<std::string, YAML::Node> given;

  bool has(std::string_view flag) const { return given.count(std::string(flag)) > 0; }
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

// The settings given that `request` takes, written into it (the request's
// own fields, model and ids, are the caller's).
void fill_request(const RunSettings& s, google::protobuf::Message* request);

// Requests: the settings given, and x0 "first" when it was not.
// `more_datasets`: the ids of the experiments after the first (s.experiments
// uploaded where they are files), in order.
v1::IdentificationSpec to_identification_spec(const RunSettings& s, const std::string& dataset_id,
                                              const std::vector<std::string>& more_datasets = {});
v1::SmoothingSpec to_smoothing_spec(const RunSettings& s, const std::string& dataset_id);
v1::CreateSessionRequest to_session_request(const RunSettings& s);
v1::ValidationSpec to_validation_spec(const RunSettings& s, const std::string& dataset_id);
v1::SimulateRequest to_simulate_request(const RunSettings& s);
v1::RetuneSessionRequest to_retune_request(const RunSettings& s, const std::string& session_id);
// --estimate (which estimate of a job --params takes), an EstimateChoice
// number; nothing when not given.
std::optional<int> estimate_choice(const RunSettings& s);

// A message of riccatid's with each request setting it names by its path
// ("filter.r is required") followed by the flag that sets it: "filter.r
// (--r) is required". Messages name the API's fields; the CLI's user types flags.
std::string with_flags(const std::string& message);

// The value of enum `type` named `name`, or nothing with an error that
// lists the choices: "\"ZERO\" is unknown (zoh, foh)".
std::optional<int> parse_choice(const google::protobuf::EnumDescriptor& type, std::string_view name,
                                std::string* error);

}  // namespace riccati::cli
