#include "settings.hpp"

#include <google/protobuf/descriptor.h>
#include <google/protobuf/reflection.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <limits>
#include <set>
#include <sstream>
#include <type_traits>
#include <variant>

#include "riccati/enum_names.hpp"
#include "riccati/settings_schema.hpp"

namespace riccati::cli {

namespace {

using google::protobuf::Descriptor;
using google::protobuf::EnumDescriptor;
using google::protobuf::FieldDescriptor;
using google::protobuf::Message;
using google::protobuf::Reflection;
using api::SettingField;
using api::ValueKind;

template <typename T>
using Member = std::optional<T> RunSettings::*;
using Names = std::vector<std::string> RunSettings::*;

// Where one of the CLI's own settings goes in RunSettings; its type says how
// the value is read.
using Target = std::variant<Member<std::string>, Member<std::vector<double>>, Names, Member<std::vector<NamedRange>>,
                            Member<std::vector<SampleSpan>>>;

struct OwnSetting {
  std::string key;    // in the job file
  std::string flag;   // CLI11's names of the flag
  unsigned commands;  // the commands whose flags include it (a bit per Command)
  std::string help;
  Target target;
  std::string form;  // how a value is written, for --help; empty: its type's name
};

constexpr unsigned bit(Command c) { return static_cast<unsigned>(c); }
constexpr unsigned kIdentify = bit(Command::kIdentify);
constexpr unsigned kValidate = bit(Command::kValidate);
constexpr unsigned kSmooth = bit(Command::kSmooth);
constexpr unsigned kColumns = kIdentify | bit(Command::kStream) | kSmooth | kValidate;  // runs on measured data

// The CLI's own settings: what the requests cannot hold as the user gives it
// (a file to upload, columns to pick, the truth to print, more experiments
// and their masks, which the CLI spreads over the request's experiments).
const std::vector<OwnSetting>& own_settings() {
  static const std::vector<OwnSetting> table = {
      {"model", "--model,-m", kColumns | bit(Command::kSimulate), "Model name", &RunSettings::model},
      {"data", "--data,-d", kIdentify | kValidate | kSmooth, "Dataset id, or a local CSV/MAT file to upload",
       &RunSettings::data},
      {"inputs", "--inputs", kColumns, "Input columns, in the model's order", &RunSettings::inputs},
      {"outputs", "--outputs", kColumns, "Output columns, in the model's order", &RunSettings::outputs},
      {"truth", "--truth", kIdentify, "True parameters, to print the error", &RunSettings::truth},
      {"experiments", "--experiment", kIdentify,
       "oe, ml: another record of the system, a dataset id or a local file (uploaded with --inputs and --outputs), "
       "with the same parameters and its own initial state (as --x0 and --estimate-x0 say). Repeatable: experiments "
       "2, 3, ... in order; --data is experiment 1",
       &RunSettings::experiments, "DATA"},
      {"exclude", "--exclude", kIdentify,
       "Leave samples FIRST to END-1 (0-based) of experiment E out (E: 1, the default, is --data; 2, 3, ... the "
       "--experiment records). Repeatable",
       &RunSettings::exclude, "[E@]FIRST:END"},
      {"output_limits", "--output-limit", kIdentify,
       "An output's saturation, in its unit: samples where it is at or below LO, or at or above HI, are left out, in "
       "every experiment; LO or HI may be left empty. Repeatable",
       &RunSettings::output_limits, "OUTPUT=LO:HI"},
  };
  return table;
}

const OwnSetting* find_own(std::string_view key) {
  for (const OwnSetting& setting : own_settings()) {
    if (setting.key == key) return &setting;
  }
  return nullptr;
}

// The request a command's settings are: identify's are an IdentificationSpec's, ...
const Descriptor& request_of(Command command) {
  switch (command) {
    case Command::kIdentify: return *v1::IdentificationSpec::descriptor();
    case Command::kStream: return *v1::CreateSessionRequest::descriptor();
    case Command::kValidate: return *v1::ValidationSpec::descriptor();
    case Command::kSimulate: return *v1::SimulateRequest::descriptor();
    case Command::kSmooth: return *v1::SmoothingSpec::descriptor();
    case Command::kRetune: return *v1::RetuneSessionRequest::descriptor();
  }
  return *v1::IdentificationSpec::descriptor();
}

// The settings whose flags `command` has: its request's, and for the
// commands whose --params may name a job, the validation's --estimate.
std::vector<const SettingField*> command_settings(Command command) {
  const Descriptor& request = request_of(command);
  std::vector<const SettingField*> out;
  for (const SettingField& s : api::settings_of(request)) {
    if (api::offered(request, s)) out.push_back(&s);
  }
  if (command == Command::kSmooth || command == Command::kSimulate) {
    out.push_back(api::find_setting(*v1::ValidationSpec::descriptor(), "estimate"));
  }
  return out;
}

// Job-file keys of earlier versions, as the settings' paths.
std::string_view current_key(std::string_view key) {
  static const std::map<std::string_view, std::string_view> renamed = {
      {"filter", "filter.kind"},
      {"integrator", "integrator.kind"},
      {"x0", "initial_state"},
      {"estimate_x0", "initial_state.estimate"},
      {"estimation.estimate_q", "estimation.estimate_process_noise"},
      {"estimation.estimate_r", "estimation.estimate_measurement_noise"},
  };
  const auto it = renamed.find(key);
  return it == renamed.end() ? key : it->second;
}

// The request setting a job-file key names: its path in any request (the
// filter's also without `filter.`), case aside (P0, Q, optimal.V).
const SettingField* setting_for_key(std::string key) {
  std::transform(key.begin(), key.end(), key.begin(), [](unsigned char c) { return std::tolower(c); });
  const std::string path(current_key(key));
  for (const Descriptor* request : api::setting_requests()) {
    for (const std::string& prefix : {std::string(), std::string("filter.")}) {
      if (const SettingField* s = api::find_setting(*request, prefix + path)) return s;
    }
  }
  return nullptr;
}

// The keys grouped under `group` ("kind, substeps, rtol, atol, max_steps"):
// the next part of the settings' paths under it; empty: it is no group.
std::string group_keys(std::string_view group) {
  std::vector<std::string> keys;
  const auto add = [&](std::string_view path) {
    if (path.size() <= group.size() || !path.starts_with(group) || path[group.size()] != '.') return;
    std::string_view key = path.substr(group.size() + 1);
    key = key.substr(0, key.find('.'));
    if (std::find(keys.begin(), keys.end(), key) == keys.end()) keys.emplace_back(key);
  };
  for (const Descriptor* request : api::setting_requests()) {
    for (const SettingField& s : api::settings_of(*request)) {
      add(s.path);
      if (s.path.starts_with("filter.")) add(std::string_view(s.path).substr(7));
    }
  }
  std::string out;
  for (const std::string& key : keys) out += (out.empty() ? "" : ", ") + key;
  return out;
}


// ------------------------------------------------------------ values

std::string_view trim(std::string_view text) {
  while (!text.empty() && text.front() == ' ') text.remove_prefix(1);
  while (!text.empty() && text.back() == ' ') text.remove_suffix(1);
  return text;
}

std::string in_quotes(std::string_view text) { return "\"" + std::string(text) + "\""; }

template <typename T>
bool parse_number(std::string_view text, T* out) {
  text = trim(text);
  if (text.starts_with('+')) text.remove_prefix(1);
  const char* end = text.data() + text.size();
  const auto [ptr, ec] = std::from_chars(text.data(), end, *out);
  return ec == std::errc() && ptr == end && !text.empty();
}

// A value as written (a job file's, or a flag's as one would be), read into
// its type; false with what is wrong.

bool read(const YAML::Node& node, std::string* out, std::string* error) {
  if (!node.IsScalar()) {
    *error = "expected a string";
    return false;
  }
  *out = node.Scalar();
  return true;
}

bool read(const YAML::Node& node, double* out, std::string* error) {
  if (!node.IsScalar()) {
    *error = "expected a number";
    return false;
  }
  if (!parse_number(node.Scalar(), out)) {
    *error = in_quotes(node.Scalar()) + " is not a number";
    return false;
  }
  return true;
}

bool read(const YAML::Node& node, std::uint64_t* out, std::string* error) {
  if (!node.IsScalar()) {
    *error = "expected a whole number (0 or more)";
    return false;
  }
  if (!parse_number(node.Scalar(), out)) {
    *error = in_quotes(node.Scalar()) + " is not a whole number (0 or more)";
    return false;
  }
  return true;
}

bool read(const YAML::Node& node, bool* out, std::string* error) {
  try {
    *out = node.as<bool>();
    return true;
  } catch (const YAML::Exception&) {
    *error = "expected true or false";
    return false;
  }
}

bool read_choice(const YAML::Node& node, const EnumDescriptor& type, int* out, std::string* error) {
  if (!node.IsScalar()) {
    *error = "expected one of " + api::enum_choice_list(type);
    return false;
  }
  const std::optional<int> value = parse_choice(type, node.Scalar(), error);
  if (value) *out = *value;
  return value.has_value();
}

// One number or a list of them.
bool read(const YAML::Node& node, std::vector<double>* out, std::string* error) {
  out->clear();
  if (node.IsScalar()) {
    out->emplace_back();
    return read(node, &out->back(), error);
  }
  if (!node.IsSequence()) {
    *error = "expected a number or a list of numbers";
    return false;
  }
  for (const YAML::Node& item : node) {
    out->emplace_back();
    if (!read(item, &out->back(), error)) return false;
  }
  return true;
}

// One value (the whole diagonal), a list (the diagonal) or rows (the full
// matrix). Whether the size fits the model is riccatid's to say.
bool read(const YAML::Node& node, v1::Covariance* out, std::string* error) {
  if (node.IsSequence() && node.size() > 0 && node[0].IsSequence()) {
    v1::Matrix* full = out->mutable_full();
    std::vector<std::vector<double>> rows(node.size());
    for (std::size_t i = 0; i < rows.size(); ++i) {
      if (!read(node[i], &rows[i], error)) return false;
      if (rows[i].size() != rows[0].size()) {
        *error = "row " + std::to_string(i + 1) + " has " + std::to_string(rows[i].size()) + " value" +
                 (rows[i].size() == 1 ? "" : "s") + ", row 1 has " + std::to_string(rows[0].size());
        return false;
      }
    }
    full->set_rows(static_cast<uint32_t>(rows.size()));
    full->set_cols(static_cast<uint32_t>(rows[0].size()));
    for (std::size_t j = 0; j < rows[0].size(); ++j) {  // column-major
      for (const std::vector<double>& row : rows) full->add_values(row[j]);
    }
    return true;
  }
  std::vector<double> values;
  if (!read(node, &values, error)) return false;
  if (values.size() == 1) {
    out->set_scalar(values[0]);
  } else {
    out->mutable_diagonal()->mutable_values()->Add(values.begin(), values.end());
  }
  return true;
}

// "first" (the toolbox's x0 = Y(t0)) or the values.
bool read(const YAML::Node& node, v1::InitialState* out, std::string* error) {
  if (node.IsScalar() && node.Scalar() == "first") {
    out->set_first_measurement(true);
    return true;
  }
  std::vector<double> values;
  if (!read(node, &values, error)) {
    *error += " (give first or a list of numbers)";
    return false;
  }
  out->mutable_x0()->Add(values.begin(), values.end());
  return true;
}

bool read(const YAML::Node& node, std::vector<std::string>* out, std::string* error) {
  out->clear();
  if (node.IsScalar()) {
    out->push_back(node.Scalar());
    return true;
  }
  if (node.IsSequence()) {
    for (const YAML::Node& item : node) {
      out->emplace_back();
      if (!read(item, &out->back(), error)) return false;
    }
    return true;
  }
  *error = "expected a list of names";
  return false;
}

// ------------------------------------------------------------ items: NAME=LO:HI, NAME[=VALUE], [E@]FIRST:END

// A name before '=' or alone: not empty, and with no ':' or '=' in it (a
// mistyped separator is then an error here, not an unknown name there).
bool read_name(std::string_view item, std::string_view name, std::string* out, std::string* error) {
  name = trim(name);
  if (name.empty()) {
    *error = in_quotes(item) + ": a name is missing before '='";
    return false;
  }
  if (name.find_first_of(":=") != std::string_view::npos) return false;
  *out = std::string(name);
  return true;
}

// One side of LO:HI: empty is none.
bool read_side(std::string_view item, std::string_view side, std::optional<double>* out, std::string* error) {
  side = trim(side);
  if (side.empty()) return true;
  double v = 0.0;
  if (!parse_number(side, &v)) {
    *error = in_quotes(item) + ": " + in_quotes(side) + " is not a number";
    return false;
  }
  *out = v;
  return true;
}

bool read_item(std::string_view item, NamedRange* out, std::string* error) {
  const auto not_the_form = [&] {
    *error = in_quotes(item) + " is not NAME=LO:HI (LO or HI may be left empty)";
    return false;
  };
  const std::size_t eq = item.find('=');
  if (eq == std::string_view::npos) return not_the_form();
  error->clear();
  if (!read_name(item, item.substr(0, eq), &out->name, error)) return error->empty() ? not_the_form() : false;
  const std::string_view range = item.substr(eq + 1);
  const std::size_t colon = range.find(':');
  if (colon == std::string_view::npos || range.find(':', colon + 1) != std::string_view::npos) return not_the_form();
  if (!read_side(item, range.substr(0, colon), &out->lower, error) ||
      !read_side(item, range.substr(colon + 1), &out->upper, error)) {
    return false;
  }
  if (!out->lower && !out->upper) {
    *error = in_quotes(item) + " gives neither LO nor HI";
    return false;
  }
  return true;
}

bool read_item(std::string_view item, NamedValue* out, std::string* error) {
  const auto not_the_form = [&] {
    *error = in_quotes(item) + " is not NAME or NAME=VALUE";
    return false;
  };
  const std::size_t eq = item.find('=');
  error->clear();
  if (!read_name(item, item.substr(0, eq), &out->name, error)) return error->empty() ? not_the_form() : false;
  if (eq == std::string_view::npos) return true;
  const std::string_view value = trim(item.substr(eq + 1));
  double v = 0.0;
  if (!parse_number(value, &v)) {
    *error = in_quotes(item) + ": " + in_quotes(value) + " is not a number";
    return false;
  }
  out->value = v;
  return true;
}

bool read_item(std::string_view item, SampleSpan* out, std::string* error) {
  const auto not_the_form = [&] {
    *error = in_quotes(item) + " is not [E@]FIRST:END (samples FIRST to END-1, 0-based, of experiment E)";
    return false;
  };
  std::string_view range = item;
  if (const std::size_t at = item.find('@'); at != std::string_view::npos) {
    if (!parse_number(item.substr(0, at), &out->experiment)) return not_the_form();
    if (out->experiment == 0) {
      *error = in_quotes(item) + ": experiments count from 1 (1 is --data)";
      return false;
    }
    range = item.substr(at + 1);
  }
  const std::size_t colon = range.find(':');
  if (colon == std::string_view::npos || !parse_number(range.substr(0, colon), &out->first) ||
      !parse_number(range.substr(colon + 1), &out->end)) {
    return not_the_form();
  }
  return true;
}

// One item, or a list of them, each as its flag takes it.
template <typename Item>
bool read(const YAML::Node& node, std::vector<Item>* out, std::string* error) {
  out->clear();
  const auto one = [&](const YAML::Node& item) {
    if (!item.IsScalar()) {
      *error = "expected a list of texts as the flag takes them";
      return false;
    }
    out->emplace_back();
    return read_item(item.Scalar(), &out->back(), error);
  };
  if (node.IsScalar()) return one(node);
  if (!node.IsSequence()) {
    *error = "expected a list of texts as the flag takes them";
    return false;
  }
  for (const YAML::Node& item : node) {
    if (!one(item)) return false;
  }
  return true;
}


// ------------------------------------------------------------ request settings

// A count for a uint32 field: past its range is past riccatid's limits too,
// and riccatid says so.
uint32_t saturated(std::uint64_t count) {
  return static_cast<uint32_t>(std::min<std::uint64_t>(count, std::numeric_limits<uint32_t>::max()));
}

// A value below the setting's declared minimum (--horizon 0, --passes 0) is
// refused here, as the workbench's form refuses it, rather than sent as the
// field's "unset" 0.
bool at_least_minimum(const SettingField& s, double value, std::string* error) {
  if (s.setting == nullptr || !s.setting->has_minimum() || value >= s.setting->minimum()) return true;
  const auto text = [](double v) {
    std::ostringstream out;
    out << v;
    return out.str();
  };
  *error = text(value) + " is below the least value, " + text(s.setting->minimum());
  return false;
}

// Reads `node` into the setting's field of `request`; false with what is wrong.
bool write_setting(const SettingField& s, const YAML::Node& node, Message* request, std::string* error) {
  Message* holder = api::mutable_holder(request, s);
  const Reflection* r = holder->GetReflection();
  const FieldDescriptor* f = s.field;
  switch (s.kind) {
    case ValueKind::kNumber: {
      double v = 0.0;
      if (!read(node, &v, error) || !at_least_minimum(s, v, error)) return false;
      r->SetDouble(holder, f, v);
      return true;
    }
    case ValueKind::kCount: {
      std::uint64_t v = 0;
      if (!read(node, &v, error) || !at_least_minimum(s, static_cast<double>(v), error)) return false;
      if (f->cpp_type() == FieldDescriptor::CPPTYPE_UINT32) {
        r->SetUInt32(holder, f, saturated(v));
      } else {
        r->SetUInt64(holder, f, v);
      }
      return true;
    }
    case ValueKind::kSwitch: {
      bool v = false;
      if (!read(node, &v, error)) return false;
      r->SetBool(holder, f, v);
      return true;
    }
    case ValueKind::kText: {
      std::string v;
      if (!read(node, &v, error)) return false;
      r->SetString(holder, f, v);
      return true;
    }
    case ValueKind::kChoice: {
      int v = 0;
      if (!read_choice(node, *f->enum_type(), &v, error)) return false;
      r->SetEnumValue(holder, f, v);
      return true;
    }
    case ValueKind::kNumbers: {
      std::vector<double> v;
      if (!read(node, &v, error)) return false;
      r->ClearField(holder, f);
      for (const double x : v) r->AddDouble(holder, f, x);
      return true;
    }
    case ValueKind::kNames: {
      std::vector<std::string> v;
      if (!read(node, &v, error)) return false;
      r->ClearField(holder, f);
      for (const std::string& x : v) r->AddString(holder, f, x);
      return true;
    }
    case ValueKind::kCovariance: {
      v1::Covariance v;
      if (!read(node, &v, error)) return false;
      r->MutableMessage(holder, f)->CopyFrom(v);
      return true;
    }
    case ValueKind::kInitialState: {
      v1::InitialState v;
      if (!read(node, &v, error)) return false;
      auto* state = static_cast<v1::InitialState*>(r->MutableMessage(holder, f));
      state->clear_first_measurement();  // what estimate names stays
      state->clear_x0();
      state->MergeFrom(v);
      return true;
    }
    case ValueKind::kBounds: {
      std::vector<NamedRange> v;
      if (!read(node, &v, error)) return false;
      r->ClearField(holder, f);
      for (const NamedRange& item : v) {
        auto* bound = static_cast<v1::ParameterBound*>(r->AddMessage(holder, f));
        bound->set_name(item.name);
        if (item.lower) bound->set_lower(*item.lower);
        if (item.upper) bound->set_upper(*item.upper);
      }
      return true;
    }
    case ValueKind::kFixed: {
      std::vector<NamedValue> v;
      if (!read(node, &v, error)) return false;
      r->ClearField(holder, f);
      for (const NamedValue& item : v) {
        auto* fixed = static_cast<v1::FixedParameter*>(r->AddMessage(holder, f));
        fixed->set_name(item.name);
        if (item.value) fixed->set_value(*item.value);
      }
      return true;
    }
  }
  return false;
}

// Whether `node` is a value of the setting (read into a request of its own).
bool check_value(const SettingField& s, const YAML::Node& node, std::string* error) {
  const Descriptor* request = s.chain.front()->containing_type();
  std::unique_ptr<Message> scratch(google::protobuf::MessageFactory::generated_factory()->GetPrototype(request)->New());
  return write_setting(s, node, scratch.get(), error);
}

bool read_own(const OwnSetting& setting, const YAML::Node& node, RunSettings* s, std::string* error) {
  return std::visit(
      [&](auto member) {
        auto& to = s->*member;
        if constexpr (std::is_same_v<decltype(member), Names>) {
          return read(node, &to, error);
        } else {
          typename std::remove_reference_t<decltype(to)>::value_type value{};
          const bool ok = read(node, &value, error);
          if (ok) to = std::move(value);
          return ok;
        }
      },
      setting.target);
}

// One key of a job file (under `group`, if any): a setting, or a group of them.
bool read_entry(const std::string& group, const YAML::Node& key_node, const YAML::Node& value, RunSettings* s,
                std::string* error) {
  const std::string key = (group.empty() ? "" : group + ".") + key_node.Scalar();
  const std::string where = in_quotes(key) + " (line " + std::to_string(key_node.Mark().line + 1) + ")";
  std::string lower = key;
  std::transform(lower.begin(), lower.end(), lower.begin(), [](unsigned char c) { return std::tolower(c); });
  const std::string grouped = group_keys(lower);
  if (value.IsMap()) {
    if (grouped.empty()) {
      *error = "key " + where + ": a map, but no settings are grouped under it";
      return false;
    }
    for (const auto& entry : value) {
      if (!read_entry(key, entry.first, entry.second, s, error)) return false;
    }
    return true;
  }
  if (const OwnSetting* own = group.empty() ? find_own(key) : nullptr) {
    if (!read_own(*own, value, s, error)) {
      *error = "key " + where + ": " + *error;
      return false;
    }
    return true;
  }
  if (lower == "joseph") {  // earlier job files: the Joseph form on (true) or off
    bool joseph = true;
    if (!read(value, &joseph, error)) {
      *error = "key " + where + ": " + *error;
      return false;
    }
    s->given["--no-joseph"] = YAML::Node(joseph ? "false" : "true");
    return true;
  }
  const SettingField* setting = setting_for_key(key);
  if (setting == nullptr && !grouped.empty()) {
    *error = "key " + where + ": expected a map (" + grouped + ")";
    return false;
  }
  if (setting == nullptr) {
    std::string keys = group;
    std::transform(keys.begin(), keys.end(), keys.begin(), [](unsigned char c) { return std::tolower(c); });
    keys = group.empty() ? "" : group_keys(keys);
    *error = "unknown key " + where + (keys.empty() ? "" : " (expected " + keys + ")");
    return false;
  }
  if (!check_value(*setting, value, error)) {
    *error = "key " + where + ": " + *error;
    return false;
  }
  s->given[setting->setting->flag()] = YAML::Clone(value);
  return true;
}

// How --help shows the value a flag takes.
std::string type_name(const SettingField& s) {
  if (!s.setting->form().empty()) return s.setting->form();
  switch (s.kind) {
    case ValueKind::kNumber: return "FLOAT";
    case ValueKind::kCount: return "UINT";
    case ValueKind::kNumbers: return "X,...";
    case ValueKind::kCovariance: return "V|V,...";
    case ValueKind::kNames: return "NAME";
    case ValueKind::kChoice: return "CHOICE";
    default: return "TEXT";
  }
}

std::string list_of(const google::protobuf::RepeatedPtrField<std::string>& names) {
  std::string out;
  for (const std::string& n : names) out += (out.empty() ? "" : ", ") + n;
  return out;
}

// The help of a request setting: what it is, its choices, its default,
// its unit and where it applies.
std::string help_of(const SettingField& s) {
  const v1::Setting& o = *s.setting;
  std::string help = o.help();
  if (s.kind == ValueKind::kChoice) help += " (" + api::enum_choice_list(*s.field->enum_type()) + ")";
  if (s.kind == ValueKind::kNames || s.kind == ValueKind::kBounds || s.kind == ValueKind::kFixed) {
    help += ". Repeatable, or comma-separated";
  }
  std::vector<std::string> notes;
  if (!o.unit().empty()) notes.push_back("unit: " + o.unit());
  if (!o.default_value().empty()) notes.push_back("default " + o.default_value());
  if (o.methods_size() > 0) notes.push_back("method " + list_of(o.methods()));
  if (o.filters_size() > 0) notes.push_back("filter " + list_of(o.filters()));
  for (std::size_t i = 0; i < notes.size(); ++i) help += (i == 0 ? " [" : "; ") + notes[i];
  if (!notes.empty()) help += "]";
  return help;
}

std::string own_type_name(const OwnSetting& setting) {
  if (!setting.form.empty()) return setting.form;
  return std::holds_alternative<Member<std::vector<double>>>(setting.target) ? "X,..." : "TEXT";
}

// A flag's text as a job file would have it: commas make a list, for the
// settings that take one.
YAML::Node written(bool takes_list, const std::string& text) {
  if (!takes_list || text.find(',') == std::string::npos) return YAML::Node(text);
  YAML::Node list(YAML::NodeType::Sequence);
  std::stringstream items(text);
  for (std::string item; std::getline(items, item, ',');) list.push_back(item);
  return list;
}

}  // namespace

bool load_job_file(const std::string& path, RunSettings* s, std::string* error) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::Exception& e) {
    *error = path + ": " + e.what();
    return false;
  }
  if (!root.IsMap()) {
    *error = path + ": expected a map of settings";
    return false;
  }
  for (const auto& entry : root) {
    if (!read_entry("", entry.first, entry.second, s, error)) {
      *error = path + ": " + *error;
      return false;
    }
  }
  return true;
}

struct RunFlags::Flag {
  const OwnSetting* own = nullptr;      // one of the CLI's own settings,
  const SettingField* field = nullptr;  // or a request's
  CLI::Option* option = nullptr;
  std::string text;
  std::vector<std::string> items;
  bool on = false;
};

RunFlags::RunFlags(CLI::App* cmd, Command command) {
  for (const OwnSetting& setting : own_settings()) {
    if ((setting.commands & bit(command)) == 0) continue;
    Flag& flag = flags_.emplace_back(Flag{.own = &setting});
    const Target& t = setting.target;
    if (std::holds_alternative<Member<std::string>>(t) || std::holds_alternative<Member<std::vector<double>>>(t)) {
      flag.option = cmd->add_option(setting.flag, flag.text, setting.help)->type_name(own_type_name(setting));
    } else {
      // One item per occurrence (or a comma-separated list); never the next word.
      flag.option = cmd->add_option(setting.flag, flag.items, setting.help)
                        ->delimiter(',')
                        ->allow_extra_args(false)
                        ->type_name(own_type_name(setting));
    }
  }
  for (const SettingField* s : command_settings(command)) {
    Flag& flag = flags_.emplace_back(Flag{.field = s});
    const std::string& name = s->setting->flag();
    if (s->kind == ValueKind::kSwitch) {
      flag.option = cmd->add_flag(name, flag.on, help_of(*s));
    } else if (s->kind == ValueKind::kNames || s->kind == ValueKind::kBounds || s->kind == ValueKind::kFixed) {
      flag.option = cmd->add_option(name, flag.items, help_of(*s))
                        ->delimiter(',')
                        ->allow_extra_args(false)
                        ->type_name(type_name(*s));
      if (!s->setting->implicit().empty()) flag.option->expected(0, 1);
    } else {
      flag.option = cmd->add_option(name, flag.text, help_of(*s))->type_name(type_name(*s));
    }
  }
}

RunFlags::~RunFlags() = default;

bool RunFlags::apply(RunSettings* s, std::string* error) const {
  for (const Flag& flag : flags_) {
    if (flag.option->count() == 0) continue;
    const auto failed = [&] {
      *error = flag.option->get_name() + ": " + *error;
      return false;
    };
    if (flag.own != nullptr) {
      const Target& t = flag.own->target;
      YAML::Node node;
      if (std::holds_alternative<Member<std::string>>(t) || std::holds_alternative<Member<std::vector<double>>>(t)) {
        node = written(std::holds_alternative<Member<std::vector<double>>>(t), flag.text);
      } else {
        node = YAML::Node(YAML::NodeType::Sequence);
        for (const std::string& item : flag.items) node.push_back(item);
      }
      if (!read_own(*flag.own, node, s, error)) return failed();
      continue;
    }
    const SettingField& field = *flag.field;
    YAML::Node node;
    switch (field.kind) {
      case ValueKind::kSwitch:
        node = YAML::Node("true");
        break;
      case ValueKind::kNames:
      case ValueKind::kBounds:
      case ValueKind::kFixed: {
        // The flag without a value (CLI11 gives one empty text): its implicit value.
        const bool alone = !field.setting->implicit().empty() &&
                           std::all_of(flag.items.begin(), flag.items.end(), [](const std::string& i) { return i.empty(); });
        node = YAML::Node(YAML::NodeType::Sequence);
        if (alone) {
          node.push_back(field.setting->implicit());
        } else {
          for (const std::string& item : flag.items) node.push_back(item);
        }
        break;
      }
      default:
        node = written(field.kind == ValueKind::kNumbers || field.kind == ValueKind::kCovariance ||
                           field.kind == ValueKind::kInitialState,
                       flag.text);
    }
    if (!check_value(field, node, error)) return failed();
    s->given[field.setting->flag()] = node;
  }
  return true;
}

void RunFlags::require(std::string_view key) {
  for (Flag& flag : flags_) {
    if (flag.own != nullptr && flag.own->key == key) flag.option->required();
  }
}

bool parse_list(const std::string& text, std::vector<double>* out, std::string* error) {
  out->clear();
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    double v = 0.0;
    if (!parse_number(item, &v)) {
      *error = in_quotes(item) + " is not a number";
      return false;
    }
    out->push_back(v);
  }
  if (out->empty()) {
    *error = "an empty list";
    return false;
  }
  return true;
}

bool parse_named_list(const std::string& text, std::map<std::string, double>* out, std::string* error) {
  out->clear();
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    const std::size_t equals = item.find('=');
    double v = 0.0;
    if (equals == std::string::npos || !parse_number(std::string_view(item).substr(equals + 1), &v)) {
      *error = in_quotes(item) + " is not NAME=VALUE";
      return false;
    }
    (*out)[std::string(trim(std::string_view(item).substr(0, equals)))] = v;
  }
  if (out->empty()) {
    *error = "an empty list";
    return false;
  }
  return true;
}

bool check_identification(const RunSettings& s, std::string* error) {
  const std::uint64_t experiments = 1 + s.experiments.size();
  for (const SampleSpan& span : s.exclude.value_or(std::vector<SampleSpan>{})) {
    if (span.experiment <= experiments) continue;
    *error = "--exclude " + std::to_string(span.experiment) + "@" + std::to_string(span.first) + ":" +
             std::to_string(span.end) + ": there is no experiment " + std::to_string(span.experiment) + " (1 is --data" +
             (experiments == 2   ? ", 2 the --experiment record"
              : experiments > 2 ? ", 2 to " + std::to_string(experiments) + " the --experiment records"
                                : "") +
             ")";
    return false;
  }
  return true;
}

void fill_request(const RunSettings& s, Message* request) {
  const Descriptor& type = *request->GetDescriptor();
  for (const SettingField& field : api::settings_of(type)) {
    if (!api::offered(type, field)) continue;
    const auto it = s.given.find(field.setting->flag());
    if (it == s.given.end()) continue;
    std::string error;  // none: the value was read when it was given
    write_setting(field, it->second, request, &error);
  }
}

namespace {

// x0 "first" (the toolbox's x0 = Y(t0)) when no --x0 was given.
template <typename Request>
void first_measurement_unless_given(const RunSettings& s, Request* out) {
  if (!s.has("--x0")) out->mutable_initial_state()->set_first_measurement(true);
}

// Experiment `experiment`'s (1-based) mask: the output limits (every
// experiment's) and its excluded ranges.
v1::SampleMask sample_mask(const RunSettings& s, std::uint64_t experiment) {
  v1::SampleMask out;
  for (const NamedRange& limit : s.output_limits.value_or(std::vector<NamedRange>{})) {
    v1::OutputLimit* l = out.add_limits();
    l->set_output(limit.name);
    if (limit.lower) l->set_lower(*limit.lower);
    if (limit.upper) l->set_upper(*limit.upper);
  }
  for (const SampleSpan& span : s.exclude.value_or(std::vector<SampleSpan>{})) {
    if (span.experiment != experiment) continue;
    v1::SampleRange* range = out.add_excluded();
    range->set_first(span.first);
    range->set_end(span.end);
  }
  return out;
}

}  // namespace

v1::IdentificationSpec to_identification_spec(const RunSettings& s, const std::string& dataset_id,
                                              const std::vector<std::string>& more_datasets) {
  v1::IdentificationSpec out;
  fill_request(s, &out);
  out.set_model(s.model.value_or(""));
  out.set_dataset_id(dataset_id);
  first_measurement_unless_given(s, &out);
  if (const v1::SampleMask mask = sample_mask(s, 1); mask.ByteSizeLong() > 0) *out.mutable_mask() = mask;
  for (std::size_t e = 0; e < more_datasets.size(); ++e) {
    v1::Experiment* experiment = out.add_experiments();
    experiment->set_dataset_id(more_datasets[e]);
    *experiment->mutable_initial_state() = out.initial_state();
    if (const v1::SampleMask mask = sample_mask(s, e + 2); mask.ByteSizeLong() > 0) *experiment->mutable_mask() = mask;
  }
  return out;
}

v1::SmoothingSpec to_smoothing_spec(const RunSettings& s, const std::string& dataset_id) {
  v1::SmoothingSpec out;
  fill_request(s, &out);
  out.set_model(s.model.value_or(""));
  out.set_dataset_id(dataset_id);
  first_measurement_unless_given(s, &out);
  return out;
}

v1::CreateSessionRequest to_session_request(const RunSettings& s) {
  v1::CreateSessionRequest out;
  fill_request(s, &out);
  out.set_model(s.model.value_or(""));
  first_measurement_unless_given(s, &out);
  return out;
}

v1::ValidationSpec to_validation_spec(const RunSettings& s, const std::string& dataset_id) {
  v1::ValidationSpec out;
  fill_request(s, &out);
  out.set_model(s.model.value_or(""));
  out.set_dataset_id(dataset_id);
  first_measurement_unless_given(s, &out);
  // --x0-samples alone: every initial state is fitted.
  if (out.estimate_x0_samples() > 0 && out.initial_state().estimate_size() == 0) {
    out.mutable_initial_state()->add_estimate("all");
  }
  return out;
}

v1::SimulateRequest to_simulate_request(const RunSettings& s) {
  v1::SimulateRequest out;
  fill_request(s, &out);
  out.set_model(s.model.value_or(""));
  return out;
}

v1::RetuneSessionRequest to_retune_request(const RunSettings& s, const std::string& session_id) {
  v1::RetuneSessionRequest out;
  fill_request(s, &out);
  out.set_id(session_id);
  return out;
}

std::optional<int> estimate_choice(const RunSettings& s) {
  const auto it = s.given.find("--estimate");
  if (it == s.given.end()) return std::nullopt;
  int value = 0;
  std::string error;
  read_choice(it->second, *v1::EstimateChoice_descriptor(), &value, &error);
  return value;
}

std::string with_flags(const std::string& message) {
  // Each request setting's path, and the flag that sets it where the flag
  // is not the path itself ("filter.r": --r; not "passes": --passes).
  std::map<std::string, std::string> flags;
  for (const Descriptor* request : api::setting_requests()) {
    for (const SettingField& s : api::settings_of(*request)) {
      std::string plain = "--" + s.path;
      std::replace(plain.begin(), plain.end(), '_', '-');
      if (s.setting->flag() != plain) flags.emplace(s.path, s.setting->flag());
    }
  }
  const auto part_of_name = [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '.'; };
  std::string out;
  std::set<std::string> done;
  for (std::size_t at = 0; at < message.size();) {
    if (at > 0 && part_of_name(message[at - 1])) {
      out += message[at++];
      continue;
    }
    // The name that starts here ("filter.r.diagonal"), and the longest setting path it begins with.
    std::size_t end = at;
    while (end < message.size() && part_of_name(message[end])) ++end;
    if (end > at && message[end - 1] == '.') --end;  // a sentence's full stop
    if (end == at) {
      out += message[at++];
      continue;
    }
    const std::string name = message.substr(at, end - at);
    const std::string* flag = nullptr;
    std::size_t longest = 0;
    for (const auto& [path, f] : flags) {
      const bool begins = name.compare(0, path.size(), path) == 0 && (name.size() == path.size() || name[path.size()] == '.');
      if (begins && path.size() > longest) {
        longest = path.size();
        flag = &f;
      }
    }
    out += name;
    if (flag != nullptr && !done.count(*flag)) {
      // A plain word ("q", "fixed") only where it leads the message or a clause.
      const std::string path = name.substr(0, longest);
      const bool identifier = path.find_first_of("._0123456789") != std::string::npos;
      const bool leads = at == 0 || (at >= 2 && message.compare(at - 2, 2, ": ") == 0);
      if (identifier || leads) {
        out += " (" + *flag + ")";
        done.insert(*flag);
      }
    }
    at = end;
  }
  return out;
}

std::optional<int> parse_choice(const google::protobuf::EnumDescriptor& type, std::string_view name,
                                std::string* error) {
  const google::protobuf::EnumValueDescriptor* value = api::find_enum_value(type, name);
  if (value != nullptr) return value->number();
  *error = "\"" + std::string(name) + "\" is unknown (" + api::enum_choice_list(type) + ")";
  return std::nullopt;
}

}  // namespace riccati::cli
