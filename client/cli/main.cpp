// riccati: the command line of the riccati estimation service.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "commands/commands.hpp"
#include "riccati/enum_names.hpp"

namespace {

using namespace riccati::cli;

// A job file (if any) with the flags over it.
bool settings_from(const std::string& config, const RunFlags& flags, RunSettings* out) {
  std::string error;
  if ((!config.empty() && !load_job_file(config, out, &error)) || !flags.apply(out, &error)) {
    std::fprintf(stderr, "riccati: %s\n", error.c_str());
    return false;
  }
  return true;
}

// Edit distance, for "did you mean".
std::size_t distance(const std::string& a, const std::string& b) {
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diagonal = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diagonal = up;
    }
  }
  return row[b.size()];
}

// The first word of the command line that is not a global option (or its
// value), when it names no command: "unknown command ...; did you mean ...?"
// rather than CLI11's "A subcommand is required". Empty: no such word.
std::string unknown_command(const CLI::App& app, int argc, char** argv) {
  for (int i = 1; i < argc; ++i) {
    const std::string word = argv[i];
    if (word.rfind("-", 0) == 0) {
      const CLI::Option* option = word.find('=') == std::string::npos ? app.get_option_no_throw(word) : nullptr;
      if (option != nullptr && option->get_expected_min() > 0) ++i;  // its value
      continue;
    }
    for (const CLI::App* sub : app.get_subcommands({})) {
      if (sub->check_name(word)) return "";
    }
    std::string nearest;
    std::size_t best = 3;  // at most two edits away
    for (const CLI::App* sub : app.get_subcommands({})) {
      const std::size_t d = distance(word, sub->get_name());
      if (d < best || (sub->get_name().rfind(word, 0) == 0 && nearest.empty())) {
        best = std::min(best, d);
        nearest = sub->get_name();
      }
    }
    return "unknown command \"" + word + "\"" + (nearest.empty() ? "" : "; did you mean \"" + nearest + "\"?") +
           " (riccati --help lists the commands)";
  }
  return "";
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"riccati: identification and filtering of continuous-time models with riccatid"};
  app.footer(
      "Exit status: 0 success; 1 the operation failed (job failed or cancelled, input refused); 2 usage error;\n"
      "3 riccatid unreachable; 4 not found; 130 interrupted (Ctrl-C while identify, validate or smooth waits:\n"
      "the job is cancelled).\n"
      "Connection settings come from the flags, else the environment (RICCATI_SERVER, RICCATI_TOKEN_FILE,\n"
      "RICCATI_TOKEN, RICCATI_CA, RICCATI_CERT, RICCATI_KEY, RICCATI_TLS, RICCATI_TLS_SERVER_NAME), else the\n"
      "config file (RICCATI_CONFIG, else ~/.config/riccati/client.yaml: server, token_file, ca, cert, key, tls,\n"
      "tls_server_name); the server defaults to 127.0.0.1:7531. The token is never a flag: it stays out of\n"
      "shell history.");
  app.require_subcommand(1);
  // Global flags are taken after the command too (riccati models --json):
  // what a command does not know falls through to here.
  app.fallthrough();
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

  auto* models = app.add_subcommand("models", "List the models (models show NAME: one in detail; add FILE, remove NAME, reload)");
  auto* models_show_cmd = models->add_subcommand("show", "Show one model (a text model: its equations and Jacobian sparsity)");
  std::string model_name;
  models_show_cmd->add_option("name", model_name, "Model name (a text model's revision: name@3)")->required();
  std::string model_file;
  auto* models_add_cmd = models->add_subcommand("add", "Upload a text model (YAML, docs/text-models.md)");
  models_add_cmd->add_option("file", model_file, "The model's YAML file")->required();
  auto* models_remove_cmd = models->add_subcommand("remove", "Remove a text model (jobs that use it keep it)");
  models_remove_cmd->add_option("name", model_name, "Model name")->required();
  auto* models_reload_cmd = models->add_subcommand(
      "reload", "Read riccatid's models directory again (as SIGHUP): new and changed plugins and text models");

  auto* data = app.add_subcommand("data", "Datasets: upload, list, show, delete");
  data->require_subcommand(1);
  UploadOptions upload;
  auto* upload_cmd = data->add_subcommand("upload", "Upload a CSV or MAT file");
  upload_cmd->add_option("file", upload.file, "CSV (header row) or MAT file (level 5, as MATLAB saves with -v7; variables T, U, Y)")->required();
  upload_cmd->add_option("--inputs", upload.inputs, "Input columns")->delimiter(',');
  upload_cmd->add_option("--outputs", upload.outputs, "Output columns")->delimiter(',')->required();
  auto* upload_time = upload_cmd->add_option("--time", upload.time, "Time column")->capture_default_str();
  upload_cmd->add_option("--ts", upload.sample_time, "Sample time in seconds, for a CSV file without a time column (t = k * ts)")
      ->check(CLI::PositiveNumber)
      ->excludes(upload_time);
  upload_cmd->add_option("--name", upload.name, "Name (default: the file name)");
  std::string upload_truth;
  upload_cmd->add_option("--truth", upload_truth,
                         "NAME=VALUE,...: the parameters the data was made with (a simulated reference dataset); "
                         "results on it show the error of each estimate");
  auto* data_list_cmd = data->add_subcommand("list", "List datasets");
  std::string data_id;
  auto* data_show_cmd = data->add_subcommand("show", "Show a dataset");
  data_show_cmd->add_option("id", data_id)->required();
  auto* data_delete_cmd = data->add_subcommand("delete", "Delete a dataset");
  data_delete_cmd->add_option("id", data_id)->required();

  std::string config;
  bool no_wait = false;
  auto* identify_cmd = app.add_subcommand(
      "identify", "Identify the parameters: the iterated filter, output error or maximum likelihood (--method); "
                  "waits and prints the result");
  identify_cmd->add_option("--config", config, "YAML job file (flags override it)");
  identify_cmd->add_flag("--no-wait", no_wait, "Print the job id and return at once");
  const RunFlags id_flags(identify_cmd, Command::kIdentify);

  JobsOptions jobs_options;
  auto* jobs = app.add_subcommand("jobs", "List jobs, oldest first: created (UTC), model, dataset, state, progress");
  jobs->add_option("--state", jobs_options.states,
                   "Only jobs in these states (repeat, or a comma-separated list): " +
                       riccati::api::enum_choice_list(*riccati::v1::JobState_descriptor()))
      ->delimiter(',');
  jobs->add_option("--model", jobs_options.model, "Only jobs of this model (name: any revision; name@3: that one)");
  jobs->add_option("--limit", jobs_options.limit, "At most this many jobs (then: the token of the next page)");
  jobs->add_option("--page-token", jobs_options.page_token, "The next page, from the token a --limit listing printed");
  auto* job = app.add_subcommand("job", "One job: show, watch, cancel, delete");
  job->require_subcommand(1);
  std::string job_id;
  auto* job_show_cmd = job->add_subcommand("show", "Show a job");
  job_show_cmd->add_option("id", job_id)->required();
  auto* job_watch_cmd = job->add_subcommand("watch", "Follow a job to its end");
  job_watch_cmd->add_option("id", job_id)->required();
  auto* job_cancel_cmd = job->add_subcommand("cancel", "Cancel a job");
  job_cancel_cmd->add_option("id", job_id)->required();
  auto* job_delete_cmd = job->add_subcommand("delete", "Delete an ended job and its result");
  job_delete_cmd->add_option("id", job_id)->required();

  auto* sessions_cmd = app.add_subcommand("sessions", "Filter sessions: list (the default), show, close, retune");
  std::string session_id;
  auto* sessions_list_cmd = sessions_cmd->add_subcommand("list", "List the sessions, on every instance");
  auto* session_show_cmd = sessions_cmd->add_subcommand("show", "Show a session: state, measurements, estimate");
  session_show_cmd->add_option("id", session_id)->required();
  auto* session_close_cmd = sessions_cmd->add_subcommand("close", "Close a session (its stream, if any, ends)");
  session_close_cmd->add_option("id", session_id)->required();
  auto* session_retune_cmd = sessions_cmd->add_subcommand(
      "retune", "Change a running session's noise settings between two measurements (the estimate is kept)");
  session_retune_cmd->add_option("id", session_id)->required();
  const RunFlags retune_flags(session_retune_cmd, Command::kRetune);

  std::string format = "table", output, truth_text;
  auto* result_cmd = app.add_subcommand("result", "A finished job's result");
  result_cmd->add_option("id", job_id)->required();
  result_cmd->add_option("--format", format, "table, json or csv (traces and model outputs)")->capture_default_str();
  result_cmd->add_option("--output,-o", output, "Write to this file");
  result_cmd->add_option("--truth", truth_text, "True parameters, to print the error (default: those the dataset declares, data upload --truth)");
  std::string export_path;
  result_cmd->add_option("--export", export_path,
                         "Write the result to FILE.csv, FILE.json or FILE.mat (the 1999 toolbox's layout: T, Theta, "
                         "Trace, X, Ymod, ...; validations T, Y, Ymod)")
      ->excludes("--output");

  CompareOptions compare_options;
  auto* compare_cmd = app.add_subcommand(
      "compare",
      "Output-error and likelihood fits side by side: log-likelihood, AIC, AICc, BIC, fit per output; a "
      "likelihood-ratio test for each nested pair; with --data, each fit also on one common validation record");
  compare_cmd->add_option("jobs", compare_options.ids, "Two or more jobs of --method oe or ml")->required()->expected(2, -1);
  compare_cmd->add_option("--data", compare_options.data,
                          "A common validation record (a dataset id, or a file to upload): each job's model is "
                          "simulated on it at its estimate (riccati validate), the fits side by side");
  compare_cmd->add_option("--horizon", compare_options.horizon,
                          "With --data: predict each sample K samples ahead with each job's filter and noise model "
                          "instead of simulating (as nlgreyest's compare(data, m1, m2, K))")
      ->check(CLI::Range(1u, 4294967295u))
      ->needs("--data");

  ValidateOptions val;
  auto* validate_cmd = app.add_subcommand("validate", "Simulate a model against measured data: the fit table");
  RunFlags val_flags(validate_cmd, Command::kValidate);
  val_flags.require("model");
  val_flags.require("data");
  validate_cmd->add_option("--params", val.params, "Identification job id, YAML file (theta: [...]) or list")
      ->required();

  StreamOptions st;
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
  stream_cmd->add_option("--session", st.session,
                         "Resume this session (kept with --keep, or whose stream broke): the file's rows after the "
                         "session's t are sent; its model and settings are the session's");
  stream_cmd->add_option("--live", st.live,
                         "Live view of the estimates on stderr: auto (when it is a terminal and the estimates go "
                         "elsewhere), always, never")
      ->check(CLI::IsMember({"auto", "always", "never"}))
      ->capture_default_str();
  const RunFlags st_flags(stream_cmd, Command::kStream);

  SmoothOptions sm;
  std::string sm_config;
  auto* smooth_cmd = app.add_subcommand(
      "smooth", "States and parameters given all the samples: the EKF or UKF forward, then the smoother back "
                "(waits and prints the smoothing table)");
  smooth_cmd->add_option("--config", sm_config, "YAML job file (flags override it)");
  smooth_cmd->add_option("--params", sm.params,
                         "Parameters to smooth with: an identification job id, a YAML file (theta: [...]) or a list "
                         "(default: theta0 of --config, else the model's)");
  smooth_cmd->add_option("--format", sm.format, "table, json or csv (every sample: smoothed, filtered, std)")
      ->check(CLI::IsMember({"table", "json", "csv"}))
      ->capture_default_str();
  smooth_cmd->add_option("--output,-o", sm.output, "Write to this file");
  const RunFlags sm_flags(smooth_cmd, Command::kSmooth);

  std::string settings_format = "table";
  auto* settings_cmd = app.add_subcommand(
      "settings", "Every request's settings: job-file key, flag, value, default and where each applies (no riccatid needed)");
  settings_cmd->add_option("--format", settings_format, "table, json or markdown")
      ->check(CLI::IsMember({"table", "json", "markdown"}))
      ->capture_default_str();

  SimulateOptions sim;
  auto* simulate_cmd = app.add_subcommand("simulate", "Model outputs for given inputs (CSV out)");
  RunFlags sim_flags(simulate_cmd, Command::kSimulate);
  sim_flags.require("model");
  simulate_cmd->add_option("--params", sim.params, "Job id, YAML file or list (default: the model's)");
  simulate_cmd->add_option("--inputs", sim.inputs_file, "CSV file with a time column and the inputs")->required();
  simulate_cmd->add_option("--input-columns", sim.input_columns, "Input columns (default: the model's names)")
      ->delimiter(',');
  simulate_cmd->add_option("--time", sim.time, "Time column")->capture_default_str();
  simulate_cmd->add_option("--x0", sim.x0,
                           "Initial state (default, as identify and validate: a state named as an output at that column's first value in the inputs file, others 0)");
  simulate_cmd->add_option("--output,-o", sim.output, "Write to this file");

  if (const std::string unknown = unknown_command(app, argc, argv); !unknown.empty()) {
    std::fprintf(stderr, "riccati: %s\n", unknown.c_str());
    return kExitUsage;
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? kExitOk : kExitUsage;
  }

  if (*settings_cmd) return settings_reference(settings_format);
  Connection connection;
  if (auto error = resolve_connection(connection_flags, [](const char* name) { return std::getenv(name); },
                                      &connection)) {
    std::fprintf(stderr, "riccati: %s\n", error->c_str());
    return kExitUsage;
  }
  Client client(connection, timeout, json);
  if (*health_cmd) return health(client, health_service);
  if (*models) {
    if (*models_show_cmd) return models_show(client, model_name);
    if (*models_add_cmd) return models_add(client, model_file);
    if (*models_remove_cmd) return models_remove(client, model_name);
    if (*models_reload_cmd) return models_reload(client);
    return models_list(client);
  }
  if (*upload_cmd) {
    std::string error;
    if (!upload_truth.empty() && !parse_named_list(upload_truth, &upload.truth, &error)) {
      std::fprintf(stderr, "riccati: --truth: %s\n", error.c_str());
      return kExitUsage;
    }
    return data_upload(client, upload);
  }
  if (*data_list_cmd) return data_list(client);
  if (*data_show_cmd) return data_show(client, data_id);
  if (*data_delete_cmd) return data_delete(client, data_id);
  if (*identify_cmd) {
    RunSettings s;
    if (!settings_from(config, id_flags, &s)) return kExitUsage;
    return identify(client, s, !no_wait);
  }
  if (*jobs) return jobs_list(client, jobs_options);
  if (*sessions_cmd) {
    if (*session_show_cmd) return session_show(client, session_id);
    if (*session_close_cmd) return session_close(client, session_id);
    if (*session_retune_cmd) {
      RunSettings s;
      if (!settings_from("", retune_flags, &s)) return kExitUsage;
      return session_retune(client, session_id, s);
    }
    (void)sessions_list_cmd;
    return sessions_list(client);
  }
  if (*job_show_cmd) return job_show(client, job_id);
  if (*job_watch_cmd) return job_watch(client, job_id);
  if (*job_cancel_cmd) return job_cancel(client, job_id);
  if (*job_delete_cmd) return job_delete(client, job_id);
  if (*result_cmd) {
    std::vector<double> truth;
    std::string error;
    if (!truth_text.empty() && !parse_list(truth_text, &truth, &error)) {
      std::fprintf(stderr, "riccati: --truth: %s\n", error.c_str());
      return kExitUsage;
    }
    if (!export_path.empty()) return result_export(client, job_id, export_path);
    return result(client, job_id, json && format == "table" ? "json" : format, output, truth);
  }
  if (*compare_cmd) return compare(client, compare_options);
  if (*validate_cmd) {
    if (!settings_from("", val_flags, &val.settings)) return kExitUsage;
    return validate(client, val);
  }
  if (*stream_cmd) {
    if (!settings_from(st_config, st_flags, &st.settings)) return kExitUsage;
    return stream(client, st);
  }
  if (*smooth_cmd) {
    if (!settings_from(sm_config, sm_flags, &sm.settings)) return kExitUsage;
    return smooth(client, sm);
  }
  if (*simulate_cmd) {
    if (!settings_from("", sim_flags, &sim.settings)) return kExitUsage;
    return simulate(client, sim);
  }
  return kExitUsage;
}
