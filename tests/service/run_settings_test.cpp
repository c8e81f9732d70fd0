// The API's settings onto the engine's: every enum maps by name in both
// directions (so the proto and the engine's tables are the only lists), and
// a covariance may be one value, a diagonal or a full matrix.
#include <gtest/gtest.h>

#include "engine/filters/filter_kinds.hpp"
#include "engine/models/plugin_loader.hpp"
#include "riccati/enum_names.hpp"
#include "service/convert.hpp"
#include "service/jobs/identification_job.hpp"
#include "service/run_settings.hpp"

#include "riccati/settings_schema.hpp"
#include <map>
#include <set>

namespace riccati::service {
namespace {

const ModelRegistry& models() {
  static const ModelRegistry registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
  return registry;
}

v1::FilterSettings two_tank_ekf() {
  v1::FilterSettings s;
  s.mutable_r()->set_scalar(1e-3);
  return s;
}

TEST(RunSettings, EveryFilterKindOfTheApiIsAnEngineKindAndBack) {
  const auto& descriptor = *v1::FilterKind_descriptor();
  for (const auto* value : api::enum_choices(descriptor)) {
    FilterKind kind{};
    const Status mapped = enum_from_proto(value->number(), descriptor, &parse_filter_kind, "filter.kind", &kind);
    ASSERT_TRUE(mapped.is_ok()) << value->name() << ": " << mapped.message();
    EXPECT_EQ(filter_kind_name(kind), api::enum_value_name(*value));
    EXPECT_EQ(to_proto(kind), value->number());
  }
  for (const FilterKindInfo& info : filter_kinds()) {
    EXPECT_NE(to_proto(info.kind), v1::FILTER_KIND_UNSPECIFIED) << info.name << " has no value in the API";
  }
}

template <typename T>
void expect_every_value_maps(const google::protobuf::EnumDescriptor& descriptor, Result<T> (*parse)(std::string_view)) {
  for (const auto* value : api::enum_choices(descriptor)) {
    T engine{};
    const Status mapped = enum_from_proto(value->number(), descriptor, parse, descriptor.name(), &engine);
    EXPECT_TRUE(mapped.is_ok()) << value->name() << ": " << mapped.message();
  }
}

TEST(RunSettings, EverySettingsEnumOfTheApiMapsOntoTheEngine) {
  expect_every_value_maps(*v1::IntegratorKind_descriptor(), &parse_integrator_kind);
  expect_every_value_maps(*v1::HoldOrder_descriptor(), &parse_hold_order);
  expect_every_value_maps(*v1::GainInversion_descriptor(), &parse_gain_inversion);
  expect_every_value_maps(*v1::SigmaWeights_descriptor(), &parse_sigma_weights);
  expect_every_value_maps(*v1::OptimalForm_descriptor(), &parse_optimal_form);
}

TEST(RunSettings, UnspecifiedIsTheEngineDefaultAndAnUnknownNumberIsRefused) {
  const ModelPtr model = models().find("two_tank");
  v1::FilterSettings s = two_tank_ekf();
  auto settings = from_proto(s, *model);
  ASSERT_TRUE(settings.is_ok()) << settings.status().message();
  EXPECT_EQ(settings->kind, FilterSettings{}.kind);
  EXPECT_EQ(settings->integrator.kind, IntegratorSettings{}.kind);
  s.set_kind(static_cast<v1::FilterKind>(42));
  settings = from_proto(s, *model);
  ASSERT_FALSE(settings.is_ok());
  EXPECT_EQ(settings.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(settings.status().message().find("filter.kind 42 is unknown (expected ekf, ukf, optimal)"),
            std::string::npos)
      << settings.status().message();
}

TEST(RunSettings, ACovarianceIsOneValueADiagonalOrAFullMatrix) {
  v1::Covariance c;
  c.set_scalar(2.5);
  EXPECT_TRUE(from_covariance(c, 3, true, "q").value().isApprox(2.5 * Eigen::Matrix3d::Identity()));
  for (double v : {1.0, 2.0, 3.0}) c.mutable_diagonal()->add_values(v);
  EXPECT_TRUE(from_covariance(c, 3, true, "q").value().isApprox(Eigen::Vector3d(1, 2, 3).asDiagonal().toDenseMatrix()));
  c.set_scalar(std::numeric_limits<double>::infinity());
  EXPECT_EQ(from_covariance(c, 3, true, "q").status().message(), "q.scalar is not finite");
  const auto missing = from_covariance(v1::Covariance(), 3, true, "filter.r");
  ASSERT_FALSE(missing.is_ok());
  EXPECT_NE(missing.status().message().find("filter.r is required"), std::string::npos);
}

TEST(RunSettings, SettingsOfAnotherKindAreRefusedNamingTheField) {
  const ModelPtr two_tank = models().find("two_tank");
  v1::FilterSettings s = two_tank_ekf();
  s.mutable_optimal()->mutable_v()->set_scalar(1.0);
  auto settings = from_proto(s, *two_tank);
  ASSERT_FALSE(settings.is_ok());
  EXPECT_NE(settings.status().message().find("filter.optimal applies to the optimal filter only"), std::string::npos)
      << settings.status().message();

  const ModelPtr manipulator = models().find("flexible_manipulator");
  v1::FilterSettings optimal;
  optimal.set_kind(v1::FILTER_KIND_OPTIMAL);
  optimal.mutable_optimal()->mutable_v()->set_scalar(1e6);
  optimal.mutable_optimal()->mutable_w()->set_scalar(1e4);
  ASSERT_TRUE(from_proto(optimal, *manipulator).is_ok());
  optimal.mutable_r()->set_scalar(1e-3);
  settings = from_proto(optimal, *manipulator);
  ASSERT_FALSE(settings.is_ok());
  EXPECT_NE(settings.status().message().find("filter.q and filter.r do not apply to the optimal filter"),
            std::string::npos)
      << settings.status().message();
}

// An initial state given neither as "first" nor as values is "first", the
// default the schema documents: a form or keyword left empty sends nothing.
TEST(RunSettings, AnInitialStateLeftOutStartsAtTheFirstMeasurement) {
  const ModelPtr two_tank = models().find("two_tank");
  const google::protobuf::RepeatedField<double> theta0;
  const auto absent =
      initial_estimate_from_proto(v1::InitialState(), theta0, v1::Covariance(), two_tank_ekf(), *two_tank);
  ASSERT_TRUE(absent.is_ok()) << absent.status().message();
  EXPECT_EQ(absent.value().mode, InitialState::kFirstMeasurement);
  v1::InitialState first;
  first.set_first_measurement(true);
  const auto given = initial_estimate_from_proto(first, theta0, v1::Covariance(), two_tank_ekf(), *two_tank);
  ASSERT_TRUE(given.is_ok());
  EXPECT_TRUE(absent.value().P0.isApprox(given.value().P0));  // its default P0 too: 0 for the measured levels
  v1::InitialState values;
  values.add_x0(0.4);
  const auto short_x0 = initial_estimate_from_proto(values, theta0, v1::Covariance(), two_tank_ekf(), *two_tank);
  ASSERT_FALSE(short_x0.is_ok());
  EXPECT_NE(short_x0.status().message().find("initial_state.x0"), std::string::npos) << short_x0.status().message();
}

// The methods' table and the API's enum name the same methods, each once.
TEST(RunSettings, EveryIdentificationMethodOfTheApiIsARowOfTheTableAndBack) {
  const auto& descriptor = *v1::IdentificationMethod_descriptor();
  std::set<std::string> rows;
  for (const IdentificationMethodInfo& info : identification_methods()) {
    EXPECT_TRUE(rows.insert(std::string(info.name)).second) << info.name << " twice";
    EXPECT_EQ(&identification_method_info(info.method), &info);
    EXPECT_NE(api::find_enum_value(descriptor, info.name), nullptr) << info.name << " has no value in the API";
    EXPECT_TRUE(info.iterated_filter != info.optimiser) << info.name << ": passes or an optimiser, one of the two";
  }
  for (const auto* value : api::enum_choices(descriptor)) {
    IdentificationMethod method{};
    const Status mapped =
        enum_from_proto(value->number(), descriptor, &parse_identification_method, "method", &method);
    ASSERT_TRUE(mapped.is_ok()) << value->name() << ": " << mapped.message();
    EXPECT_EQ(identification_method_name(method), api::enum_value_name(*value));
  }
  EXPECT_EQ(parse_identification_method("pem").status().message(),
            "unknown identification method \"pem\" (expected filter, oe, ml)");
}

// ------------------------------------------------------------ the settings schema (riccati.v1.setting)

double number(const std::string& text) { return std::stod(text); }

// The defaults the schema tells every surface are the ones riccatid takes
// when a field is left out: one place for each, checked here.
TEST(SettingsSchema, ItsDefaultsAreWhatRiccatidTakes) {
  const auto default_of = [](const google::protobuf::Descriptor& request, const std::string& path) {
    const api::SettingField* s = api::find_setting(request, path);
    EXPECT_NE(s, nullptr) << path;
    return s == nullptr ? std::string() : s->setting->default_value();
  };
  const auto& spec = *v1::IdentificationSpec::descriptor();
  const Result<IntegratorSettings> made_integrator = from_proto(v1::IntegratorSettings{});
  ASSERT_TRUE(made_integrator.is_ok()) << made_integrator.status().message();
  const IntegratorSettings& integrator = made_integrator.value();
  EXPECT_EQ(integrator.substeps, number(default_of(spec, "filter.integrator.substeps")));
  EXPECT_EQ(integrator.rtol, number(default_of(spec, "filter.integrator.rtol")));
  EXPECT_EQ(integrator.atol, number(default_of(spec, "filter.integrator.atol")));
  EXPECT_EQ(integrator.max_steps, number(default_of(spec, "filter.integrator.max_steps")));
  EXPECT_EQ(integrator_kind_name(integrator.kind), default_of(spec, "filter.integrator.kind"));

  const ModelPtr model = models().find("two_tank");
  v1::IdentificationSpec oe;
  oe.set_dataset_id("ds-1");
  oe.set_method(v1::IDENTIFICATION_METHOD_OE);
  const Result<IdentificationJob> made = identification_from_proto(oe, *model);
  ASSERT_TRUE(made.is_ok()) << made.status().message();
  const IdentificationJob& job = made.value();
  const OptimizerSettings& optimizer = job.output_error.optimizer;
  EXPECT_EQ(optimizer.max_iterations, number(default_of(spec, "estimation.max_iterations")));
  EXPECT_EQ(optimizer.function_tolerance, number(default_of(spec, "estimation.function_tolerance")));
  EXPECT_EQ(optimizer.gradient_tolerance, number(default_of(spec, "estimation.gradient_tolerance")));
  EXPECT_EQ(optimizer.parameter_tolerance, number(default_of(spec, "estimation.parameter_tolerance")));
  EXPECT_EQ(job.init_passes, number(default_of(spec, "init_passes")));

  v1::IdentificationSpec filter;
  filter.set_dataset_id("ds-1");
  filter.mutable_filter()->mutable_r()->set_scalar(1e-3);
  const Result<IdentificationJob> made_filter = identification_from_proto(filter, *model);
  ASSERT_TRUE(made_filter.is_ok()) << made_filter.status().message();
  const IdentificationJob& passes = made_filter.value();
  EXPECT_EQ(passes.filter.passes, number(default_of(spec, "passes")));
  EXPECT_EQ(filter_kind_name(passes.filter.filter.kind), default_of(spec, "filter.kind"));
  EXPECT_EQ(api::choice_of(filter, "method"), "filter");
  EXPECT_EQ(api::choice_of(filter, "filter.kind"), "ekf");
  EXPECT_EQ(api::choice_of(filter, "filter.hold"), "zoh");
  EXPECT_EQ(api::choice_of(filter, "filter.inversion"), "cholesky");
}

// ML filters the states alone: its --q takes the states' nx intensities (a
// diagonal or an nx x nx matrix), the parameters' part zero; nz values still
// work, and another count is refused naming both.
TEST(IdentificationSettings, MaximumLikelihoodTakesTheStatesProcessNoise) {
  const ModelPtr model = models().find("two_tank");  // nx 2, ntheta 4
  v1::IdentificationSpec ml;
  ml.set_dataset_id("ds-1");
  ml.set_method(v1::IDENTIFICATION_METHOD_ML);
  ml.mutable_filter()->mutable_r()->set_scalar(1e-3);
  ml.mutable_filter()->mutable_q()->mutable_diagonal()->add_values(1e-6);
  ml.mutable_filter()->mutable_q()->mutable_diagonal()->add_values(2e-6);
  ml.mutable_estimation()->set_estimate_process_noise(true);
  Result<IdentificationJob> made = identification_from_proto(ml, *model);
  ASSERT_TRUE(made.is_ok()) << made.status().message();
  Eigen::MatrixXd expected = Eigen::MatrixXd::Zero(6, 6);
  expected(0, 0) = 1e-6;
  expected(1, 1) = 2e-6;
  EXPECT_EQ(made->max_likelihood.filter.Q, expected);

  v1::Matrix* full = ml.mutable_filter()->mutable_q()->mutable_full();
  full->set_rows(2);
  full->set_cols(2);
  for (double v : {1e-6, 5e-7, 5e-7, 2e-6}) full->add_values(v);
  made = identification_from_proto(ml, *model);
  ASSERT_TRUE(made.is_ok()) << made.status().message();
  expected(0, 1) = expected(1, 0) = 5e-7;
  EXPECT_EQ(made->max_likelihood.filter.Q, expected);

  for (double v : {1e-6, 2e-6, 0.0, 0.0, 0.0, 0.0}) ml.mutable_filter()->mutable_q()->mutable_diagonal()->add_values(v);
  made = identification_from_proto(ml, *model);
  ASSERT_TRUE(made.is_ok()) << made.status().message();
  expected(0, 1) = expected(1, 0) = 0.0;
  EXPECT_EQ(made->max_likelihood.filter.Q, expected);

  ml.mutable_filter()->mutable_q()->mutable_diagonal()->add_values(0.0);
  made = identification_from_proto(ml, *model);
  ASSERT_FALSE(made.is_ok());
  EXPECT_EQ(made.status().message(),
            "filter.q.diagonal needs 2 values (the states': method ml filters the states alone) or 6, got 7");

  // The iterated filter estimates the parameters too: its Q is nz x nz.
  v1::IdentificationSpec filter = ml;
  filter.set_method(v1::IDENTIFICATION_METHOD_FILTER);
  filter.clear_estimation();
  filter.mutable_filter()->mutable_q()->mutable_diagonal()->clear_values();
  filter.mutable_filter()->mutable_q()->mutable_diagonal()->add_values(1e-6);
  filter.mutable_filter()->mutable_q()->mutable_diagonal()->add_values(1e-6);
  made = identification_from_proto(filter, *model);
  ASSERT_FALSE(made.is_ok());
  EXPECT_EQ(made.status().message(), "filter.q.diagonal needs 6 values, got 2");
}

// What every surface relies on: a flag means one thing (the same kind of
// value in every request that has it), names are unique within a request,
// and what a setting applies to names real methods and filter kinds.
TEST(SettingsSchema, FlagsMeanOneThingAndNameRealMethodsAndKinds) {
  const std::vector<std::string> methods = api::enum_choice_names(*v1::IdentificationMethod_descriptor());
  const std::vector<std::string> kinds = api::enum_choice_names(*v1::FilterKind_descriptor());
  std::map<std::string, api::ValueKind> kind_of_flag;
  for (const google::protobuf::Descriptor* request : api::setting_requests()) {
    std::set<std::string> flags;
    for (const api::SettingField& s : api::settings_of(*request)) {
      const v1::Setting& o = *s.setting;
      EXPECT_TRUE(o.flag().starts_with("--")) << s.path;
      EXPECT_FALSE(o.help().empty()) << s.path;
      EXPECT_TRUE(flags.insert(o.flag()).second) << request->name() << ": " << o.flag() << " twice";
      const auto [it, first] = kind_of_flag.emplace(o.flag(), s.kind);
      EXPECT_EQ(it->second, s.kind) << o.flag() << " is another kind of value in " << request->name();
      EXPECT_TRUE(s.kind != api::ValueKind::kText || s.field->type() == google::protobuf::FieldDescriptor::TYPE_STRING)
          << s.path << ": a message no surface can write";
      for (const std::string& m : o.methods()) EXPECT_NE(std::find(methods.begin(), methods.end(), m), methods.end()) << s.path;
      for (const std::string& f : o.filters()) EXPECT_NE(std::find(kinds.begin(), kinds.end(), f), kinds.end()) << s.path;
      if (s.kind == api::ValueKind::kChoice && !o.default_value().empty()) {
        EXPECT_NE(api::find_enum_value(*s.field->enum_type(), o.default_value()), nullptr) << s.path;
      }
    }
  }
}

// A setting where its method or filter kind does not take it: one message,
// naming the field, the method or kind it is for and the one asked for.
TEST(SettingsSchema, ASettingWhereItDoesNotApplyIsRefusedNamingIt) {
  v1::IdentificationSpec spec;
  spec.set_method(v1::IDENTIFICATION_METHOD_OE);
  spec.set_passes(3);
  Status s = check_settings_apply(spec);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(s.message(), "passes applies to method filter only, not to oe");
  spec.clear_passes();
  spec.mutable_estimation()->set_estimate_measurement_noise(true);
  EXPECT_EQ(check_settings_apply(spec).message(),
            "estimation.estimate_measurement_noise applies to method ml only, not to oe");
  spec.set_method(v1::IDENTIFICATION_METHOD_ML);
  EXPECT_TRUE(check_settings_apply(spec).is_ok());
  spec.mutable_filter()->mutable_ukf()->set_alpha(0.5);
  EXPECT_EQ(check_settings_apply(spec).message(), "filter.ukf.alpha applies to the ukf filter only, not to the ekf filter");
  spec.mutable_filter()->set_kind(v1::FILTER_KIND_UKF);
  EXPECT_TRUE(check_settings_apply(spec).is_ok());

  // A session runs a filter: the states it does not estimate as output error does.
  v1::CreateSessionRequest session;
  session.mutable_initial_state()->add_estimate("all");
  EXPECT_EQ(check_settings_apply(session).message(),
            "initial_state.estimate applies to method oe and ml only, not to filter");
  // A retuning is checked against the session's kind.
  v1::RetuneSessionRequest retune;
  retune.mutable_v()->set_scalar(1.0);
  EXPECT_EQ(check_settings_apply(retune, "ekf").message(), "v applies to the optimal filter only, not to the ekf filter");
  EXPECT_TRUE(check_settings_apply(retune, "optimal").is_ok());
}

TEST(SettingsSchema, TheHttpSchemaListsEveryOfferedSetting) {
  const std::string json = api::settings_schema_json();
  for (const google::protobuf::Descriptor* request : api::setting_requests()) {
    EXPECT_NE(json.find("\"" + std::string(request->name()) + "\""), std::string::npos) << request->name();
    for (const api::SettingField& s : api::settings_of(*request)) {
      EXPECT_NE(json.find("\"path\":\"" + s.path + "\""), std::string::npos) << s.path;
    }
  }
  EXPECT_NE(json.find("\"keyword\":\"estimate_q\""), std::string::npos);
  EXPECT_NE(json.find("\"choices\":[\"filter\",\"oe\",\"ml\"]"), std::string::npos);
  // Beside them, the names a request's JSON gives them (the workbench sends these).
  EXPECT_NE(json.find("\"values\":[\"IDENTIFICATION_METHOD_FILTER\",\"IDENTIFICATION_METHOD_OE\","
                      "\"IDENTIFICATION_METHOD_ML\"]"),
            std::string::npos);
}

}  // namespace
}  // namespace riccati::service
