// The CLI's job files and flags, turned into API requests, and the choices
// of enum settings from the API's descriptors (no daemon).
#include <gtest/gtest.h>
#include <google/protobuf/text_format.h>
#include <google/protobuf/util/message_differencer.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <sstream>
#include <unistd.h>

#include "commands/commands.hpp"
#include "connection.hpp"
#include "riccati/enum_names.hpp"
#include "output.hpp"
#include "settings.hpp"

namespace riccati::cli {
namespace {

using google::protobuf::EnumDescriptor;

std::string write(const std::string& name, const std::string& text) {
  const auto path = std::filesystem::temp_directory_path() / name;
  std::ofstream(path) << text;
  return path.string();
}

template <typename Message>
Message parse_text(const std::string& text) {
  Message m;
  EXPECT_TRUE(google::protobuf::TextFormat::ParseFromString(text, &m)) << text;
  return m;
}

::testing::AssertionResult SameMessage(const google::protobuf::Message& a, const google::protobuf::Message& b) {
  std::string difference;
  google::protobuf::util::MessageDifferencer differencer;
  differencer.ReportDifferencesToString(&difference);
  if (differencer.Compare(a, b)) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << difference;
}

// The settings from `args` given to `riccati <command>`, over `base`.
bool from_flags(Command command, const std::string& args, RunSettings* base, std::string* error) {
  CLI::App app;
  CLI::App* cmd = app.add_subcommand("command");
  const RunFlags flags(cmd, command);
  app.parse("command " + args, false);
  return flags.apply(base, error);
}

RunSettings from_job_file(const std::string& name, const std::string& text) {
  RunSettings s;
  std::string error;
  EXPECT_TRUE(load_job_file(write(name, text), &s, &error)) << error;
  return s;
}

// ------------------------------------------------------------ enum choices

// The names users write today, derived from the proto's values.
TEST(EnumChoices, DerivedFromTheValueNamesOrTheirShortName) {
  using Names = std::vector<std::string>;
  EXPECT_EQ(api::enum_choice_names(*v1::FilterKind_descriptor()), (Names{"ekf", "ukf", "optimal"}));
  EXPECT_EQ(api::enum_choice_names(*v1::HoldOrder_descriptor()), (Names{"zoh", "foh"}));
  EXPECT_EQ(api::enum_choice_names(*v1::IntegratorKind_descriptor()),
            (Names{"rk4", "rk3", "cvode-bdf", "cvode-adams", "arkode-erk"}));
  EXPECT_EQ(api::enum_choice_names(*v1::GainInversion_descriptor()), (Names{"cholesky", "pinv"}));
  EXPECT_EQ(api::enum_choice_names(*v1::SigmaWeights_descriptor()), (Names{"julier", "scaled"}));
  EXPECT_EQ(api::enum_choice_names(*v1::OptimalForm_descriptor()), (Names{"continuous", "split-step"}));
}

TEST(EnumChoices, NamesReadBackAsTheirValues) {
  const std::vector<std::pair<const EnumDescriptor*, int>> values = {
      {v1::HoldOrder_descriptor(), v1::HOLD_ORDER_ZERO},
      {v1::GainInversion_descriptor(), v1::GAIN_INVERSION_PSEUDO_INVERSE},
      {v1::IntegratorKind_descriptor(), v1::INTEGRATOR_KIND_CVODE_BDF},
      {v1::OptimalForm_descriptor(), v1::OPTIMAL_FORM_SPLIT_STEP},
  };
  std::vector<std::string> names;
  for (const auto& [type, number] : values) {
    const std::string name = api::enum_value_name(*type->FindValueByNumber(number));
    names.push_back(name);
    std::string error;
    EXPECT_EQ(parse_choice(*type, name, &error), number) << name << ": " << error;
  }
  EXPECT_EQ(names, (std::vector<std::string>{"zoh", "pinv", "cvode-bdf", "split-step"}));
  std::string error;
  EXPECT_EQ(parse_choice(*v1::HoldOrder_descriptor(), "unspecified", &error), std::nullopt);  // no choice
  EXPECT_EQ(parse_choice(*v1::HoldOrder_descriptor(), "ZERO", &error), std::nullopt);
  EXPECT_EQ(error, "\"ZERO\" is unknown (zoh, foh)");
}

// `riccati <args>` with nowhere to connect to; stdout and stderr together.
struct CliRun {
  int exit_code;
  std::string out;
};
CliRun riccati(const std::string& args) {
  const std::string command = "HOME=" + std::filesystem::temp_directory_path().string() + " " + RICCATI_CLI_BIN +
                              " --server 127.0.0.1:1 --timeout 1 " + args + " 2>&1";
  CliRun run{0, ""};
  std::FILE* pipe = popen(command.c_str(), "r");
  std::array<char, 4096> buffer;
  std::size_t n;
  while ((n = std::fread(buffer.data(), 1, buffer.size(), pipe)) > 0) run.out.append(buffer.data(), n);
  const int status = pclose(pipe);
  run.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return run;
}

// The names in the last "(a, b, c)" of the line of `text` that has `flag`.
std::vector<std::string> listed_after(const std::string& text, const std::string& flag) {
  std::istringstream lines(text);
  for (std::string line; std::getline(lines, line);) {
    if (line.find(flag) == std::string::npos) continue;
    const std::size_t open = line.rfind('(');
    const std::size_t close = line.rfind(')');
    if (open == std::string::npos || close < open) return {};
    std::vector<std::string> names;
    std::istringstream list(line.substr(open + 1, close - open - 1));
    for (std::string name; std::getline(list, name, ',');) names.push_back(name.substr(name.find_first_not_of(' ')));
    return names;
  }
  return {};
}

// Every value of the enum in the proto but the unspecified one, by name.
std::vector<std::string> values_of(const EnumDescriptor& type) {
  std::vector<std::string> names;
  for (int i = 0; i < type.value_count(); ++i) {
    if (type.value(i)->number() != 0) names.push_back(api::enum_value_name(*type.value(i)));
  }
  return names;
}

// A kind added to the proto reaches --help and the errors with no change to
// the CLI: both list what the descriptor has.
TEST(EnumChoices, HelpAndErrorsListTheValuesOfTheDescriptor) {
  const CliRun help = riccati("identify --help");
  ASSERT_EQ(help.exit_code, 0) << help.out;
  for (const auto& [flag, type] : {std::pair{"--filter ", v1::FilterKind_descriptor()},
                                   std::pair{"--integrator ", v1::IntegratorKind_descriptor()}}) {
    const std::vector<std::string> offered = listed_after(help.out, flag);
    EXPECT_EQ(offered, values_of(*type)) << help.out;
    EXPECT_EQ(offered.size(), static_cast<std::size_t>(type->value_count() - 1));
  }

  CliRun refused = riccati("identify --model two_tank --data ds-1 --filter nosuch");
  EXPECT_EQ(refused.exit_code, 2) << refused.out;
  EXPECT_NE(refused.out.find("--filter: \"nosuch\" is unknown ("), std::string::npos) << refused.out;
  EXPECT_EQ(listed_after(refused.out, "--filter"), values_of(*v1::FilterKind_descriptor())) << refused.out;

  refused = riccati("stream --model two_tank --data x.csv --integrator euler");
  EXPECT_EQ(refused.exit_code, 2) << refused.out;
  EXPECT_EQ(listed_after(refused.out, "--integrator: \"euler\" is unknown"),
            values_of(*v1::IntegratorKind_descriptor()))
      << refused.out;

  const std::string job = write("riccati-job-kind.yaml", "model: two_tank\n\nfilter: nosuch\n");
  refused = riccati("identify --config " + job + " --data ds-1");
  EXPECT_EQ(refused.exit_code, 2) << refused.out;
  EXPECT_EQ(listed_after(refused.out, "key \"filter\" (line 3): \"nosuch\" is unknown"),
            values_of(*v1::FilterKind_descriptor()))
      << refused.out;
}

// ------------------------------------------------------------ settings

TEST(JobFile, ScalarsListsAndRowsBecomeCovariancesAsGiven) {
  const RunSettings s = from_job_file(
      "riccati-job-1.yaml",
      "model: two_tank\nfilter: ukf\npasses: 10\nx0: first\ntheta0: [20, 20, 1, 1]\n"
      "P0: [0, 0, 10, 10, 10, 10]\nQ: 0\nR: [[1e-3, 1e-4], [1e-4, 2e-3]]\n"
      "integrator: {kind: cvode-bdf, rtol: 1e-9}\nukf: {weights: scaled, alpha: 0.5}\n");
  EXPECT_TRUE(SameMessage(to_identification_spec(s, "ds-1"), parse_text<v1::IdentificationSpec>(R"pb(
    model: "two_tank"
    dataset_id: "ds-1"
    filter {
      kind: FILTER_KIND_UKF
      integrator { kind: INTEGRATOR_KIND_CVODE_BDF rtol: 1e-9 }
      q { scalar: 0 }
      r { full { rows: 2 cols: 2 values: [ 1e-3, 1e-4, 1e-4, 2e-3 ] } }
      ukf { weights: SIGMA_WEIGHTS_SCALED alpha: 0.5 }
    }
    initial_state { first_measurement: true }
    theta0: [ 20, 20, 1, 1 ]
    p0 { diagonal { values: [ 0, 0, 10, 10, 10, 10 ] } }
    passes: 10
  )pb")));
}

// What was not given is not sent: riccatid's defaults stand, and riccatid
// alone says which settings a filter takes and what sizes they have.
TEST(JobFile, NothingIsAddedToWhatWasGiven) {
  RunSettings s;
  s.model = "two_tank";
  EXPECT_TRUE(SameMessage(to_identification_spec(s, "ds-1"), parse_text<v1::IdentificationSpec>(R"pb(
    model: "two_tank" dataset_id: "ds-1" filter {} initial_state { first_measurement: true }
  )pb")));
  // The optimal filter's weights with the EKF's R, for a model of any size: sent as they are.
  const RunSettings mixed = from_job_file("riccati-job-mixed.yaml",
                                          "model: two_tank\nR: 1e-3\nP0: 1\noptimal: {V: 1e6, W: [1, 2, 3]}\n");
  EXPECT_TRUE(SameMessage(to_session_request(mixed), parse_text<v1::CreateSessionRequest>(R"pb(
    model: "two_tank"
    filter { r { scalar: 1e-3 } optimal { v { scalar: 1e6 } w { diagonal { values: [ 1, 2, 3 ] } } } }
    initial_state { first_measurement: true }
    p0 { scalar: 1 }
  )pb")));
}

TEST(JobFile, TheOptimalFiltersWeightsUnderOptimal) {
  const RunSettings s = from_job_file("riccati-job-optimal.yaml",
                                      "model: flexible_manipulator\nfilter: optimal\nx0: [0, 0, 0, 0]\n"
                                      "optimal:\n  V: [1e6, 1e6, 1e4, 1e6, 1e6]\n  W: 1e10\n  r0: 1e3\n"
                                      "  form: split-step\n  hold_outputs: true\n");
  EXPECT_TRUE(SameMessage(to_session_request(s), parse_text<v1::CreateSessionRequest>(R"pb(
    model: "flexible_manipulator"
    filter {
      kind: FILTER_KIND_OPTIMAL
      optimal {
        v { diagonal { values: [ 1e6, 1e6, 1e4, 1e6, 1e6 ] } }
        w { scalar: 1e10 }
        r0 { scalar: 1e3 }
        form: OPTIMAL_FORM_SPLIT_STEP
        hold_outputs: true
      }
    }
    initial_state { x0: [ 0, 0, 0, 0 ] }
  )pb")));
}

// The flags and the job file come from one table: the same settings either way.
TEST(Flags, GiveWhatTheJobFileGives) {
  const RunSettings file = from_job_file(
      "riccati-job-all.yaml",
      "model: two_tank\ndata: ds-1\ninputs: [F1, F2]\noutputs: [h1, h2]\nfilter: ekf\npasses: 3\n"
      "x0: [0.4, 0.15]\ntheta0: [20, 20, 1, 1]\nP0: [0, 0, 10, 10, 10, 10]\nQ: 0\nR: 1e-3\nhold: foh\n"
      "integrator: {kind: rk3, substeps: 4, rtol: 1e-7, atol: 1e-9}\ninversion: pinv\njoseph: false\n"
      "ukf: {weights: julier, alpha: 1, beta: 2, kappa: -3}\n"
      "optimal: {V: [1, 2], W: 3, R0: [4, 5], form: continuous, hold_outputs: true}\n"
      "first_sample: 5\nend_sample: 50\ntruth: [10, 5, 0.0791, 0.1342]\n");
  RunSettings flags;
  std::string error;
  ASSERT_TRUE(from_flags(Command::kIdentify,
                         "-m two_tank -d ds-1 --inputs F1,F2 --outputs h1,h2 --filter ekf --passes 3 "
                         "--x0 0.4,0.15 --theta0 20,20,1,1 --p0 0,0,10,10,10,10 --q 0 --r 1e-3 --hold foh "
                         "--integrator rk3 --substeps 4 --rtol 1e-7 --atol 1e-9 --inversion pinv --no-joseph "
                         "--weights julier --alpha 1 --beta 2 --kappa -3 --v 1,2 --w 3 --r0 4,5 --form continuous "
                         "--hold-outputs --first-sample 5 --end-sample 50 --truth 10,5,0.0791,0.1342",
                         &flags, &error))
      << error;
  EXPECT_TRUE(SameMessage(to_identification_spec(flags, "ds-1"), to_identification_spec(file, "ds-1")));
  EXPECT_EQ(flags.data, file.data);
  EXPECT_EQ(flags.inputs, file.inputs);
  EXPECT_EQ(flags.outputs, file.outputs);
  EXPECT_EQ(flags.truth, file.truth);
  const v1::FilterSettings filter = to_filter_settings(flags);
  EXPECT_EQ(filter.hold(), v1::HOLD_ORDER_FIRST);
  EXPECT_EQ(filter.integrator().substeps(), 4u);
  EXPECT_EQ(filter.inversion(), v1::GAIN_INVERSION_PSEUDO_INVERSE);
  EXPECT_TRUE(filter.short_covariance_update());
  EXPECT_EQ(filter.ukf().kappa(), -3.0);
  EXPECT_EQ(filter.optimal().w().scalar(), 3.0);
  EXPECT_TRUE(filter.optimal().hold_outputs());
  EXPECT_EQ(to_identification_spec(flags, "ds-1").end_sample(), 50u);
}

TEST(Flags, OverrideTheJobFile) {
  RunSettings s = from_job_file("riccati-job-2.yaml", "model: two_tank\npasses: 10\nR: 1e-3\nP0: 1\nfilter: ukf\n");
  std::string error;
  ASSERT_TRUE(from_flags(Command::kIdentify, "--passes 3 --r 2e-3,3e-3", &s, &error)) << error;
  const v1::IdentificationSpec spec = to_identification_spec(s, "ds-1");
  EXPECT_EQ(spec.passes(), 3u);
  EXPECT_EQ(spec.filter().r().diagonal().values(1), 3e-3);
  EXPECT_EQ(spec.filter().kind(), v1::FILTER_KIND_UKF);  // not given as a flag: the file's
  EXPECT_EQ(spec.p0().scalar(), 1.0);
}

TEST(Flags, EachCommandHasItsOwn) {
  RunSettings s;
  std::string error;
  EXPECT_THROW(from_flags(Command::kStream, "--passes 3", &s, &error), CLI::ExtrasError);
  EXPECT_THROW(from_flags(Command::kSimulate, "--filter ekf", &s, &error), CLI::ExtrasError);
  ASSERT_TRUE(from_flags(Command::kValidate, "-m two_tank -d ds-1 --hold zoh --integrator cvode-adams --x0 first",
                         &s, &error))
      << error;
  EXPECT_TRUE(SameMessage(to_validation_spec(s, "ds-1"), parse_text<v1::ValidationSpec>(R"pb(
    model: "two_tank"
    dataset_id: "ds-1"
    initial_state { first_measurement: true }
    hold: HOLD_ORDER_ZERO
    integrator { kind: INTEGRATOR_KIND_CVODE_ADAMS }
  )pb")));
}

TEST(Flags, ErrorsNameTheFlag) {
  RunSettings s;
  std::string error;
  EXPECT_FALSE(from_flags(Command::kIdentify, "--p0 1,abc", &s, &error));
  EXPECT_EQ(error, "--p0: \"abc\" is not a number");
  EXPECT_FALSE(from_flags(Command::kIdentify, "--passes -1", &s, &error));
  EXPECT_EQ(error, "--passes: \"-1\" is not a whole number (0 or more)");
  EXPECT_FALSE(from_flags(Command::kStream, "--x0 firts", &s, &error));
  EXPECT_EQ(error, "--x0: \"firts\" is not a number (give first or a list of numbers)");
}

TEST(JobFile, ErrorsNameTheKeyAndItsLine) {
  const auto error_of = [](const std::string& name, const std::string& text) {
    RunSettings s;
    std::string error;
    EXPECT_FALSE(load_job_file(write(name, text), &s, &error)) << text;
    return error;
  };
  std::string error = error_of("riccati-job-3.yaml", "model: two_tank\npases: 3\n");
  EXPECT_NE(error.find("riccati-job-3.yaml: unknown key \"pases\" (line 2)"), std::string::npos) << error;
  error = error_of("riccati-job-4.yaml", "passes: many\n");
  EXPECT_NE(error.find("key \"passes\" (line 1): \"many\" is not a whole number"), std::string::npos) << error;
  error = error_of("riccati-job-5.yaml", "model: m\nintegrator:\n  kind: rk4\n  steps: 3\n");
  EXPECT_NE(error.find("unknown key \"integrator.steps\" (line 4) (expected kind, substeps, rtol, atol)"),
            std::string::npos)
      << error;
  error = error_of("riccati-job-6.yaml", "optimal: 5\n");
  EXPECT_NE(error.find("key \"optimal\" (line 1): expected a map (V, W, R0, form, hold_outputs)"), std::string::npos)
      << error;
  error = error_of("riccati-job-7.yaml", "R: [[1, 2], [3]]\n");
  EXPECT_NE(error.find("key \"R\" (line 1): row 2 has 1 value, row 1 has 2"), std::string::npos) << error;
  error = error_of("riccati-job-8.yaml", "optimal:\n  form: split_step\n");
  EXPECT_NE(error.find("key \"optimal.form\" (line 2): \"split_step\" is unknown (continuous, split-step)"),
            std::string::npos)
      << error;
}

TEST(Lists, ParseNumbersStrictly) {
  std::vector<double> v;
  std::string error;
  ASSERT_TRUE(parse_list("1, 2.5,-3e-2", &v, &error));
  EXPECT_EQ(v, (std::vector<double>{1, 2.5, -3e-2}));
  EXPECT_FALSE(parse_list("1,x", &v, &error));
  EXPECT_NE(error.find("\"x\" is not a number"), std::string::npos);
}

TEST(ExitCodes, FollowTheStatusCode) {
  EXPECT_EQ(exit_code_for(grpc::StatusCode::OK), kExitOk);
  EXPECT_EQ(exit_code_for(grpc::StatusCode::NOT_FOUND), kExitNotFound);
  EXPECT_EQ(exit_code_for(grpc::StatusCode::UNAVAILABLE), kExitUnreachable);
  EXPECT_EQ(exit_code_for(grpc::StatusCode::DEADLINE_EXCEEDED), kExitUnreachable);
  EXPECT_EQ(exit_code_for(grpc::StatusCode::INVALID_ARGUMENT), kExitFailed);
  EXPECT_EQ(exit_code_for(grpc::StatusCode::FAILED_PRECONDITION), kExitFailed);
}

TEST(Tables, ParameterTableShowsTruthAndError) {
  v1::IdentificationResult r;
  r.add_param_names("A1");
  r.add_theta_mean(9.9);
  r.add_theta_std(0.01);
  r.add_theta(9.95);
  const std::string table = parameter_table(r, {20.0}, {10.0});
  EXPECT_NE(table.find("A1"), std::string::npos);
  EXPECT_NE(table.find("-1.000"), std::string::npos) << table;  // (9.9 - 10) / 10 = -1 %
}

}  // namespace
}  // namespace riccati::cli

namespace riccati::cli {
namespace {

// The connection settings: flag over environment over config file, and the
// token only ever from a file or the environment.
class ConnectionTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() / ("riccati-conn-" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir_);
    env_["HOME"] = dir_.string();
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  std::string file(const std::string& name, const std::string& text, std::filesystem::perms perms =
                                                                          std::filesystem::perms::owner_read |
                                                                          std::filesystem::perms::owner_write) {
    const auto path = dir_ / name;
    std::filesystem::create_directories(path.parent_path());
    std::ofstream(path) << text;
    std::filesystem::permissions(path, perms);
    return path.string();
  }

  std::optional<std::string> resolve(const ConnectionFlags& flags, Connection* out) {
    return resolve_connection(
        flags,
        [this](const char* name) -> const char* {
          auto it = env_.find(name);
          return it == env_.end() ? nullptr : it->second.c_str();
        },
        out);
  }

  std::filesystem::path dir_;
  std::map<std::string, std::string> env_;
};

TEST_F(ConnectionTest, FlagsBeatTheEnvironmentWhichBeatsTheConfigFile) {
  file("ca.pem", "CA");
  file("file-token", "from-file\n");
  file("env-token", "from-env-file");
  file(".config/riccati/client.yaml", "server: config:1\ntoken_file: ~/file-token\nca: ~/ca.pem\n");
  Connection c;
  ASSERT_EQ(resolve({}, &c), std::nullopt);
  EXPECT_EQ(c.server, "config:1");
  EXPECT_EQ(c.token, "from-file");  // the trailing newline is not part of it
  EXPECT_TRUE(c.tls);
  EXPECT_EQ(c.ca_pem, "CA");

  env_["RICCATI_SERVER"] = "env:2";
  env_["RICCATI_TOKEN_FILE"] = (dir_ / "env-token").string();
  Connection e;
  ASSERT_EQ(resolve({}, &e), std::nullopt);
  EXPECT_EQ(e.server, "env:2");
  EXPECT_EQ(e.token, "from-env-file");

  ConnectionFlags flags;
  flags.server = "flag:3";
  flags.token_file = (dir_ / "file-token").string();
  Connection f;
  ASSERT_EQ(resolve(flags, &f), std::nullopt);
  EXPECT_EQ(f.server, "flag:3");
  EXPECT_EQ(f.token, "from-file");
}

TEST_F(ConnectionTest, NothingConfiguredIsPlainLoopbackWithoutAToken) {
  Connection c;
  ASSERT_EQ(resolve({}, &c), std::nullopt);
  EXPECT_EQ(c.server, "127.0.0.1:7531");
  EXPECT_TRUE(c.token.empty());
  EXPECT_FALSE(c.tls);
  env_["RICCATI_TOKEN"] = "in-the-environment";
  Connection t;
  ASSERT_EQ(resolve({}, &t), std::nullopt);
  EXPECT_EQ(t.token, "in-the-environment");
}

TEST_F(ConnectionTest, RefusesATokenFileOthersCanReadAndUnknownConfigKeys) {
  using std::filesystem::perms;
  ConnectionFlags flags;
  flags.token_file = file("open-token", "secret", perms::owner_read | perms::group_read | perms::others_read);
  Connection c;
  auto error = resolve(flags, &c);
  ASSERT_TRUE(error.has_value());
  EXPECT_NE(error->find("chmod 600"), std::string::npos) << *error;

  file(".config/riccati/client.yaml", "server: a:1\ntoken: secret\n");
  error = resolve({}, &c);
  ASSERT_TRUE(error.has_value());
  EXPECT_NE(error->find("unknown key \"token\""), std::string::npos) << *error;

  env_["RICCATI_CONFIG"] = file("other.yaml", "server: [unclosed\n");
  error = resolve({}, &c);
  ASSERT_TRUE(error.has_value());
  EXPECT_NE(error->find("other.yaml"), std::string::npos) << *error;

  env_.erase("RICCATI_CONFIG");
  std::filesystem::remove(dir_ / ".config/riccati/client.yaml");
  flags = {};
  flags.ca = (dir_ / "missing.pem").string();
  error = resolve(flags, &c);
  ASSERT_TRUE(error.has_value());
  EXPECT_NE(error->find("missing.pem"), std::string::npos) << *error;
}

TEST_F(ConnectionTest, TheTlsServerNameComesFromTheFlagTheEnvironmentOrTheConfigFile) {
  file(".config/riccati/client.yaml", "tls: true\ntls_server_name: from-config\n");
  Connection c;
  ASSERT_EQ(resolve({}, &c), std::nullopt);
  EXPECT_EQ(c.tls_server_name, "from-config");
  env_["RICCATI_TLS_SERVER_NAME"] = "from-env";
  ASSERT_EQ(resolve({}, &c), std::nullopt);
  EXPECT_EQ(c.tls_server_name, "from-env");
  ConnectionFlags flags;
  flags.tls_server_name = "from-flag";
  ASSERT_EQ(resolve(flags, &c), std::nullopt);
  EXPECT_EQ(c.tls_server_name, "from-flag");
}

}  // namespace
}  // namespace riccati::cli
