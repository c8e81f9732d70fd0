// The filter kinds, described once: what each is called, what it is, which
// noise settings it takes, how its settings are checked and how it is made.
//
// Everything else derives from this table: make_filter() and validate()
// dispatch through it, riccati-engine lists it in its help, and the service
// maps the API's FilterKind enum onto it by name (the enum value's short
// name, riccati.v1.short_name, is the name here). A new kind is a Filter in
// its own file in filters/, a value of FilterKind (filter.hpp), a row of the
// table (filter_kinds.cpp) and a value of the API's enum (common.proto).
#pragma once

#include <memory>
#include <span>
#include <string>
#include <string_view>

#include "engine/filters/filter.hpp"

namespace riccati {

// Which noise settings a kind takes.
enum class NoiseSettings {
  kCovariances,     // process noise intensity Q and measurement noise covariance R (FilterSettings::Q, R)
  kOptimalWeights,  // the optimal filter's weights V and W (FilterSettings::optimal), no Q and R
};

struct FilterKindInfo {
  FilterKind kind;
  std::string_view name;     // "ekf": in the API, the CLI, job files and messages
  std::string_view summary;  // what it is, in a line (help texts)
  NoiseSettings noise;
  // Checks the settings particular to the kind against a model (the
  // integrator's are checked for every kind first).
  Status (*validate)(const FilterSettings& settings, const Model& model);
  // Makes the filter from validated settings.
  std::unique_ptr<Filter> (*make)(ModelPtr model, const FilterSettings& settings,
                                  std::unique_ptr<Integrator> integrator);
};

// Every kind, in the order of the enum.
std::span<const FilterKindInfo> filter_kinds();
const FilterKindInfo& filter_kind_info(FilterKind kind);
const char* filter_kind_name(FilterKind kind);
// The kind of that name; kInvalidArgument listing the names otherwise.
Result<FilterKind> parse_filter_kind(std::string_view name);
// "ekf, ukf or optimal": the names, for messages and help.
std::string filter_kind_names();

}  // namespace riccati
