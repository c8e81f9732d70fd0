#include "engine/models/text/diagnostics.hpp"

#include <cctype>
#include <charconv>
#include <cmath>
#include <set>

namespace riccati::text {

bool valid_identifier(const std::string& s) {
  if (s.empty() || !(std::isalpha(static_cast<unsigned char>(s[0])) != 0 || s[0] == '_')) return false;
  return std::all_of(s.begin(), s.end(), [](char c) { return std::isalnum(static_cast<unsigned char>(c)) != 0 || c == '_'; });
}

bool valid_model_name(const std::string& s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_';
  });
}

Status entries(const Source& src, const YAML::Node& map, const std::string& what, std::vector<Entry>* out) {
  out->clear();
  if (!map.IsDefined() || map.IsNull()) return Status::ok();
  if (!map.IsMap()) return src.at(map.Mark(), what + " must be a mapping (name: value)");
  std::set<std::string> seen;
  for (auto it = map.begin(); it != map.end(); ++it) {
    if (!it->first.IsScalar()) return src.at(it->first.Mark(), "a key of " + what + " must be a name");
    const std::string key = it->first.Scalar();
    if (!seen.insert(key).second) return src.at(it->first.Mark(), "\"" + key + "\" appears twice in " + what);
    out->push_back({key, it->first, it->second});
  }
  return Status::ok();
}

Status name_list(const Source& src, const YAML::Node& node, const std::string& what, std::vector<Entry>* out) {
  out->clear();
  if (!node.IsDefined() || node.IsNull()) return Status::ok();
  if (node.IsSequence()) {
    std::set<std::string> seen;
    for (const YAML::Node& item : node) {
      if (!item.IsScalar()) return src.at(item.Mark(), "each of " + what + " must be a name");
      if (!seen.insert(item.Scalar()).second) return src.at(item.Mark(), "\"" + item.Scalar() + "\" appears twice in " + what);
      out->push_back({item.Scalar(), item, YAML::Node()});
    }
    return Status::ok();
  }
  RICCATI_RETURN_IF_ERROR(entries(src, node, what, out));
  for (const Entry& e : *out) {
    if (e.value.IsNull() || e.value.IsScalar()) continue;  // no attributes, or a unit alone
    std::vector<Entry> attributes;
    RICCATI_RETURN_IF_ERROR(entries(src, e.value, what + "." + e.key, &attributes));
    for (const Entry& a : attributes) {
      if (a.key != "unit" && a.key != "description") {
        return src.at(a.key_node.Mark(), "unknown attribute \"" + a.key + "\" of " + e.key + " (unit, description)");
      }
    }
  }
  return Status::ok();
}

std::string unit_of(const Entry& e) {
  if (e.value.IsScalar()) return e.value.Scalar();
  if (!e.value.IsMap()) return "";
  for (const auto& attribute : e.value) {
    if (attribute.first.IsScalar() && attribute.first.Scalar() == "unit" && attribute.second.IsScalar()) {
      return attribute.second.Scalar();
    }
  }
  return "";
}

Result<double> number(const Source& src, const YAML::Node& node, const std::string& what) {
  if (!node.IsScalar()) return src.at(node.Mark(), what + " must be a number");
  const std::string& s = node.Scalar();
  double v = 0.0;
  const char* begin = s.data();
  if (!s.empty() && s[0] == '+') ++begin;
  const auto [ptr, ec] = std::from_chars(begin, s.data() + s.size(), v);
  if (ec != std::errc() || ptr != s.data() + s.size() || !std::isfinite(v)) {
    return src.at(node.Mark(), what + " must be a finite number, not \"" + s + "\"");
  }
  return v;
}

Status parse(const Source& src, const Entry& e, const std::string& what, Expression* out) {
  out->name = e.key;
  out->key = e.key_node;
  out->value = e.value;
  if (!e.value.IsScalar()) return src.at(e.value.Mark(), what + " " + e.key + " must be an expression");
  ExpressionError error;
  if (!parse_expression(e.value.Scalar(), &out->ast, &error)) return src.in_scalar(e.value, error.offset, error.message);
  return Status::ok();
}

}  // namespace riccati::text
