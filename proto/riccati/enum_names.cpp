#include "riccati/enum_names.hpp"

#include <cctype>

#include "riccati/v1/common.pb.h"

namespace riccati::api {
namespace {

// The prefix every value of the enum shares: "FILTER_KIND_" for FilterKind.
std::string common_prefix(const google::protobuf::EnumDescriptor& e) {
  if (e.value_count() == 0) return "";
  std::string prefix = e.value(0)->name();
  for (int i = 1; i < e.value_count(); ++i) {
    const std::string& name = e.value(i)->name();
    std::size_t n = 0;
    while (n < prefix.size() && n < name.size() && prefix[n] == name[n]) ++n;
    prefix.resize(n);
  }
  // Up to and including the last underscore: a whole word.
  const std::size_t underscore = prefix.rfind('_');
  return underscore == std::string::npos ? "" : prefix.substr(0, underscore + 1);
}

}  // namespace

std::string enum_value_name(const google::protobuf::EnumValueDescriptor& value) {
  const std::string& short_name = value.options().GetExtension(v1::short_name);
  if (!short_name.empty()) return short_name;
  std::string name = value.name().substr(common_prefix(*value.type()).size());
  for (char& c : name) c = c == '_' ? '-' : static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return name;
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

std::string enum_choice_list(const google::protobuf::EnumDescriptor& e) {
  const auto choices = enum_choices(e);
  std::string list;
  for (std::size_t i = 0; i < choices.size(); ++i) {
    if (i > 0) list += i + 1 == choices.size() ? " or " : ", ";
    list += enum_value_name(*choices[i]);
  }
  return list;
}

}  // namespace riccati::api
