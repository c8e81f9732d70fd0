// riccati: the command line of the riccati estimation service.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <cstdlib>

#include "commands.hpp"

namespace {

using namespace riccati::cli;

// Flags for every run setting, collected into a RunSettings (only the flags
// given, so that they override a job file and nothing else).
struct RunFlags {
  std::string model, data, filter, hold, integrator, inversion, weights, x0, theta0, truth, p0, q, r;
  std::string v, w, r0, form;
  bool hold_outputs = false;
  std::vector<std::string> inputs, outputs;
  int passes = 0, substeps = 0;
  double rtol = 0, atol = 0, alpha = 0, beta = 0, kappa = 0;
  bool no_joseph = false;
  long long first_sample = 0, end_sample = 0;
  std::map<std::string, CLI::Option*> given;

  void add(CLI::App* cmd, bool identification) {
    given["model"] = cmd->add_option("--model,-m", model, "Model name");
    given["inputs"] = cmd->add_option("--inputs", inputs, "Input columns, in the model's order")->delimiter(',');
    given["outputs"] = cmd->add_option("--outputs", outputs, "Output columns, in the model's order")->delimiter(',');
    given["filter"] = cmd->add_option("--filter", filter, "ekf, ukf or optimal");
    given["x0"] = cmd->add_option("--x0", x0, "Initial state: first (first measurement) or a list");
    given["theta0"] = cmd->add_option("--theta0", theta0, "Initial parameters (default: the model's)");
    given["p0"] = cmd->add_option("--p0", p0, "Initial variances of [x; theta] (one value: all)");
    given["q"] = cmd->add_option("--q", q, "Process noise intensities of [x; theta] (one value: all)");
    given["r"] = cmd->add_option("--r", r, "Measurement noise variances (one value: all)");
    given["hold"] = cmd->add_option("--hold", hold, "Input hold: zoh or foh");
    given["integrator"] = cmd->add_option("--integrator", integrator, "rk4, rk3, cvode-bdf, cvode-adams, arkode-erk");
    given["substeps"] = cmd->add_option("--substeps", substeps, "Fixed-step integrators: steps per sample");
    given["rtol"] = cmd->add_option("--rtol", rtol, "Adaptive integrators: relative tolerance");
    given["atol"] = cmd->add_option("--atol", atol, "Adaptive integrators: absolute tolerance");
    given["inversion"] = cmd->add_option("--inversion", inversion, "Gain solve: cholesky or pinv");
    given["no_joseph"] = cmd->add_flag("--no-joseph", no_joseph, "EKF: short covariance update");
    given["weights"] = cmd->add_option("--weights", weights, "UKF weights: julier or scaled");
    given["alpha"] = cmd->add_option("--alpha", alpha, "UKF scaled weights: alpha");
    given["beta"] = cmd->add_option("--beta", beta, "UKF scaled weights: beta");
    given["kappa"] = cmd->add_option("--kappa", kappa, "UKF kappa");
    given["v"] = cmd->add_option("--v", v, "Optimal filter: weights of the equations of motion, inputs, outputs");
    given["w"] = cmd->add_option("--w", w, "Optimal filter: weights of the states and parameters");
    given["r0"] = cmd->add_option("--r0", r0, "Optimal filter: confidence in x0 and theta0 (instead of --p0)");
    given["form"] = cmd->add_option("--form", form, "Optimal filter: continuous or split-step");
    given["hold_outputs"] =
        cmd->add_flag("--hold-outputs", hold_outputs, "Optimal filter: hold outputs over a step (strict real time)");
    if (identification) {
      given["data"] = cmd->add_option("--data,-d", data, "Dataset id, or a local CSV/MAT file to upload");
      given["passes"] = cmd->add_option("--passes", passes, "Passes over the data");
      given["first_sample"] = cmd->add_option("--first-sample", first_sample, "Trial: first sample (0-based)");
      given["end_sample"] = cmd->add_option("--end-sample", end_sample, "Trial: end sample (0: to the end)");
      given["truth"] = cmd->add_option("--truth", truth, "True parameters, to print the error");
    }
  }

  bool has(const std::string& key) const {
    auto it = given.find(key);
    return it != given.end() && it->second->count() > 0;
  }

  // The flags given, as settings; false with a message on a bad list.
  bool collect(RunSettings* s, std::string* error) const {
    auto list = [&](const std::string& key, const std::string& text, std::optional<std::vector<double>>* out) {
      if (!has(key)) return true;
      std::vector<double> values;
      if (!parse_list(text, &values, error)) {
        *error = "--" + key + ": " + *error;
        return false;
      }
      *out = values;
      return true;
    };
    auto matrix = [&](const std::string& key, const std::string& text, std::optional<MatrixSetting>* out) {
      std::optional<std::vector<double>> values;
      if (!list(key, text, &values)) return false;
      if (values) *out = matrix_from_list(*values);
      return true;
    };
    if (has("model")) s->model = model;
    if (has("data")) s->data = data;
    if (has("inputs")) s->inputs = inputs;
    if (has("outputs")) s->outputs = outputs;
    if (has("filter")) s->filter = filter;
    if (has("x0")) s->x0 = x0;
    if (has("hold")) s->hold = hold;
    if (has("integrator")) s->integrator = integrator;
    if (has("substeps")) s->substeps = substeps;
    if (has("rtol")) s->rtol = rtol;
    if (has("atol")) s->atol = atol;
    if (has("inversion")) s->inversion = inversion;
    if (has("no_joseph")) s->joseph = false;
    if (has("weights")) s->weights = weights;
    if (has("alpha")) s->alpha = alpha;
    if (has("beta")) s->beta = beta;
    if (has("kappa")) s->kappa = kappa;
    if (has("passes")) s->passes = passes;
    if (has("first_sample")) s->first_sample = first_sample;
    if (has("end_sample")) s->end_sample = end_sample;
    if (has("form")) s->form = form;
    if (has("hold_outputs")) s->hold_outputs = true;
    return list("theta0", theta0, &s->theta0) && list("truth", truth, &s->truth) && matrix("p0", p0, &s->p0) &&
           matrix("q", q, &s->q) && matrix("r", r, &s->r) && matrix("v", v, &s->v) && matrix("w", w, &s->w) &&
           matrix("r0", r0, &s->r0);
  }
};

// A job file (if any) with the flags over it.
bool settings_from(const std::string& config, const RunFlags& flags, RunSettings* out) {
  std::string error;
  if (!config.empty() && !load_job_file(config, out, &error)) {
    std::fprintf(stderr, "riccati: %s\n", error.c_str());
    return false;
  }
  RunSettings given;
  if (!flags.collect(&given, &error)) {
    std::fprintf(stderr, "riccati: %s\n", error.c_str());
    return false;
  }
  overlay(given, out);
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"riccati: identification and filtering of continuous-time models with riccatid"};
  app.footer(
      "Exit status: 0 success; 1 the operation failed (job failed or cancelled, input refused); 2 usage error;\n"
      "3 riccatid unreachable; 4 not found.\n"
      "Connection settings come from the flags, else the environment (RICCATI_SERVER, RICCATI_TOKEN_FILE,\n"
      "RICCATI_TOKEN, RICCATI_CA, RICCATI_CERT, RICCATI_KEY, RICCATI_TLS, RICCATI_TLS_SERVER_NAME), else the\n"
      "config file (RICCATI_CONFIG, else ~/.config/riccati/client.yaml: server, token_file, ca, cert, key, tls,\n"
      "tls_server_name); the server defaults to 127.0.0.1:7531. The token is never a flag: it stays out of\n"
      "shell history.");
  app.require_subcommand(1);
  ConnectionFlags connection_flags;
  bool json = false;
  double timeout = 30.0;
  app.add_option("--server", connection_flags.server, "riccatid address (host:port)");
  app.add_option("--token-file", connection_flags.token_file, "File holding the bearer token (mode 600)");
  app.add_option("--ca", connection_flags.ca, "PEM CA certificate to trust: connect with TLS");
  app.add_option("--cert", connection_flags.cert, "PEM client certificate (mutual TLS)");
  app.add_option("--key", connection_flags.key, "PEM client key (mutual TLS)");
  app.add_flag("--tls", connection_flags.tls, "Connect with TLS, trusting the system's CAs");
  app.add_option("--tls-server-name", connection_flags.tls_server_name,
                 "Name to check in the server's certificate (default: the host of --server)");
  app.add_flag("--json", json, "Machine-readable output (JSON)");
  app.add_option("--timeout", timeout, "Seconds to wait for each call")->capture_default_str();

  std::string health_service;
  auto* health_cmd = app.add_subcommand(
      "health", "Is riccatid serving? grpc.health.v1 Check: prints SERVING (exit 0) or the status (exit 1)");
  health_cmd->add_option("--service", health_service, "A service's name (default: the daemon as a whole)");

  auto* models = app.add_subcommand("models", "List the models (models show NAME: one in detail)");
  auto* models_show_cmd = models->add_subcommand("show", "Show one model");
  std::string model_name;
  models_show_cmd->add_option("name", model_name, "Model name")->required();

  auto* data = app.add_subcommand("data", "Datasets: upload, list, show, delete");
  data->require_subcommand(1);
  UploadOptions upload;
  auto* upload_cmd = data->add_subcommand("upload", "Upload a CSV or MAT file");
  upload_cmd->add_option("file", upload.file, "CSV (header row) or MAT file (level 5, as MATLAB saves with -v7; variables T, U, Y)")->required();
  upload_cmd->add_option("--inputs", upload.inputs, "Input columns")->delimiter(',');
  upload_cmd->add_option("--outputs", upload.outputs, "Output columns")->delimiter(',')->required();
  upload_cmd->add_option("--time", upload.time, "Time column")->capture_default_str();
  upload_cmd->add_option("--name", upload.name, "Name (default: the file name)");
  auto* data_list_cmd = data->add_subcommand("list", "List datasets");
  std::string data_id;
  auto* data_show_cmd = data->add_subcommand("show", "Show a dataset");
  data_show_cmd->add_option("id", data_id)->required();
  auto* data_delete_cmd = data->add_subcommand("delete", "Delete a dataset");
  data_delete_cmd->add_option("id", data_id)->required();

  std::string config;
  RunFlags id_flags;
  bool no_wait = false;
  auto* identify_cmd = app.add_subcommand("identify", "Multi-pass identification (waits and prints the parameters)");
  identify_cmd->add_option("--config", config, "YAML job file (flags override it)");
  identify_cmd->add_flag("--no-wait", no_wait, "Print the job id and return at once");
  id_flags.add(identify_cmd, true);

  auto* jobs = app.add_subcommand("jobs", "List jobs");
  auto* job = app.add_subcommand("job", "One job: show, watch, cancel");
  job->require_subcommand(1);
  std::string job_id;
  auto* job_show_cmd = job->add_subcommand("show", "Show a job");
  job_show_cmd->add_option("id", job_id)->required();
  auto* job_watch_cmd = job->add_subcommand("watch", "Follow a job to its end");
  job_watch_cmd->add_option("id", job_id)->required();
  auto* job_cancel_cmd = job->add_subcommand("cancel", "Cancel a job");
  job_cancel_cmd->add_option("id", job_id)->required();

  std::string format = "table", output, truth_text;
  auto* result_cmd = app.add_subcommand("result", "A finished job's result");
  result_cmd->add_option("id", job_id)->required();
  result_cmd->add_option("--format", format, "table, json or csv (traces and model outputs)")->capture_default_str();
  result_cmd->add_option("--output,-o", output, "Write to this file");
  result_cmd->add_option("--truth", truth_text, "True parameters, to print the error");

  ValidateOptions val;
  auto* validate_cmd = app.add_subcommand("validate", "Simulate a model against measured data: the fit table");
  validate_cmd->add_option("--model,-m", val.model, "Model name")->required();
  validate_cmd->add_option("--params", val.params, "Identification job id, YAML file (theta: [...]) or list")
      ->required();
  validate_cmd->add_option("--data,-d", val.data, "Dataset id, or a local file to upload")->required();
  validate_cmd->add_option("--inputs", val.inputs, "Input columns (for a local file)")->delimiter(',');
  validate_cmd->add_option("--outputs", val.outputs, "Output columns (for a local file)")->delimiter(',');
  validate_cmd->add_option("--x0", val.x0, "Initial state: first or a list")->capture_default_str();
  validate_cmd->add_option("--hold", val.hold, "Input hold: zoh or foh");
  validate_cmd->add_option("--integrator", val.integrator, "Integrator")->capture_default_str();
  validate_cmd->add_option("--substeps", val.substeps, "Fixed-step integrators: steps per sample")
      ->capture_default_str();

  StreamOptions st;
  RunFlags st_flags;
  std::string st_config;
  auto* stream_cmd = app.add_subcommand("stream", "Replay a recorded CSV file into a filter session, as a rig would");
  stream_cmd->add_option("--data,-d", st.file, "CSV file to replay")->required();
  stream_cmd->add_option("--config", st_config, "YAML job file with the filter settings");
  stream_cmd->add_option("--rate", st.rate, "Measurements per second (0: as fast as possible)")->capture_default_str();
  stream_cmd->add_option("--batch", st.batch, "Measurements per message")->capture_default_str();
  stream_cmd->add_option("--output,-o", st.output, "Write the estimates (CSV) to this file");
  stream_cmd->add_option("--time", st.time, "Time column")->capture_default_str();
  stream_cmd->add_flag("--full-covariance", st.full_covariance, "Ask for the full covariance");
  stream_cmd->add_flag("--keep", st.keep, "Keep the session open at the end");
  stream_cmd->add_option("--live", st.live,
                         "Live view of the estimates on stderr: auto (when it is a terminal and the estimates go "
                         "elsewhere), always, never")
      ->check(CLI::IsMember({"auto", "always", "never"}))
      ->capture_default_str();
  st_flags.add(stream_cmd, false);

  SimulateOptions sim;
  auto* simulate_cmd = app.add_subcommand("simulate", "Model outputs for given inputs (CSV out)");
  simulate_cmd->add_option("--model,-m", sim.model, "Model name")->required();
  simulate_cmd->add_option("--params", sim.params, "Job id, YAML file or list (default: the model's)");
  simulate_cmd->add_option("--inputs", sim.inputs_file, "CSV file with a time column and the inputs")->required();
  simulate_cmd->add_option("--input-columns", sim.input_columns, "Input columns (default: the model's names)")
      ->delimiter(',');
  simulate_cmd->add_option("--time", sim.time, "Time column")->capture_default_str();
  simulate_cmd->add_option("--x0", sim.x0, "Initial state (default: zeros)");
  simulate_cmd->add_option("--hold", sim.hold, "Input hold: zoh or foh");
  simulate_cmd->add_option("--integrator", sim.integrator, "Integrator")->capture_default_str();
  simulate_cmd->add_option("--substeps", sim.substeps, "Steps per sample")->capture_default_str();
  simulate_cmd->add_option("--output,-o", sim.output, "Write to this file");

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? kExitOk : kExitUsage;
  }

  Connection connection;
  if (auto error = resolve_connection(connection_flags, [](const char* name) { return std::getenv(name); },
                                      &connection)) {
    std::fprintf(stderr, "riccati: %s\n", error->c_str());
    return kExitUsage;
  }
  Client client(connection, timeout, json);
  if (*health_cmd) return health(client, health_service);
  if (*models) return *models_show_cmd ? models_show(client, model_name) : models_list(client);
  if (*upload_cmd) return data_upload(client, upload);
  if (*data_list_cmd) return data_list(client);
  if (*data_show_cmd) return data_show(client, data_id);
  if (*data_delete_cmd) return data_delete(client, data_id);
  if (*identify_cmd) {
    RunSettings s;
    if (!settings_from(config, id_flags, &s)) return kExitUsage;
    return identify(client, s, !no_wait);
  }
  if (*jobs) return jobs_list(client);
  if (*job_show_cmd) return job_show(client, job_id);
  if (*job_watch_cmd) return job_watch(client, job_id);
  if (*job_cancel_cmd) return job_cancel(client, job_id);
  if (*result_cmd) {
    std::vector<double> truth;
    std::string error;
    if (!truth_text.empty() && !parse_list(truth_text, &truth, &error)) {
      std::fprintf(stderr, "riccati: --truth: %s\n", error.c_str());
      return kExitUsage;
    }
    return result(client, job_id, format, output, truth);
  }
  if (*validate_cmd) return validate(client, val);
  if (*stream_cmd) {
    if (!settings_from(st_config, st_flags, &st.settings)) return kExitUsage;
    return stream(client, st);
  }
  if (*simulate_cmd) return simulate(client, sim);
  return kExitUsage;
}
