#include "enum_choices.hpp"

#include <cctype>

#include "riccati/v1/common.pb.h"

namespace riccati::cli {

namespace {

// The prefix of an enum's value names, as protobuf's style guide has it:
// the enum's name in upper snake case (FilterKind: "FILTER_KIND_").
std::string value_prefix(const google::protobuf::EnumDescriptor& type) {
  std::string prefix;
  for (const char c : type.name()) {
    if (std::isupper(static_cast<unsigned char>(c)) && !prefix.empty()) prefix += '_';
    prefix += static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  }
  return prefix + '_';
}

std::string in_quotes(std::string_view text) {
  std::string quoted(1, '"');
  quoted.append(text);
  quoted += '"';
  return quoted;
}

}  // namespace

std::string choice_name(const google::protobuf::EnumValueDescriptor& value) {
  const std::string& short_name = value.options().GetExtension(v1::short_name);
  if (!short_name.empty()) return short_name;
  std::string_view name = value.name();
  const std::string prefix = value_prefix(*value.type());
  if (name.starts_with(prefix)) name.remove_prefix(prefix.size());
  std::string out;
  for (const char c : name) out += c == '_' ? '-' : static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

std::vector<std::string> choice_names(const google::protobuf::EnumDescriptor& type) {
  std::vector<std::string> names;
  for (int i = 0; i < type.value_count(); ++i) {
    if (type.value(i)->number() != 0) names.push_back(choice_name(*type.value(i)));
  }
  return names;
}

std::string choices_text(const google::protobuf::EnumDescriptor& type) {
  std::string text;
  for (const std::string& name : choice_names(type)) text += (text.empty() ? "" : ", ") + name;
  return text;
}

std::optional<int> parse_choice(const google::protobuf::EnumDescriptor& type, std::string_view name,
                                std::string* error) {
  for (int i = 0; i < type.value_count(); ++i) {
    const google::protobuf::EnumValueDescriptor& value = *type.value(i);
    if (value.number() != 0 && choice_name(value) == name) return value.number();
  }
  *error = in_quotes(name) + " is unknown (" + choices_text(type) + ")";
  return std::nullopt;
}

}  // namespace riccati::cli
