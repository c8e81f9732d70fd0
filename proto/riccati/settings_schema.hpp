// The settings of the API's requests, read from the proto's field options
// (riccati.v1.setting, common.proto): the one schema that the CLI's flags
// and job files, the Python client's keywords, the HTTP API's schema and the
// workbench's forms are made from, and that riccatid checks requests against
// (a field given where its method or filter kind does not take it).
//
// A setting is a field with the option. settings_of() walks a request's
// fields depth first: an annotated field is a setting; a singular message
// field is walked into (IdentificationSpec.filter: filter.q, filter.ukf.alpha,
// ...). Repeated message fields other than settings (experiments) are not
// walked. A setting's value is one of a few kinds (value_kind()): numbers,
// names, choices, and five messages with a text form of their own
// (Covariance, InitialState, ParameterBound, FixedParameter).
#pragma once

#include <google/protobuf/descriptor.h>
#include <google/protobuf/message.h>

#include <string>
#include <string_view>
#include <vector>

#include "riccati/v1/common.pb.h"

namespace riccati::api {

enum class ValueKind {
  kNumber,        // double
  kCount,         // unsigned integer
  kSwitch,        // bool
  kText,          // string
  kChoice,        // an enum: one of its value names (enum_names.hpp)
  kNumbers,       // repeated double
  kNames,         // repeated string
  kCovariance,    // one value (the diagonal), the diagonal, or rows
  kInitialState,  // "first" or the values x0
  kBounds,        // repeated ParameterBound: NAME=LO:HI
  kFixed,         // repeated FixedParameter: NAME[=VALUE]
};

struct SettingField {
  std::string path;  // from the request: "filter.integrator.substeps"
  // The fields from the request's down to the setting's.
  std::vector<const google::protobuf::FieldDescriptor*> chain;
  const google::protobuf::FieldDescriptor* field = nullptr;  // chain.back()
  const v1::Setting* setting = nullptr;                      // its option
  ValueKind kind = ValueKind::kText;
};

// Every setting of a request type, in the order of its fields.
const std::vector<SettingField>& settings_of(const google::protobuf::Descriptor& request);
// The method a request without a method setting stands for: "filter" for
// sessions and smoothing (they run a filter); empty for the others.
std::string_view implied_method(const google::protobuf::Descriptor& request);
// Whether a client offers the setting for the request: not one that only
// methods or filter kinds the request cannot have take (a session's
// initial_state.estimate, a smoothing's filter.optimal.v).
bool offered(const google::protobuf::Descriptor& request, const SettingField& s);
// The setting at `path` of `request`, or null.
const SettingField* find_setting(const google::protobuf::Descriptor& request, std::string_view path);
// The setting whose flag is `flag` ("--q"), or null.
const SettingField* find_setting_by_flag(const google::protobuf::Descriptor& request, std::string_view flag);

// The kind of a setting's value; kText for a field no surface can write
// (settings_of() refuses those when it walks them: a test checks every request).
ValueKind value_kind(const google::protobuf::FieldDescriptor& field);
const char* value_kind_name(ValueKind kind);  // "number", "covariance", ...

// Whether the request gives the setting: a set message or optional field, a
// scalar that is not its default, a list that is not empty.
bool is_given(const google::protobuf::Message& request, const SettingField& s);
// The message that holds the setting's field, made where it is not yet.
google::protobuf::Message* mutable_holder(google::protobuf::Message* request, const SettingField& s);
// The keyword of the Python client: the flag without its dashes, '-' as '_'.
std::string keyword_of(const v1::Setting& setting);

// The short name of the choice at `path` ("method", "filter.kind"), its
// setting's default_value where the request leaves it unspecified; empty
// where the request has no such setting.
std::string choice_of(const google::protobuf::Message& request, std::string_view path);

// A setting given where the request's method or filter kind does not take
// it: "passes applies to method filter only, not to oe"; empty when none is.
// `method` and `filter` are short names ("oe", "ukf"); an empty one is not checked.
std::string misplaced_setting(const google::protobuf::Message& request, std::string_view method,
                              std::string_view filter);

// The schema of the requests that take settings, as JSON (GET /api/v1/schema):
// {"requests": {"IdentificationSpec": [{"path": ..., "flag": ..., "keyword": ...,
// "kind": ..., "help": ..., "choices": [...], ...}, ...], ...},
//  "methods": [...], "filters": [...]}.
std::string settings_schema_json();

// The request types whose settings the clients write.
std::vector<const google::protobuf::Descriptor*> setting_requests();

}  // namespace riccati::api
