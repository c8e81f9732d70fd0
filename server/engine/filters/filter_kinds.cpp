#include "engine/filters/filter_kinds.hpp"

namespace riccati {

// Each kind's validation and factory, defined with the filter.
Status validate_ekf(const FilterSettings& settings, const Model& model);
std::unique_ptr<Filter> make_ekf(ModelPtr model, const FilterSettings& settings,
                                 std::unique_ptr<Integrator> integrator);
Status validate_ukf(const FilterSettings& settings, const Model& model);
std::unique_ptr<Filter> make_ukf(ModelPtr model, const FilterSettings& settings,
                                 std::unique_ptr<Integrator> integrator);
Status validate_optimal_filter(const FilterSettings& settings, const Model& model);
std::unique_ptr<Filter> make_optimal_filter(ModelPtr model, const FilterSettings& settings,
                                            std::unique_ptr<Integrator> integrator);

namespace {

constexpr FilterKindInfo kFilterKinds[] = {
    {FilterKind::kEkf, "ekf", "continuous-discrete extended Kalman filter (Hensen 1999)", NoiseSettings::kCovariances,
     &validate_ekf, &make_ekf},
    {FilterKind::kUkf, "ukf", "continuous-discrete unscented Kalman filter (Zheng, Ikeda, Shimomura 2010)",
     NoiseSettings::kCovariances, &validate_ukf, &make_ukf},
    {FilterKind::kOptimal, "optimal",
     "optimal filter of van de Molengraft and van Kessel, for mechanical models (M a + h = H u)",
     NoiseSettings::kOptimalWeights, &validate_optimal_filter, &make_optimal_filter},
};

}  // namespace

std::span<const FilterKindInfo> filter_kinds() { return kFilterKinds; }

const FilterKindInfo& filter_kind_info(FilterKind kind) {
  for (const FilterKindInfo& info : kFilterKinds) {
    if (info.kind == kind) return info;
  }
  return kFilterKinds[0];  // unreachable: every enum value has a row
}

const char* filter_kind_name(FilterKind kind) { return filter_kind_info(kind).name.data(); }

std::string filter_kind_names() {
  std::string names;
  const std::size_t n = std::size(kFilterKinds);
  for (std::size_t i = 0; i < n; ++i) {
    if (i > 0) names += i + 1 == n ? " or " : ", ";
    names += kFilterKinds[i].name;
  }
  return names;
}

Result<FilterKind> parse_filter_kind(std::string_view name) {
  for (const FilterKindInfo& info : kFilterKinds) {
    if (info.name == name) return info.kind;
  }
  return invalid_argument("unknown filter \"" + std::string(name) + "\" (expected " + filter_kind_names() + ")");
}

}  // namespace riccati
