// The names people write for the API's enum values: the CLI's flags and job
// files, the Python client, and the service's mapping onto the engine's
// settings (whose names are the same). A value's name is its
// riccati.v1.short_name option when it has one, else its own name without
// the enum's prefix, in lower case with hyphens: FILTER_KIND_EKF is "ekf",
// INTEGRATOR_KIND_CVODE_BDF "cvode-bdf", HOLD_ORDER_ZERO (short_name) "zoh".
// Lists come from the descriptor, so a value added to the proto reaches every
// client without a change.
#pragma once

#include <google/protobuf/descriptor.h>

#include <string>
#include <string_view>
#include <vector>

namespace riccati::api {

std::string enum_value_name(const google::protobuf::EnumValueDescriptor& value);
// The values people choose from: all but the *_UNSPECIFIED one (number 0).
std::vector<const google::protobuf::EnumValueDescriptor*> enum_choices(const google::protobuf::EnumDescriptor& e);
// The value of that name, or null.
const google::protobuf::EnumValueDescriptor* find_enum_value(const google::protobuf::EnumDescriptor& e,
                                                             std::string_view name);
std::vector<std::string> enum_choice_names(const google::protobuf::EnumDescriptor& e);
// "ekf, ukf, optimal": the choices' names, for help texts and messages.
std::string enum_choice_list(const google::protobuf::EnumDescriptor& e);

}  // namespace riccati::api
