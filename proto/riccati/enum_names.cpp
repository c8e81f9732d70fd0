#include "riccati/enum_names.hpp"

#include <cctype>

#include "riccati/v1/common.pb.h"

namespace riccati::api {
namespace {

// The prefix of an enum's value names, as protobuf's style guide has it:
// the enum's name in upper snake case (FilterKind: "FILTER_KIND_").
std::string value_prefix(const google::protobuf::EnumDescriptor& e) {
  std::string prefix;
  for (const char c : e.name()) {
    if (std::isupper(static_cast<unsigned char>(c)) && !prefix.empty()) prefix += '_';
    prefix += static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  }
  return prefix + '_';
}

}  // namespace

std::string enum_value_name(const google::protobuf::EnumValueDescriptor& value) {
  const std::string& short_name = value.options().GetExtension(v1::short_name);
  if (!short_name.empty()) return short_name;
  std::string_view name = value.name();
  const std::string prefix = value_prefix(*value.type());
  if (name.starts_with(prefix)) name.remove_prefix(prefix.size());
  std::string out;
  for (const char c : name) out += c == '_' ? '-' : static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

std::vector<const google::protobuf::EnumValueDescriptor*> enum_choices(const google::protobuf::EnumDescriptor& e) {
  std::vector<const google::protobuf::EnumValueDescriptor*> out;
  for (int i = 0; i < e.value_count(); ++i) {
    if (e.value(i)->number() != 0) out.push_back(e.value(i));
  }
  return out;
}

const google::protobuf::EnumValueDescriptor* find_enum_value(const google::protobuf::EnumDescriptor& e,
                                                             std::string_view name) {
  for (const auto* value : enum_choices(e)) {
    if (enum_value_name(*value) == name) return value;
  }
  return nullptr;
}

std::vector<std::string> enum_choice_names(const google::protobuf::EnumDescriptor& e) {
  std::vector<std::string> names;
  for (const auto* value : enum_choices(e)) names.push_back(enum_value_name(*value));
  return names;
}

std::string enum_choice_list(const google::protobuf::EnumDescriptor& e) {
  std::string list;
  for (const std::string& name : enum_choice_names(e)) list += (list.empty() ? "" : ", ") + name;
  return list;
}

}  // namespace riccati::api
