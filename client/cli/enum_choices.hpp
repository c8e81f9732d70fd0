// The names users write for the values of an API enum (flags and job-file
// keys such as --filter or integrator.kind), taken from the enum's
// descriptor: a value added to the proto is offered here, in --help and in
// errors, with no change to the command line.
//
// A value's name is its riccati.v1.short_name option when it has one
// (HOLD_ORDER_ZERO: "zoh"), else its own name without the enum's prefix, in
// lower case with hyphens (FILTER_KIND_EKF: "ekf", INTEGRATOR_KIND_CVODE_BDF:
// "cvode-bdf"). Value 0 (*_UNSPECIFIED) is no choice: a setting left out is
// left to riccatid's default.
#pragma once

#include <google/protobuf/descriptor.h>

#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace riccati::cli {

std::string choice_name(const google::protobuf::EnumValueDescriptor& value);

// The names of every value but the unspecified one, in the proto's order.
std::vector<std::string> choice_names(const google::protobuf::EnumDescriptor& type);

// The names as a list for help and errors: "ekf, ukf, optimal".
std::string choices_text(const google::protobuf::EnumDescriptor& type);

// The value named `name`, or nothing with an error that lists the choices.
std::optional<int> parse_choice(const google::protobuf::EnumDescriptor& type, std::string_view name,
                                std::string* error);

}  // namespace riccati::cli
