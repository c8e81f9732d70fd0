// The `riccati` commands: each talks to riccatid through the API and prints
// a table (or JSON with --json), and returns a process exit code. One file
// per area: health.cpp, models.cpp, data.cpp, jobs.cpp (jobs and results),
// identify.cpp, validate.cpp, stream.cpp, simulate.cpp, smooth.cpp, compare.cpp.
#pragma once

#include <map>
#include <optional>
#include <string>
#include <vector>

#include "client.hpp"
#include "settings.hpp"

namespace riccati::cli {

// grpc.health.v1.Health/Check of `service` (empty: the daemon as a whole).
// Prints the serving status: SERVING exits 0; NOT_SERVING or UNKNOWN exit 1
// (the operation failed); a service the daemon does not know prints
// SERVICE_UNKNOWN and exits 4 (not found); riccatid unreachable exits 3. For
// container health checks and probes: no token is needed.
int health(Client& c, const std::string& service);

int models_list(Client& c);
int models_show(Client& c, const std::string& name);
// A text model (docs/text-models.md): stored for the caller's tenant.
int models_add(Client& c, const std::string& file);
int models_remove(Client& c, const std::string& name);
int models_reload(Client& c);
void print_text_model(const v1::ModelInfo& info);

struct UploadOptions {
  std::string file, name, time = "t";
  std::vector<std::string> inputs, outputs;
  double sample_time = 0.0;  // --ts: no time column, t = k * sample_time
  std::map<std::string, double> truth;  // --truth NAME=VALUE,...: the parameters the data was made with
};
int data_upload(Client& c, const UploadOptions& o, std::string* dataset_id = nullptr);
int data_list(Client& c);
int data_show(Client& c, const std::string& id);
int data_delete(Client& c, const std::string& id);
// Whether `path` is a file here (rather than the id of something riccatid keeps).
bool is_local_file(const std::string& path);
// The dataset `data` names: uploaded first when it is a local file, its
// columns named by `inputs` and `outputs`, or, when neither is given, by the
// names of `model`'s inputs and outputs. A file the tenant uploaded before
// (a dataset with the file's SHA-256 and the same input and output names)
// is not uploaded again: that dataset is used, and stderr says so.
int dataset_for(Client& c, const std::string& data, const std::vector<std::string>& inputs,
                const std::vector<std::string>& outputs, std::string* id, const std::string& model = "");

int identify(Client& c, const RunSettings& s, bool wait);
// `riccati compare JOB JOB...`: output-error and likelihood fits side by side
// (log-likelihood, AIC, AICc, BIC, fit per output; the lowest marked), and a
// likelihood-ratio test for each pair where one model is nested in the other
// (the same model, records and method; a parameter free in one and fixed in
// the other), as riccatid's CompareJobs answers. Jobs of other kinds, or fits
// of different outputs: riccatid refuses them (INVALID_ARGUMENT, exit 1).
struct CompareOptions {
  std::vector<std::string> ids;
  std::string data;             // a common validation record (dataset id or file): each job validated on it
  std::optional<unsigned> horizon;  // with data: K steps ahead instead of the simulation
};
int compare(Client& c, const CompareOptions& o);
// `riccati settings`: every request's settings from the proto's schema, as
// `format` says: table, json (GET /api/v1/schema's) or markdown (docs/settings.md).
int settings_reference(const std::string& format);
int sessions_list(Client& c);
int session_show(Client& c, const std::string& id);
int session_close(Client& c, const std::string& id);
// RetuneSession: the running session's Q and R (EKF, UKF) or V and W (the
// optimal filter) from `s`, the others unchanged; riccatid checks them.
int session_retune(Client& c, const std::string& id, const RunSettings& s);
// `riccati jobs`: the filters and the page (ListJobsRequest).
struct JobsOptions {
  std::vector<std::string> states;  // the API's names: queued, running, ...
  std::string model, page_token;
  uint32_t limit = 0;  // 0: all
};
int jobs_list(Client& c, const JobsOptions& o);
int job_show(Client& c, const std::string& id);
int job_watch(Client& c, const std::string& id);
int job_cancel(Client& c, const std::string& id);
int job_delete(Client& c, const std::string& id);
// What Ctrl-C (SIGINT) does to a watch.
enum class OnInterrupt {
  kStopWatching,  // the default action: the command ends, the job runs on (`job watch`)
  kCancelJob,     // the job is cancelled, and stderr says so ("cancelling job-...; cancelled"); exit 130.
                  // For the commands that submit a job and wait for it: no job is left running unseen.
};
// Follows a job to its end (a progress bar on a terminal); `last` is the job
// as it ended.
int watch_until_done(Client& c, const std::string& id, v1::Job* last,
                     OnInterrupt on_interrupt = OnInterrupt::kStopWatching);
int result(Client& c, const std::string& id, const std::string& format, const std::string& output,
           const std::vector<double>& truth);
// `riccati result JOB --export FILE`: by the file's extension, .csv (as
// --format csv), .json (as --format json) or .mat (mat_export.hpp).
int result_export(Client& c, const std::string& id, const std::string& path);

// `riccati validate`: model, data, x0, hold and integrator in `settings`.
struct ValidateOptions {
  RunSettings settings;
  std::string params;
};
int validate(Client& c, const ValidateOptions& o);
// Parameters from a finished identification job id, a YAML file with
// `theta: [...]` or a list of numbers. A job id goes into `spec` as it is
// when there is one; otherwise the job's result is fetched and its estimate
// taken: an iterated filter's as `estimate` (EstimateChoice) says, the mean
// over its last pass by default. `estimate` given without a job is an error.
bool resolve_parameters(Client& c, const std::string& params, std::optional<int> estimate, v1::ValidationSpec* spec,
                        std::vector<double>* theta, std::string* error);

// `riccati smooth`: model, data and the filter in `settings`; the
// parameters from `params` (as resolve_parameters reads them; empty: theta0
// of the job file, else the model's defaults).
struct SmoothOptions {
  RunSettings settings;
  std::string params, format = "table", output;
};
int smooth(Client& c, const SmoothOptions& o);

struct StreamOptions {
  RunSettings settings;
  std::string file, output, time = "t";
  double rate = 0.0;
  int batch = 1;
  bool full_covariance = false;
  bool keep = false;
  // Resume this session (kept with --keep, or whose stream broke): the rows
  // after its time t are sent, the session's settings stay as they are.
  std::string session;
  std::string live = "auto";  // the live view on stderr: auto (on a terminal), always, never
};
int stream(Client& c, const StreamOptions& o);

// `riccati simulate`: model, hold and integrator in `settings`.
struct SimulateOptions {
  RunSettings settings;
  std::string params, inputs_file, time = "t", output, x0;
  std::vector<std::string> input_columns;
};
int simulate(Client& c, const SimulateOptions& o);

}  // namespace riccati::cli
