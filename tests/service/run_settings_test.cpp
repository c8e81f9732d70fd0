// The API's settings onto the engine's: every enum maps by name in both
// directions (so the proto and the engine's tables are the only lists), and
// a covariance may be one value, a diagonal or a full matrix.
#include <gtest/gtest.h>

#include "engine/filters/filter_kinds.hpp"
#include "engine/models/plugin_loader.hpp"
#include "riccati/enum_names.hpp"
#include "service/convert.hpp"
#include "service/run_settings.hpp"

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

}  // namespace
}  // namespace riccati::service
