// The CLI's job files and flags, turned into API requests (no daemon).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <unistd.h>

#include "commands.hpp"
#include "connection.hpp"
#include "enum_choices.hpp"
#include "settings.hpp"

namespace riccati::cli {
namespace {

using google::protobuf::EnumDescriptor;

v1::ModelInfo two_tank() {
  v1::ModelInfo m;
  m.set_name("two_tank");
  for (const char* n : {"h1", "h2"}) m.add_state_names(n);
  for (const char* n : {"A1", "A2", "k1", "k2"}) m.add_param_names(n);
  for (const char* n : {"F1", "F2"}) m.add_input_names(n);
  for (const char* n : {"h1", "h2"}) m.add_output_names(n);
  return m;
}

std::string write(const std::string& name, const std::string& text) {
  const auto path = std::filesystem::temp_directory_path() / name;
  std::ofstream(path) << text;
  return path.string();
}

TEST(JobFile, ScalarsListsAndMatricesBecomeCovariances) {
  RunSettings s;
  std::string error;
  ASSERT_TRUE(load_job_file(write("riccati-job-1.yaml",
                                  "model: two_tank\nfilter: ukf\npasses: 10\nx0: first\ntheta0: [20, 20, 1, 1]\n"
                                  "P0: [0, 0, 10, 10, 10, 10]\nQ: 0\nR: [[1e-3, 1e-4], [1e-4, 2e-3]]\n"
                                  "integrator: {kind: cvode-bdf, rtol: 1e-9}\nukf: {weights: scaled, alpha: 0.5}\n"),
                            &s, &error))
      << error;
  v1::IdentificationSpec spec;
  ASSERT_TRUE(to_identification_spec(s, two_tank(), "ds-1", &spec, &error)) << error;
  EXPECT_EQ(spec.passes(), 10u);
  EXPECT_EQ(spec.filter().kind(), v1::FILTER_KIND_UKF);
  EXPECT_TRUE(spec.initial_state().first_measurement());
  ASSERT_EQ(spec.p0().diagonal().values_size(), 6);
  EXPECT_EQ(spec.p0().diagonal().values(2), 10.0);
  ASSERT_EQ(spec.filter().q().diagonal().values_size(), 6);  // one value: the whole diagonal
  EXPECT_EQ(spec.filter().q().diagonal().values(5), 0.0);
  ASSERT_EQ(spec.filter().r().full().values_size(), 4);
  EXPECT_EQ(spec.filter().r().full().values(1), 1e-4);  // column-major (1, 0)
  EXPECT_EQ(spec.filter().integrator().kind(), v1::INTEGRATOR_KIND_CVODE_BDF);
  EXPECT_EQ(spec.filter().integrator().rtol(), 1e-9);
  EXPECT_EQ(spec.filter().ukf().weights(), v1::SIGMA_WEIGHTS_SCALED);
  EXPECT_EQ(spec.filter().ukf().alpha(), 0.5);
}

v1::ModelInfo flexible_manipulator() {
  v1::ModelInfo m;
  m.set_name("flexible_manipulator");
  m.set_ndof(2);
  for (const char* n : {"s1", "s2", "v1", "v2"}) m.add_state_names(n);
  for (const char* n : {"c1", "c2", "k", "b", "J1", "J2"}) m.add_param_names(n);
  m.add_input_names("T");
  for (const char* n : {"s1", "s2"}) m.add_output_names(n);
  return m;
}

TEST(JobFile, OptimalFilterWeightsAndTheirErrors) {
  RunSettings s;
  std::string error;
  ASSERT_TRUE(load_job_file(write("riccati-job-optimal.yaml",
                                  "model: flexible_manipulator\nfilter: optimal\nx0: [0, 0, 0, 0]\n"
                                  "optimal:\n  V: [1e6, 1e6, 1e4, 1e6, 1e6]\n  W: 1e10\n  R0: 1e3\n"
                                  "  form: split-step\n  hold_outputs: true\n"),
                            &s, &error))
      << error;
  v1::CreateSessionRequest session;
  ASSERT_TRUE(to_session_request(s, flexible_manipulator(), &session, &error)) << error;
  const v1::OptimalSettings& o = session.filter().optimal();
  EXPECT_EQ(session.filter().kind(), v1::FILTER_KIND_OPTIMAL);
  ASSERT_EQ(o.v().diagonal().values_size(), 5);  // 2 equations of motion, T, s1, s2
  EXPECT_EQ(o.v().diagonal().values(2), 1e4);
  EXPECT_EQ(o.w().diagonal().values_size(), 10);
  EXPECT_EQ(o.r0().diagonal().values(9), 1e3);
  EXPECT_EQ(o.form(), v1::OPTIMAL_FORM_SPLIT_STEP);
  EXPECT_TRUE(o.hold_outputs());
  EXPECT_FALSE(session.has_p0());  // R0 instead

  RunSettings short_v = s;
  short_v.v = matrix_from_list({1, 2, 3, 4});
  EXPECT_FALSE(to_session_request(short_v, flexible_manipulator(), &session, &error));
  EXPECT_NE(error.find("equations of motion"), std::string::npos) << error;
  RunSettings with_r = s;
  with_r.r = matrix_from_list({1e-3});
  EXPECT_FALSE(to_session_request(with_r, flexible_manipulator(), &session, &error));
  EXPECT_NE(error.find("no Q and R"), std::string::npos) << error;
  RunSettings both = s;
  both.p0 = matrix_from_list({1});
  EXPECT_FALSE(to_session_request(both, flexible_manipulator(), &session, &error));
  RunSettings not_mechanical = s;
  EXPECT_FALSE(to_session_request(not_mechanical, two_tank(), &session, &error));
  EXPECT_NE(error.find("mechanical form"), std::string::npos) << error;
  RunSettings ekf_with_v = s;
  ekf_with_v.filter = "ekf";
  ekf_with_v.r = matrix_from_list({1e-3});
  EXPECT_FALSE(to_session_request(ekf_with_v, flexible_manipulator(), &session, &error));
  EXPECT_NE(error.find("settings of the optimal filter"), std::string::npos) << error;
}

TEST(JobFile, FlagsOverrideTheFile) {
  RunSettings file;
  std::string error;
  ASSERT_TRUE(load_job_file(write("riccati-job-2.yaml", "model: two_tank\npasses: 10\nR: 1e-3\nP0: 1\n"), &file,
                            &error));
  RunSettings flags;
  flags.passes = 3;
  flags.r = matrix_from_list({2e-3, 3e-3});
  overlay(flags, &file);
  v1::IdentificationSpec spec;
  ASSERT_TRUE(to_identification_spec(file, two_tank(), "ds-1", &spec, &error)) << error;
  EXPECT_EQ(spec.passes(), 3u);
  EXPECT_EQ(spec.filter().r().diagonal().values(1), 3e-3);
  EXPECT_EQ(spec.model(), "two_tank");
}

TEST(JobFile, ErrorsNameTheKey) {
  RunSettings s;
  std::string error;
  EXPECT_FALSE(load_job_file(write("riccati-job-3.yaml", "model: two_tank\npases: 3\n"), &s, &error));
  EXPECT_NE(error.find("unknown key \"pases\" (line 2)"), std::string::npos) << error;
  EXPECT_FALSE(load_job_file(write("riccati-job-4.yaml", "passes: many\n"), &s, &error));
  EXPECT_NE(error.find("\"passes\""), std::string::npos) << error;
  RunSettings sizes;
  sizes.r = matrix_from_list({1e-3, 1e-3, 1e-3});
  sizes.p0 = matrix_from_list({1});
  v1::IdentificationSpec spec;
  EXPECT_FALSE(to_identification_spec(sizes, two_tank(), "ds", &spec, &error));
  EXPECT_NE(error.find("R (outputs h1, h2) needs 2 values"), std::string::npos) << error;
  RunSettings no_r;
  no_r.p0 = matrix_from_list({1});
  EXPECT_FALSE(to_identification_spec(no_r, two_tank(), "ds", &spec, &error));
  EXPECT_NE(error.find("R (measurement noise variances of h1, h2) is required"), std::string::npos) << error;
}

// The names users write today, derived from the proto's values.
TEST(EnumChoices, DerivedFromTheValueNamesOrTheirShortName) {
  using Names = std::vector<std::string>;
  EXPECT_EQ(choice_names(*v1::FilterKind_descriptor()), (Names{"ekf", "ukf", "optimal"}));
  EXPECT_EQ(choice_names(*v1::HoldOrder_descriptor()), (Names{"zoh", "foh"}));
  EXPECT_EQ(choice_names(*v1::IntegratorKind_descriptor()),
            (Names{"rk4", "rk3", "cvode-bdf", "cvode-adams", "arkode-erk"}));
  EXPECT_EQ(choice_names(*v1::GainInversion_descriptor()), (Names{"cholesky", "pinv"}));
  EXPECT_EQ(choice_names(*v1::SigmaWeights_descriptor()), (Names{"julier", "scaled"}));
  EXPECT_EQ(choice_names(*v1::OptimalForm_descriptor()), (Names{"continuous", "split-step"}));
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
    const std::string name = choice_name(*type->FindValueByNumber(number));
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
