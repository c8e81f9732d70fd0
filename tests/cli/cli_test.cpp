// The CLI's job files and flags, turned into API requests, and the choices
// of enum settings from the API's descriptors (no daemon).
#include <gtest/gtest.h>
#include <google/protobuf/text_format.h>
#include <google/protobuf/util/message_differencer.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <sstream>
#include <unistd.h>

#include "commands/commands.hpp"
#include "connection.hpp"
#include "estimation_output.hpp"
#include "riccati/enum_names.hpp"
#include "riccati/settings_schema.hpp"
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
            (Names{"rk4", "rk3", "cvode-bdf", "cvode-adams", "arkode-erk", "dop853"}));
  EXPECT_EQ(api::enum_choice_names(*v1::GainInversion_descriptor()), (Names{"cholesky", "pinv"}));
  EXPECT_EQ(api::enum_choice_names(*v1::SigmaWeights_descriptor()), (Names{"julier", "scaled"}));
  EXPECT_EQ(api::enum_choice_names(*v1::OptimalForm_descriptor()), (Names{"continuous", "split-step"}));
  EXPECT_EQ(api::enum_choice_names(*v1::IdentificationMethod_descriptor()), (Names{"filter", "oe", "ml"}));
  EXPECT_EQ(api::enum_choice_names(*v1::EstimateChoice_descriptor()), (Names{"last-pass-mean", "final"}));
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
CliRun riccati_raw(const std::string& args) {
  const std::string command =
      "HOME=" + std::filesystem::temp_directory_path().string() + " " + RICCATI_CLI_BIN + " " + args + " 2>&1";
  CliRun run{0, ""};
  std::FILE* pipe = popen(command.c_str(), "r");
  std::array<char, 4096> buffer;
  std::size_t n;
  while ((n = std::fread(buffer.data(), 1, buffer.size(), pipe)) > 0) run.out.append(buffer.data(), n);
  const int status = pclose(pipe);
  run.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return run;
}
CliRun riccati(const std::string& args) { return riccati_raw("--server 127.0.0.1:1 --timeout 1 " + args); }

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
                                   std::pair{"--integrator ", v1::IntegratorKind_descriptor()},
                                   std::pair{"--method ", v1::IdentificationMethod_descriptor()}}) {
    const std::vector<std::string> offered = listed_after(help.out, flag);
    EXPECT_EQ(offered, values_of(*type)) << help.out;
    EXPECT_EQ(offered.size(), static_cast<std::size_t>(type->value_count() - 1));
  }
  // smooth runs the EKF or the UKF, and says which estimate of a job --params takes.
  const CliRun smooth_help = riccati("smooth --help");
  ASSERT_EQ(smooth_help.exit_code, 0) << smooth_help.out;
  EXPECT_EQ(listed_after(smooth_help.out, "--filter "), values_of(*v1::FilterKind_descriptor())) << smooth_help.out;
  EXPECT_EQ(listed_after(smooth_help.out, "--estimate "), values_of(*v1::EstimateChoice_descriptor()))
      << smooth_help.out;

  CliRun method = riccati("identify --model two_tank --data ds-1 --method newton");
  EXPECT_EQ(method.exit_code, 2) << method.out;
  EXPECT_EQ(listed_after(method.out, "--method: \"newton\" is unknown"),
            values_of(*v1::IdentificationMethod_descriptor()))
      << method.out;

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
    model: "two_tank" dataset_id: "ds-1" initial_state { first_measurement: true }
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
  const v1::FilterSettings filter = to_identification_spec(flags, "ds-1").filter();
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
  EXPECT_NE(error.find("unknown key \"integrator.steps\" (line 4) (expected kind, substeps, rtol, atol, max_steps)"),
            std::string::npos)
      << error;
  error = error_of("riccati-job-6.yaml", "optimal: 5\n");
  EXPECT_NE(error.find("key \"optimal\" (line 1): expected a map (v, w, r0, form, hold_outputs)"), std::string::npos)
      << error;
  error = error_of("riccati-job-7.yaml", "R: [[1, 2], [3]]\n");
  EXPECT_NE(error.find("key \"R\" (line 1): row 2 has 1 value, row 1 has 2"), std::string::npos) << error;
  error = error_of("riccati-job-8.yaml", "optimal:\n  form: split_step\n");
  EXPECT_NE(error.find("key \"optimal.form\" (line 2): \"split_step\" is unknown (continuous, split-step)"),
            std::string::npos)
      << error;
}

// ------------------------------------------------------------ output error and maximum likelihood

// Every OE/ML flag, as riccati identify --help shows it, into the spec's fields.
TEST(EstimationFlags, FillTheIdentificationSpec) {
  RunSettings s;
  std::string error;
  ASSERT_TRUE(from_flags(Command::kIdentify,
                         "-m two_tank -d ds-1 --method oe --theta0 20,20,1,1 --bound A1=1:100 --bound k1=0.01: "
                         "--bound A2=:50 --fix A2 --fix k2=0.1342 --log-scale k1 --estimate-x0 h1 --init-passes 2 "
                         "--experiment ds-2 --experiment ds-3 --exclude 100:200 --exclude 3@0:50 "
                         "--output-limit h1=:0.6 --output-sigma 0.005,0.006 --max-iterations 50 "
                         "--function-tolerance 1e-10 --gradient-tolerance 1e-9 --parameter-tolerance 1e-8",
                         &s, &error))
      << error;
  ASSERT_TRUE(check_identification(s, &error)) << error;
  EXPECT_EQ(s.experiments, (std::vector<std::string>{"ds-2", "ds-3"}));  // uploaded first where they are files
  EXPECT_TRUE(SameMessage(to_identification_spec(s, "ds-1", {"ds-2", "ds-3"}), parse_text<v1::IdentificationSpec>(R"pb(
    model: "two_tank"
    dataset_id: "ds-1"
    initial_state { first_measurement: true estimate: "h1" }
    theta0: [ 20, 20, 1, 1 ]
    method: IDENTIFICATION_METHOD_OE
    init_passes: 2
    bounds { name: "A1" lower: 1 upper: 100 }
    bounds { name: "k1" lower: 0.01 }
    bounds { name: "A2" upper: 50 }
    fixed { name: "A2" }
    fixed { name: "k2" value: 0.1342 }
    log_scale: "k1"
    mask {
      limits { output: "h1" upper: 0.6 }
      excluded { first: 100 end: 200 }
    }
    experiments {
      dataset_id: "ds-2"
      initial_state { first_measurement: true estimate: "h1" }
      mask { limits { output: "h1" upper: 0.6 } }
    }
    experiments {
      dataset_id: "ds-3"
      initial_state { first_measurement: true estimate: "h1" }
      mask {
        limits { output: "h1" upper: 0.6 }
        excluded { first: 0 end: 50 }
      }
    }
    estimation {
      output_sigma: [ 0.005, 0.006 ]
      max_iterations: 50
      function_tolerance: 1e-10
      gradient_tolerance: 1e-9
      parameter_tolerance: 1e-8
    }
  )pb")));
}

TEST(EstimationFlags, TheJobFileKeysGiveWhatTheFlagsGive) {
  const RunSettings file = from_job_file(
      "riccati-job-ml.yaml",
      "model: two_tank\nmethod: ml\nR: 1e-4\ninit_passes: 1\nbounds: [A1=1:100, 'k1=0.01:']\nfixed: [A2, k2=0.1342]\n"
      "log_scale: k1\nestimate_x0: all\nexperiments: [ds-2]\nexclude: ['2@5:10']\noutput_limits: ['h2=0.01:']\n"
      "estimation:\n  estimate_q: true\n  estimate_r: true\n  max_iterations: 20\n");
  RunSettings flags;
  std::string error;
  ASSERT_TRUE(from_flags(Command::kIdentify,
                         "-m two_tank --method ml --r 1e-4 --init-passes 1 --bound A1=1:100,k1=0.01: --fix A2,k2=0.1342 "
                         "--log-scale k1 --estimate-x0 --experiment ds-2 --exclude 2@5:10 --output-limit h2=0.01: "
                         "--estimate-q --estimate-r --max-iterations 20",
                         &flags, &error))
      << error;
  const v1::IdentificationSpec spec = to_identification_spec(flags, "ds-1", {"ds-2"});
  EXPECT_TRUE(SameMessage(spec, to_identification_spec(file, "ds-1", {"ds-2"})));
  EXPECT_EQ(spec.method(), v1::IDENTIFICATION_METHOD_ML);
  EXPECT_EQ(spec.initial_state().estimate(0), "all");  // --estimate-x0 alone
  EXPECT_TRUE(spec.estimation().estimate_process_noise());
  EXPECT_TRUE(spec.estimation().estimate_measurement_noise());
  EXPECT_EQ(spec.estimation().max_iterations(), 20u);
  EXPECT_EQ(spec.experiments(0).mask().excluded(0).first(), 5u);
  EXPECT_FALSE(spec.mask().excluded_size() > 0) << "an exclusion of experiment 2 went to experiment 1";
}

// The filter method is sent nothing it did not ask for: riccatid refuses
// estimation settings for it, so none may be made up here.
TEST(EstimationFlags, NothingOfTheMethodsIsSentUnasked) {
  RunSettings s;
  std::string error;
  ASSERT_TRUE(from_flags(Command::kIdentify, "-m two_tank --passes 3", &s, &error)) << error;
  const v1::IdentificationSpec spec = to_identification_spec(s, "ds-1");
  EXPECT_FALSE(spec.has_estimation());
  EXPECT_FALSE(spec.has_mask());
  EXPECT_EQ(spec.method(), v1::IDENTIFICATION_METHOD_UNSPECIFIED);
  EXPECT_EQ(spec.experiments_size(), 0);
}

TEST(EstimationFlags, ErrorsNameTheFlagAndWhatIsWrong) {
  const auto error_of = [](const std::string& args) {
    RunSettings s;
    std::string error;
    EXPECT_FALSE(from_flags(Command::kIdentify, args, &s, &error)) << args;
    return error;
  };
  EXPECT_EQ(error_of("--bound A1"), "--bound: \"A1\" is not NAME=LO:HI (LO or HI may be left empty)");
  EXPECT_EQ(error_of("--bound A1=x:1"), "--bound: \"A1=x:1\": \"x\" is not a number");
  EXPECT_EQ(error_of("--bound A1=:"), "--bound: \"A1=:\" gives neither LO nor HI");
  EXPECT_EQ(error_of("--bound =1:2"), "--bound: \"=1:2\": a name is missing before '='");
  EXPECT_EQ(error_of("--bound A1=1:2:3"), "--bound: \"A1=1:2:3\" is not NAME=LO:HI (LO or HI may be left empty)");
  EXPECT_EQ(error_of("--fix k2=abc"), "--fix: \"k2=abc\": \"abc\" is not a number");
  EXPECT_EQ(error_of("--fix k2:1"), "--fix: \"k2:1\" is not NAME or NAME=VALUE");
  EXPECT_EQ(error_of("--exclude 5"),
            "--exclude: \"5\" is not [E@]FIRST:END (samples FIRST to END-1, 0-based, of experiment E)");
  EXPECT_EQ(error_of("--exclude 0@1:2"), "--exclude: \"0@1:2\": experiments count from 1 (1 is --data)");
  EXPECT_EQ(error_of("--output-limit h1=low:"), "--output-limit: \"h1=low:\": \"low\" is not a number");
  EXPECT_EQ(error_of("--max-iterations -5"), "--max-iterations: \"-5\" is not a whole number (0 or more)");
  EXPECT_EQ(error_of("--output-sigma 0.1,x"), "--output-sigma: \"x\" is not a number");

  // An exclusion of an experiment that was not given: the flag, the experiment and what there is.
  RunSettings s;
  std::string error;
  ASSERT_TRUE(from_flags(Command::kIdentify, "--experiment ds-2 --exclude 3@0:10", &s, &error)) << error;
  EXPECT_FALSE(check_identification(s, &error));
  EXPECT_EQ(error, "--exclude 3@0:10: there is no experiment 3 (1 is --data, 2 the --experiment record)");
  ASSERT_TRUE(from_flags(Command::kIdentify, "--experiment ds-2,ds-3 --exclude 5@0:10", &s, &error)) << error;
  EXPECT_FALSE(check_identification(s, &error));
  EXPECT_EQ(error, "--exclude 5@0:10: there is no experiment 5 (1 is --data, 2 to 3 the --experiment records)");

  // The job file: the key and its line.
  RunSettings file;
  EXPECT_FALSE(load_job_file(write("riccati-job-bounds.yaml", "model: two_tank\nbounds: [A1=1]\n"), &file, &error));
  EXPECT_NE(error.find("key \"bounds\" (line 2): \"A1=1\" is not NAME=LO:HI"), std::string::npos) << error;
  EXPECT_FALSE(load_job_file(write("riccati-job-est.yaml", "estimation:\n  max_iters: 3\n"), &file, &error));
  EXPECT_NE(error.find("unknown key \"estimation.max_iters\" (line 2) (expected output_sigma, "
                       "estimate_process_noise, estimate_measurement_noise, max_iterations, function_tolerance, "
                       "gradient_tolerance, parameter_tolerance, covariance)"),
            std::string::npos)
      << error;
}

// What riccati says before anything is sent (no daemon here: it would exit 3).
TEST(EstimationFlags, TheCommandRefusesBadFlagsWithExitTwo) {
  CliRun r = riccati("identify --model two_tank --data ds-1 --method oe --bound A1=1");
  EXPECT_EQ(r.exit_code, 2) << r.out;
  EXPECT_NE(r.out.find("riccati: --bound: \"A1=1\" is not NAME=LO:HI"), std::string::npos) << r.out;
  r = riccati("identify --model two_tank --data ds-1 --method oe --exclude 2@0:10");
  EXPECT_EQ(r.exit_code, 2) << r.out;
  EXPECT_NE(r.out.find("riccati: --exclude 2@0:10: there is no experiment 2 (1 is --data)"), std::string::npos)
      << r.out;
  r = riccati("validate --model two_tank --data ds-1 --params 10,5,0.0791,0.1342 --estimate final");
  EXPECT_EQ(r.exit_code, 2) << r.out;
  EXPECT_NE(r.out.find("--estimate chooses among an identification job's estimates; --params 10,5,0.0791,0.1342 is "
                       "not a job"),
            std::string::npos)
      << r.out;
  r = riccati("validate --model two_tank --data ds-1 --params 10,5,0.0791,0.1342 --estimate-x0 200");
  EXPECT_EQ(r.exit_code, 2) << r.out;
  EXPECT_NE(r.out.find("--estimate-x0 200: the flag names the initial states to fit (or all), as in identify; the "
                       "samples they are fitted on are --x0-samples 200"),
            std::string::npos)
      << r.out;
  r = riccati("smooth --model two_tank");
  EXPECT_EQ(r.exit_code, 2) << r.out;
  EXPECT_NE(r.out.find("smooth needs --model and --data"), std::string::npos) << r.out;
}

TEST(ValidationFlags, TheEstimateAndTheSamplesTheInitialStatesAreFittedOn) {
  RunSettings s;
  std::string error;
  ASSERT_TRUE(from_flags(Command::kValidate, "-m two_tank -d ds-1 --x0 0.2,0.5 --estimate final --x0-samples 100", &s,
                         &error))
      << error;
  EXPECT_TRUE(SameMessage(to_validation_spec(s, "ds-1"), parse_text<v1::ValidationSpec>(R"pb(
    model: "two_tank"
    dataset_id: "ds-1"
    initial_state { x0: [ 0.2, 0.5 ] estimate: "all" }
    estimate: ESTIMATE_CHOICE_FINAL
    estimate_x0_samples: 100
  )pb")));
  // --estimate-x0 names the states, as in identify; --x0-samples alone fits them all.
  RunSettings named;
  ASSERT_TRUE(from_flags(Command::kValidate, "--estimate-x0 h1 --x0-samples 50", &named, &error)) << error;
  EXPECT_EQ(to_validation_spec(named, "ds-1").initial_state().estimate(0), "h1");
  EXPECT_EQ(to_validation_spec(named, "ds-1").initial_state().estimate_size(), 1);
  EXPECT_FALSE(from_flags(Command::kValidate, "--x0-samples all", &s, &error));
  EXPECT_EQ(error, "--x0-samples: \"all\" is not a whole number (0 or more)");
  EXPECT_FALSE(from_flags(Command::kValidate, "--estimate best", &s, &error));
  EXPECT_EQ(error, "--estimate: \"best\" is unknown (last-pass-mean, final)");
}

TEST(SmoothingFlags, TheFilterAndTheRangeGoIntoTheSpec) {
  const RunSettings file = from_job_file("riccati-job-smooth.yaml",
                                         "model: two_tank\ndata: ds-1\nfilter: ukf\nR: 2.5e-5\nQ: [1e-8, 1e-8, 0, 0, 0, 0]\n"
                                         "x0: [0.4, 0.15]\ntheta0: [10, 5, 0.0791, 0.1342]\nP0: 1e-4\n"
                                         "first_sample: 10\nend_sample: 500\n");
  EXPECT_TRUE(SameMessage(to_smoothing_spec(file, "ds-1"), parse_text<v1::SmoothingSpec>(R"pb(
    model: "two_tank"
    dataset_id: "ds-1"
    filter {
      kind: FILTER_KIND_UKF
      q { diagonal { values: [ 1e-8, 1e-8, 0, 0, 0, 0 ] } }
      r { scalar: 2.5e-5 }
    }
    initial_state { x0: [ 0.4, 0.15 ] }
    theta0: [ 10, 5, 0.0791, 0.1342 ]
    p0 { scalar: 1e-4 }
    first_sample: 10
    end_sample: 500
  )pb")));
  RunSettings flags;
  std::string error;
  ASSERT_TRUE(from_flags(Command::kSmooth,
                         "-m two_tank -d ds-1 --filter ukf --r 2.5e-5 --q 1e-8,1e-8,0,0,0,0 --x0 0.4,0.15 --p0 1e-4 "
                         "--first-sample 10 --end-sample 500",
                         &flags, &error))
      << error;
  ASSERT_TRUE(from_flags(Command::kSmooth, "--theta0 10,5,0.0791,0.1342", &flags, &error)) << error;
  EXPECT_TRUE(SameMessage(to_smoothing_spec(flags, "ds-1"), to_smoothing_spec(file, "ds-1")));
  // Neither passes nor the optimal filter's weights: a smoother runs the EKF or the UKF once.
  EXPECT_THROW(from_flags(Command::kSmooth, "--passes 3", &flags, &error), CLI::ExtrasError);
  EXPECT_THROW(from_flags(Command::kSmooth, "--v 1", &flags, &error), CLI::ExtrasError);
}

// ------------------------------------------------------------ estimation tables

// An OE result of two_tank as riccatid makes one: A2 fixed, A1 and k1
// nearly indistinguishable (r = -0.97), one experiment with its fit.
v1::EstimationResult two_tank_estimate() {
  return parse_text<v1::EstimationResult>(R"pb(
    method: IDENTIFICATION_METHOD_OE
    param_names: [ "A1", "A2", "k1", "k2" ]
    theta: [ 10.02, 5, 0.0791, 0.1342 ]
    theta_std: [ 0.01, 0, 2e-5, 4e-5 ]
    ci_lower: [ 10.0004, 5, 0.07906, 0.13412 ]
    ci_upper: [ 10.0396, 5, 0.07914, 0.13428 ]
    fixed: [ false, true, false, false ]
    correlation { rows: 4 cols: 4 values: [ 1, 0, -0.97, 0.2, 0, 1, 0, 0, -0.97, 0, 1, 0.1, 0.2, 0, 0.1, 1 ] }
    warnings: "A1 and k1 are strongly correlated"
    cost: 0.0125
    sigma2: 2.5e-5
    iterations: 12
    evaluations: 30
    jacobian_evaluations: 13
    converged: true
    termination: "Function tolerance reached"
    gradient: "exact"
    experiments {
      dataset_id: "ds-1"
      x0: [ 0.4, 0.15 ]
      x0_std: [ 0.001, 0 ]
      x0_estimated: [ true, false ]
      t: [ 0, 1 ]
      y_measured { rows: 2 cols: 2 values: [ 0.4, 0.15, 0.41, 0.16 ] }
      y_model { rows: 2 cols: 2 values: [ 0.401, 0.149, 0.409, 0.161 ] }
      residuals { rows: 2 cols: 2 values: [ -0.2, 0.2, 0.2, -0.2 ] }
      mask { rows: 2 cols: 2 values: [ 1, 1, 0, 1 ] }
      fits { name: "h1" rmse: 0.001 fit_percent: 99.5 vaf_percent: 99.9 rrse: 0.005 }
      fits { name: "h2" rmse: 0.002 fit_percent: 98.25 vaf_percent: 99.8 rrse: 0.0175 }
    }
  )pb");
}

// The line of `text` that starts with `start`.
std::string line_of(const std::string& text, const std::string& start) {
  std::istringstream lines(text);
  for (std::string line; std::getline(lines, line);) {
    if (line.rfind(start, 0) == 0) return line;
  }
  return "";
}

TEST(EstimationTables, TheParameterTableHasStdIntervalsInitialAndTruth) {
  const std::string table =
      estimation_table(two_tank_estimate(), {20, 20, 1, 1}, {10, 5, 0.0791, 0.1342}, ModelNames{{"h1", "h2"}, {}, {}});
  EXPECT_NE(table.find("method oe: converged after 12 iterations (Function tolerance reached); cost 0.0125"),
            std::string::npos)
      << table;
  EXPECT_NE(table.find("residual variance 2.5e-05 (scales the covariance)"), std::string::npos) << table;
  std::istringstream a1(line_of(table, "A1 "));
  std::string name, initial, estimate, std_error, lower, upper, relative, percent, truth, error;
  a1 >> name >> initial >> estimate >> std_error >> lower >> upper >> relative >> percent >> truth >> error;
  EXPECT_EQ(initial, "20");
  EXPECT_EQ(estimate, "10.02");
  EXPECT_EQ(std_error, "0.01");
  EXPECT_EQ(lower + " " + upper, "[10.0004, 10.0396]");
  EXPECT_EQ(relative + " " + percent, "0.0998 %");  // 0.01 / 10.02
  EXPECT_EQ(truth, "10");
  EXPECT_EQ(error, "0.2");  // (10.02 - 10) / 10 in %
  // The truth outside the interval is said; inside, nothing.
  EXPECT_NE(line_of(table, "A1 ").find("(outside the interval)"), std::string::npos) << table;
  EXPECT_EQ(line_of(table, "k1 ").find("(outside the interval)"), std::string::npos) << table;
  // A fixed parameter has neither std nor interval.
  const std::string a2 = line_of(table, "A2 ");
  EXPECT_NE(a2.find("fixed"), std::string::npos) << a2;
  EXPECT_EQ(a2.find('['), std::string::npos) << a2;
  EXPECT_NE(table.find("warnings:\n  A1 and k1 are strongly correlated\n"), std::string::npos) << table;
  // The experiment: x0 estimated (with its std) or given, and the fit per output.
  EXPECT_NE(table.find("experiment 1 (ds-1): 2 samples\n  x0: h1 = 0.4 (std 0.001), h2 = 0.15 (given)\n"),
            std::string::npos)
      << table;
  std::istringstream h2(line_of(table, "  h2 "));
  double rmse = 0, fit = 0;
  h2 >> name >> rmse >> fit;
  EXPECT_EQ(fit, 98.25);
  // Without a truth or a start, their columns are not there.
  const std::string bare = estimation_table(two_tank_estimate(), {}, {}, {});
  EXPECT_EQ(bare.find("true"), std::string::npos) << bare;
  EXPECT_EQ(line_of(bare, "A1 ").find("20"), std::string::npos) << bare;
}

// Counts in the singular for one, in the plural otherwise (zero included).
TEST(EstimationTables, CountsSayOneInTheSingular) {
  EXPECT_EQ(counted(1, "state"), "1 state");
  EXPECT_EQ(counted(0, "state"), "0 states");
  EXPECT_EQ(counted(2000, "sample"), "2000 samples");
  EXPECT_EQ(counted(1, "pass", "passes"), "1 pass");
  EXPECT_EQ(counted(3, "pass", "passes"), "3 passes");
  v1::EstimationResult r = two_tank_estimate();
  r.set_iterations(1);
  r.set_evaluations(1);
  r.mutable_experiments(0)->mutable_t()->Truncate(1);
  r.mutable_experiments(0)->mutable_diagnostics()->set_samples(1);
  const std::string table = estimation_table(r, {}, {}, ModelNames{{"h1", "h2"}, {}, {}});
  EXPECT_NE(table.find("converged after 1 iteration (Function tolerance reached)"), std::string::npos) << table;
  EXPECT_NE(table.find("\n1 evaluation, 13 of the Jacobian"), std::string::npos) << table;
  EXPECT_NE(table.find("experiment 1 (ds-1): 1 sample\n"), std::string::npos) << table;
  EXPECT_NE(table.find("(each at 95 %; 1 sample, lags"), std::string::npos) << table;
}

TEST(EstimationTables, CorrelationsMarkTheHighOnesAndLeaveTheFixedOut) {
  const std::string table = correlation_table(two_tank_estimate());
  EXPECT_EQ(line_of(table, "A2"), "") << "a fixed parameter in the correlations:\n" << table;
  // Rows k1 and k2 against A1 (and k1): the lower triangle of A1, k1, k2.
  EXPECT_EQ(line_of(table, "k1 "), "k1          -0.970*") << table;
  EXPECT_EQ(line_of(table, "k2 "), "k2           0.200    0.100 ") << table;
  EXPECT_NE(table.find("(|r| near 1:"), std::string::npos) << table;
  v1::EstimationResult apart = two_tank_estimate();
  apart.mutable_correlation()->set_values(2, -0.5);
  apart.mutable_correlation()->set_values(8, -0.5);
  EXPECT_EQ(line_of(correlation_table(apart), "k1 "), "k1          -0.500 ") << correlation_table(apart);
  // One free parameter: nothing to correlate.
  apart.mutable_fixed()->Set(0, true);
  apart.mutable_fixed()->Set(3, true);
  EXPECT_EQ(correlation_table(apart), "");
}

TEST(EstimationTables, DiagnosticsAreATablePerTestWithNamesPValuesAndDof) {
  // The p-values and dof are riccatid's (made up here, so that a CLI that
  // recomputed them would print something else).
  const auto two = parse_text<v1::Diagnostics>(R"pb(
    samples: 2000 lags: 20 band: 0.0438
    ljung_box: [ 25.0, 40.0 ] ljung_box_limit: 31.410432844230922 ljung_box_dof: 20 ljung_box_p: [ 0.123, 0.00456 ]
    cross_statistic: [ 10, 50 ] cross_limit: [ 32.670573340917301, 32.670573340917301 ]
    cross_dof: [ 21, 21 ] cross_p: [ 0.777, 0.000888 ]
    nis_mean: 2.3 nis_lower: 1.91 nis_upper: 2.09 nis_consistent: false nis_dof: 4000 nis_p: 0.00321
  )pb");
  const std::string table = diagnostics_table(two, ModelNames{{}, {"F1_inflow"}, {"level_h1", "h2"}});
  const auto words_of = [](const std::string& line) {
    std::istringstream in(line);
    std::vector<std::string> out;
    for (std::string w; in >> w;) out.push_back(w);
    return out;
  };
  const auto words = [&](const std::string& start) { return words_of(line_of(table, start)); };
  EXPECT_NE(table.find("    whiteness: Ljung-Box Q over lags 1..20\n"), std::string::npos) << table;
  EXPECT_EQ(words("      output  "), (std::vector<std::string>{"output", "Q", "limit", "p-value", "dof", "verdict"}))
      << table;
  // By name: output, Q, limit, p-value, dof, verdict.
  EXPECT_EQ(words("      level_h1 "), (std::vector<std::string>{"level_h1", "25", "31.41", "0.123", "20", "pass"}))
      << table;
  EXPECT_EQ(words("      h2  "), (std::vector<std::string>{"h2", "40", "31.41", "0.00456", "20", "FAIL"})) << table;
  EXPECT_NE(table.find("    independence from inputs: N R^2 of the residual on the input at lags 0..20\n"),
            std::string::npos)
      << table;
  EXPECT_EQ(words("      level_h1 F1_inflow"),
            (std::vector<std::string>{"level_h1", "F1_inflow", "10", "32.67", "0.777", "21", "pass"}))
      << table;
  EXPECT_EQ(words("      h2       F1_inflow"),
            (std::vector<std::string>{"h2", "F1_inflow", "50", "32.67", "0.000888", "21", "FAIL"}))
      << table;
  EXPECT_NE(table.find("    noise consistency: mean NIS in its band (two-sided)\n"), std::string::npos) << table;
  const std::vector<std::string> nis = words(std::string(6 + 9, ' ') + "2.3");
  EXPECT_EQ(nis, (std::vector<std::string>{"2.3", "[1.91,", "2.09]", "0.00321", "4000", "FAIL"})) << table;
  // No names: numbered. A constant input: not tested, no p-value.
  v1::Diagnostics constant = two;
  constant.set_cross_limit(0, 0.0);
  constant.set_cross_dof(0, 0);
  constant.set_cross_p(0, 1.0);
  const std::string numbered = diagnostics_table(constant, {});
  EXPECT_EQ(words_of(line_of(numbered, "      y1     u1    ")),
            (std::vector<std::string>{"y1", "u1", "10", "0", "-", "0", "pass", "(constant", "input:", "not", "tested)"}))
      << numbered;
  // No NIS (output error): no table for it.
  v1::Diagnostics oe = two;
  oe.set_nis_mean(std::numeric_limits<double>::quiet_NaN());
  EXPECT_EQ(diagnostics_table(oe, {}).find("NIS"), std::string::npos);
  // A result stored before riccatid sent p-values and dof: "-", not a number made up.
  v1::Diagnostics old = two;
  old.clear_ljung_box_p();
  old.clear_ljung_box_dof();
  old.clear_cross_dof();
  old.clear_cross_p();
  old.clear_nis_dof();
  const std::string stored = diagnostics_table(old, ModelNames{{}, {"F1"}, {"h1", "h2"}});
  EXPECT_EQ(words_of(line_of(stored, "      h1  ")), (std::vector<std::string>{"h1", "25", "31.41", "-", "-", "pass"}))
      << stored;
}

TEST(EstimationTables, TheNoiseLevelsOfMaximumLikelihood) {
  v1::EstimationResult ml = two_tank_estimate();
  ml.set_method(v1::IDENTIFICATION_METHOD_ML);
  for (double r : {2.4e-5, 2.6e-5}) ml.add_measurement_noise(r);
  for (double s : {1e-6, 1.2e-6}) ml.add_measurement_noise_std(s);
  for (double q : {0.0, 0.0}) ml.add_process_noise(q);
  for (double s : {0.0, 0.0}) ml.add_process_noise_std(s);
  const std::string table = estimation_table(ml, {}, {}, ModelNames{{"h1", "h2"}, {"F1", "F2"}, {"h1", "h2"}});
  EXPECT_NE(table.find("method ml:"), std::string::npos) << table;
  EXPECT_NE(table.find("measurement noise R (diagonal): h1 2.4e-05 (std 1e-06), h2 2.6e-05 (std 1.2e-06)\n"),
            std::string::npos)
      << table;
  EXPECT_NE(table.find("process noise Q (states' diagonal): h1 0, h2 0 (given)\n"), std::string::npos) << table;
}

TEST(EstimationTables, TheCsvHasEverySampleOfEveryExperiment) {
  v1::EstimationResult r = two_tank_estimate();
  *r.add_experiments() = r.experiments(0);
  r.mutable_experiments(1)->set_t(1, 5.0);
  const std::string csv = estimation_csv(r, {});
  std::istringstream lines(csv);
  std::vector<std::string> rows;
  for (std::string line; std::getline(lines, line);) rows.push_back(line);
  ASSERT_EQ(rows.size(), 5u) << csv;
  EXPECT_EQ(rows[0],
            "experiment,t,y.h1,y.h2,y_model.h1,y_model.h2,residual.h1,residual.h2,residual_normalised.h1,"
            "residual_normalised.h2,used.h1,used.h2");
  // 17 digits: the doubles exactly; the raw residual y - y_model, the normalised one as the result has it.
  std::ostringstream raw;
  raw.precision(17);
  raw << 0.41 - 0.409 << "," << 0.16 - 0.161;
  EXPECT_EQ(rows[2], "1,1,0.40999999999999998,0.16,0.40899999999999997,0.161," + raw.str() +
                         ",0.20000000000000001,-0.20000000000000001,0,1");
  EXPECT_EQ(rows[4].substr(0, 4), "2,5,");
}

v1::SmoothingResult smoothed() {
  return parse_text<v1::SmoothingResult>(R"pb(
    names: [ "h1", "A1" ]
    t: [ 0, 1, 2 ]
    z_filtered { rows: 2 cols: 3 values: [ 0.4, 10, 0.41, 10.5, 0.42, 10.2 ] }
    std_filtered { rows: 2 cols: 3 values: [ 0.01, 1, 0.008, 0.5, 0.006, 0.3 ] }
    z_smoothed { rows: 2 cols: 3 values: [ 0.401, 10.1, 0.411, 10.15, 0.419, 10.2 ] }
    std_smoothed { rows: 2 cols: 3 values: [ 0.005, 0.3, 0.004, 0.3, 0.006, 0.3 ] }
    y_model { rows: 1 cols: 3 values: [ 0.401, 0.411, 0.419 ] }
    innovations { rows: 1 cols: 3 values: [ 0, 0.001, -0.002 ] }
  )pb");
}

TEST(SmoothingTables, StartEndAndTheMeanStdFilteredAndSmoothed) {
  const std::string table = smoothing_table(smoothed());
  EXPECT_NE(table.find("smoothed over 3 samples, t = 0 to 2\n"), std::string::npos) << table;
  std::istringstream a1(line_of(table, "A1 "));
  std::string name;
  double start = 0, start_std = 0, end = 0, end_std = 0, filtered = 0, smooth = 0;
  a1 >> name >> start >> start_std >> end >> end_std >> filtered >> smooth;
  EXPECT_EQ(start, 10.1);
  EXPECT_EQ(end_std, 0.3);
  EXPECT_NEAR(filtered, 0.6, 1e-12);  // (1 + 0.5 + 0.3) / 3
  EXPECT_NEAR(smooth, 0.3, 1e-12);

  const std::string csv = smoothing_csv(smoothed(), ModelNames{{}, {}, {"h1"}});
  std::istringstream lines(csv);
  std::string header, first;
  std::getline(lines, header);
  std::getline(lines, first);
  EXPECT_EQ(header,
            "t,h1,A1,std.h1,std.A1,filtered.h1,filtered.A1,filtered_std.h1,filtered_std.A1,y_model.h1,innovation.h1");
  EXPECT_EQ(first, "0,0.40100000000000002,10.1,0.0050000000000000001,0.29999999999999999,0.40000000000000002,10,"
                   "0.01,1,0.40100000000000002,0");
}

// `riccati result` and `riccati jobs` for the new kinds of job.
TEST(ResultTables, EachKindOfResultHasItsTableAndJobsTheirProgress) {
  v1::JobResult estimation;
  *estimation.mutable_estimation() = two_tank_estimate();
  EXPECT_EQ(result_table(estimation, {20, 20, 1, 1}, {}, {}), estimation_table(two_tank_estimate(), {20, 20, 1, 1}, {}, {}));
  EXPECT_EQ(result_csv(estimation, {}), estimation_csv(two_tank_estimate(), {}));
  v1::JobResult smoothing;
  *smoothing.mutable_smoothing() = smoothed();
  EXPECT_EQ(result_table(smoothing, {}, {}, {}), smoothing_table(smoothed()));

  v1::Job job = parse_text<v1::Job>(R"pb(
    id: "job-1" state: JOB_STATE_RUNNING identification { model: "two_tank" method: IDENTIFICATION_METHOD_ML }
    progress { pass_number: 2 passes: 2 sample: 2000 samples: 2000 iteration: 7 cost: -4779.23 }
  )pb");
  EXPECT_NE(job_line(job).find("identification  running    -                    two_tank             -                      "
                               "iteration 7, cost -4779.23"),
            std::string::npos)
      << job_line(job);
  job = parse_text<v1::Job>(R"pb(
    id: "job-2" state: JOB_STATE_QUEUED smoothing { model: "rotating_arm" dataset_id: "ds-7" }
    progress { pass_number: 1 passes: 2 } created { seconds: 1795000000 }
  )pb");
  EXPECT_NE(job_line(job).find("smoothing       queued     2026-11-18T11:06:40Z rotating_arm         ds-7                   "
                               "pass 1/2"),
            std::string::npos)
      << job_line(job);

  // A validation says where its parameters and initial states came from.
  const auto validation = parse_text<v1::ValidationResult>(R"pb(
    theta: [ 10, 5 ] x0: [ 0.4, 0.15 ] parameters_from: "job job-1: its oe estimate"
    x0_from: "fitted by output error on the first 100 samples"
    fits { name: "h1" rmse: 0.001 fit_percent: 99.5 vaf_percent: 99.9 rrse: 0.005 }
  )pb");
  const std::string fits = fit_table(validation);
  EXPECT_EQ(fits.substr(0, fits.find("output  ")),
            "parameters: job job-1: its oe estimate [10, 5]\nx0: fitted by output error on the first 100 samples "
            "[0.4, 0.15]\nfit of the simulation:\n");
  EXPECT_NE(line_of(fits, "h1 ").find("99.500"), std::string::npos) << fits;
  // A prediction says how many samples ahead, and by what.
  auto predicted = validation;
  predicted.set_horizon(3);
  predicted.set_predictor("ekf of job job-1 (Q as the job ran, R as the job ran, the states' P0), 3 samples ahead");
  const std::string ahead = fit_table(predicted);
  EXPECT_NE(ahead.find("\nfit of the 3-step-ahead predictions: ekf of job job-1 (Q as the job ran"), std::string::npos)
      << ahead;
}

TEST(Lists, ParseNumbersStrictly) {
  std::vector<double> v;
  std::string error;
  ASSERT_TRUE(parse_list("1, 2.5,-3e-2", &v, &error));
  EXPECT_EQ(v, (std::vector<double>{1, 2.5, -3e-2}));
  EXPECT_FALSE(parse_list("1,x", &v, &error));
  EXPECT_NE(error.find("\"x\" is not a number"), std::string::npos);
}

// Nothing listens on 127.0.0.1:1 (riccati() above): the message says so in
// words, with the address, for every command that calls riccatid.
TEST(Unreachable, TheMessageNamesTheAddressAndTheCause) {
  for (const std::string args : {"models", "health", "jobs"}) {
    const CliRun run = riccati(args);
    EXPECT_EQ(run.exit_code, 3) << args << ": " << run.out;
    EXPECT_EQ(run.out, "riccati: cannot reach riccatid at 127.0.0.1:1 (connection refused); is it running?\n")
        << args;
  }
  const grpc::Status refused(grpc::StatusCode::UNAVAILABLE,
                             "failed to connect to all addresses; last error: UNKNOWN: ipv4:10.0.0.7:7531: Failed to "
                             "connect to remote host: No route to host");
  EXPECT_EQ(unreachable_message("10.0.0.7:7531", refused),
            "cannot reach riccatid at 10.0.0.7:7531 (no route to host); is it running?");
  const grpc::Status other(grpc::StatusCode::UNAVAILABLE, "riccatid is shutting down");
  EXPECT_EQ(unreachable_message("10.0.0.7:7531", other), "riccatid is shutting down");
}

TEST(Commands, AnUnknownOneIsNamedWithTheNearest) {
  CliRun run = riccati("modles");
  EXPECT_EQ(run.exit_code, 2);
  EXPECT_EQ(run.out, "riccati: unknown command \"modles\"; did you mean \"models\"? (riccati --help lists the commands)\n");
  run = riccati("--json idnetify --model two_tank");
  EXPECT_EQ(run.exit_code, 2);
  EXPECT_NE(run.out.find("did you mean \"identify\"?"), std::string::npos) << run.out;
  run = riccati("frobnicate");
  EXPECT_EQ(run.out, "riccati: unknown command \"frobnicate\" (riccati --help lists the commands)\n");
  EXPECT_NE(riccati("").out.find("A subcommand is required"), std::string::npos) << "no word: CLI11's usage";
}

TEST(Commands, GlobalFlagsAfterTheCommand) {
  // --server, --timeout and --json after the command (and after its own subcommand).
  CliRun run = riccati_raw("models --server 127.0.0.1:1 --timeout 1 --json");
  EXPECT_EQ(run.exit_code, 3) << run.out;
  EXPECT_NE(run.out.find("cannot reach riccatid at 127.0.0.1:1"), std::string::npos) << run.out;
  run = riccati_raw("models show two_tank --server=127.0.0.1:1 --timeout 1");
  EXPECT_NE(run.out.find("cannot reach riccatid at 127.0.0.1:1"), std::string::npos) << run.out;
  run = riccati_raw("job show job-1 --timeout 1 --server 127.0.0.1:1");
  EXPECT_NE(run.out.find("cannot reach riccatid at 127.0.0.1:1"), std::string::npos) << run.out;
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

// The interval riccatid reports (not estimate -+ 1.96 std), the filter's own
// std beside it, which covariance it is, and a truth outside it marked.
TEST(Tables, ParameterTableShowsTheIntervalsAndTheFiltersStd) {
  v1::IdentificationResult r;
  r.add_param_names("A1");
  r.add_theta_mean(9.9);
  r.add_theta_std(0.01);
  r.add_theta(9.95);
  r.add_ci_lower(9.85);
  r.add_ci_upper(9.93);
  r.add_filter_theta_std(0.003);
  r.set_covariance_method("output error at the estimate: white residuals: s2 (J'J)^-1");
  r.add_warnings("the estimate has not settled after 10 passes");
  const std::string table = parameter_table(r, {20.0}, {10.0});
  EXPECT_NE(table.find("[9.85, 9.93]"), std::string::npos) << table;
  EXPECT_NE(table.find("0.003"), std::string::npos) << table;
  EXPECT_NE(table.find("(outside the interval)"), std::string::npos) << table;
  EXPECT_NE(table.find("std. error and interval: output error at the estimate: white residuals"), std::string::npos)
      << table;
  EXPECT_NE(table.find("  the estimate has not settled after 10 passes\n"), std::string::npos) << table;
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

// ------------------------------------------------------------ the settings come from the proto

// Every setting of every request the CLI writes is a flag of its command,
// with the proto's help, and a job-file key under its path: nothing listed
// by hand stands between a field with the option and the command line.
TEST(SchemaFlags, EveryRequestSettingIsAFlagOfItsCommand) {
  const std::vector<std::pair<std::string, const google::protobuf::Descriptor*>> commands = {
      {"identify", v1::IdentificationSpec::descriptor()}, {"stream", v1::CreateSessionRequest::descriptor()},
      {"smooth", v1::SmoothingSpec::descriptor()},        {"validate", v1::ValidationSpec::descriptor()},
      {"simulate", v1::SimulateRequest::descriptor()},    {"sessions retune", v1::RetuneSessionRequest::descriptor()}};
  for (const auto& [command, request] : commands) {
    const CliRun help = riccati_raw(command + " --help");
    ASSERT_EQ(help.exit_code, 0) << help.out;
    int offered = 0;
    for (const api::SettingField& s : api::settings_of(*request)) {
      if (!api::offered(*request, s)) {
        EXPECT_EQ(help.out.find(s.setting->flag() + " "), std::string::npos) << command << " offers " << s.path;
        continue;
      }
      ++offered;
      EXPECT_NE(help.out.find(s.setting->flag()), std::string::npos) << command << ": " << s.path;
      // The help's first words are the proto's.
      const std::string words = s.setting->help().substr(0, 20);
      EXPECT_NE(help.out.find(words), std::string::npos) << command << ": " << s.path << ": " << words;
    }
    EXPECT_GT(offered, 0) << command;
  }
}

TEST(SchemaFlags, EveryIdentificationSettingIsAJobFileKeyAtItsPath) {
  for (const api::SettingField& s : api::settings_of(*v1::IdentificationSpec::descriptor())) {
    std::string value;
    switch (s.kind) {
      case api::ValueKind::kNumber: value = "0.5"; break;
      case api::ValueKind::kCount: value = "3"; break;
      case api::ValueKind::kSwitch: value = "true"; break;
      case api::ValueKind::kChoice: value = api::enum_choice_names(*s.field->enum_type()).back(); break;
      case api::ValueKind::kNumbers: value = "[1, 2]"; break;
      case api::ValueKind::kNames: value = "[h1]"; break;
      case api::ValueKind::kCovariance: value = "[1, 2]"; break;
      case api::ValueKind::kInitialState: value = "[0.1, 0.2]"; break;
      case api::ValueKind::kBounds: value = "['A1=1:2']"; break;
      case api::ValueKind::kFixed: value = "[A2]"; break;
      case api::ValueKind::kText: value = "x"; break;
    }
    const RunSettings file = from_job_file("riccati-job-path.yaml", s.path + ": " + value + "\n");
    const v1::IdentificationSpec spec = to_identification_spec(file, "ds-1");
    EXPECT_TRUE(api::is_given(spec, s)) << s.path << ": " << value;
  }
}

// riccatid names the API's fields; the CLI puts the flag beside each.
TEST(SchemaFlags, MessagesNameTheFlagBesideTheField) {
  EXPECT_EQ(with_flags("filter.r is required"), "filter.r (--r) is required");
  EXPECT_EQ(with_flags("filter.r.diagonal needs 2 values, got 3"), "filter.r.diagonal (--r) needs 2 values, got 3");
  EXPECT_EQ(with_flags("initial_state.estimate: model two_tank has no state \"h3\""),
            "initial_state.estimate (--estimate-x0): model two_tank has no state \"h3\"");
  EXPECT_EQ(with_flags("bounds: model two_tank has no parameter \"A3\""),
            "bounds (--bound): model two_tank has no parameter \"A3\"");
  EXPECT_EQ(with_flags("estimation.estimate_process_noise applies to method ml only, not to oe"),
            "estimation.estimate_process_noise (--estimate-q) applies to method ml only, not to oe");
  // A flag that is the field's own name needs nothing; an English word is left alone.
  EXPECT_EQ(with_flags("passes applies to method filter only, not to oe"),
            "passes applies to method filter only, not to oe");
  EXPECT_EQ(with_flags("the job asks for 12 passes, more than max_passes"),
            "the job asks for 12 passes, more than max_passes");
  EXPECT_EQ(with_flags("dataset ds-1 has 2 outputs; the fixed point"), "dataset ds-1 has 2 outputs; the fixed point");
}

}  // namespace
}  // namespace riccati::cli
