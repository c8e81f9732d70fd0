// `riccati settings`: the requests' settings, from the proto's schema (the
// same that makes the flags, the job-file keys, Python's keywords and the
// workbench's forms), as a table, JSON (what GET /api/v1/schema serves) or
// the Markdown of docs/settings.md.
#include <cstdio>
#include <string>

#include "commands/commands.hpp"
#include "riccati/enum_names.hpp"
#include "riccati/settings_schema.hpp"

namespace riccati::cli {
namespace {

std::string joined(const google::protobuf::RepeatedPtrField<std::string>& names) {
  std::string out;
  for (const std::string& n : names) out += (out.empty() ? "" : ", ") + n;
  return out;
}

// Where it applies: "method oe, ml; filter ukf", or "" (everywhere).
std::string applies(const v1::Setting& o) {
  std::string out;
  if (o.methods_size() > 0) out += "method " + joined(o.methods());
  if (o.filters_size() > 0) out += std::string(out.empty() ? "" : "; ") + "filter " + joined(o.filters());
  return out;
}

std::string escaped(std::string text) {  // a Markdown table cell
  for (std::size_t at = text.find('|'); at != std::string::npos; at = text.find('|', at + 2)) text.replace(at, 1, "\\|");
  return text;
}

}  // namespace

int settings_reference(const std::string& format) {
  if (format == "json") {
    std::printf("%s\n", api::settings_schema_json().c_str());
    return kExitOk;
  }
  const bool markdown = format == "markdown";
  for (const google::protobuf::Descriptor* request : api::setting_requests()) {
    if (markdown) {
      std::printf("### %s\n\n| job-file key (path) | flag | value | default | applies to | what |\n|---|---|---|---|---|---|\n",
                  std::string(request->name()).c_str());
    } else {
      std::printf("%s\n", std::string(request->name()).c_str());
    }
    for (const api::SettingField& s : api::settings_of(*request)) {
      if (!api::offered(*request, s)) continue;
      const v1::Setting& o = *s.setting;
      std::string value = o.form().empty() ? api::value_kind_name(s.kind) : o.form();
      if (s.kind == api::ValueKind::kChoice) value = api::enum_choice_list(*s.field->enum_type());
      if (!o.unit().empty()) value += " (" + o.unit() + ")";
      if (markdown) {
        std::printf("| `%s` | `%s` | %s | %s | %s | %s |\n", s.path.c_str(), o.flag().c_str(), escaped(value).c_str(),
                    escaped(o.default_value()).c_str(), escaped(applies(o)).c_str(), escaped(o.help()).c_str());
      } else {
        std::printf("  %-36s %-22s %s%s\n", s.path.c_str(), o.flag().c_str(), value.c_str(),
                    applies(o).empty() ? "" : ("  [" + applies(o) + "]").c_str());
      }
    }
    std::printf("\n");
  }
  return kExitOk;
}

}  // namespace riccati::cli
