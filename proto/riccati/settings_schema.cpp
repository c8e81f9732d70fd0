#include "riccati/settings_schema.hpp"

#include <google/protobuf/struct.pb.h>
#include <google/protobuf/util/json_util.h>

#include <algorithm>
#include <deque>
#include <map>
#include <mutex>
#include <stdexcept>

#include "riccati/enum_names.hpp"
#include "riccati/v1/jobs.pb.h"
#include "riccati/v1/models.pb.h"
#include "riccati/v1/sessions.pb.h"

namespace riccati::api {
namespace {

using google::protobuf::Descriptor;
using google::protobuf::FieldDescriptor;
using google::protobuf::Message;
using google::protobuf::Reflection;

bool has_setting(const FieldDescriptor& field) { return field.options().HasExtension(v1::setting); }

// The first declaration with help of the setting `flag` among the requests'
// fields (setting_requests() order: identification first), or null.
const v1::Setting* declaration_of(const Descriptor& type, std::string_view flag, int depth) {
  for (int i = 0; i < type.field_count(); ++i) {
    const FieldDescriptor* field = type.field(i);
    if (has_setting(*field)) {
      const v1::Setting& setting = field->options().GetExtension(v1::setting);
      if (setting.flag() == flag && !setting.help().empty()) return &setting;
    }
    if (field->type() == FieldDescriptor::TYPE_MESSAGE && !field->is_repeated() && depth < 8) {
      if (const v1::Setting* found = declaration_of(*field->message_type(), flag, depth + 1)) return found;
    }
  }
  return nullptr;
}

// A setting written as its flag alone ("[(setting) = { flag: \"--x0\" }]",
// where a request repeats a setting of another) takes the rest from the
// flag's declaration; what it states itself stays. Kept for the process, as
// the options are.
const v1::Setting* completed(const v1::Setting& own) {
  if (!own.help().empty()) return &own;
  const v1::Setting* declared = nullptr;
  for (const Descriptor* request : setting_requests()) {
    if ((declared = declaration_of(*request, own.flag(), 0)) != nullptr) break;
  }
  if (declared == nullptr) throw std::logic_error("setting " + own.flag() + " has no help and no declaration with help");
  static std::deque<v1::Setting> completed_settings;  // settings_of's lock guards it
  v1::Setting& out = completed_settings.emplace_back(*declared);
  const Reflection& reflection = *own.GetReflection();
  for (int i = 0; i < v1::Setting::descriptor()->field_count(); ++i) {
    const FieldDescriptor* f = v1::Setting::descriptor()->field(i);
    const bool stated = f->is_repeated() ? reflection.FieldSize(own, f) > 0 : reflection.HasField(own, f);
    if (!stated) continue;
    out.GetReflection()->ClearField(&out, f);
    if (f->is_repeated()) {
      for (int k = 0; k < reflection.FieldSize(own, f); ++k) {
        out.GetReflection()->AddString(&out, f, reflection.GetRepeatedString(own, f, k));
      }
    } else if (f->cpp_type() == FieldDescriptor::CPPTYPE_STRING) {
      out.GetReflection()->SetString(&out, f, reflection.GetString(own, f));
    } else {
      out.GetReflection()->SetDouble(&out, f, reflection.GetDouble(own, f));
    }
  }
  return &out;
}

void walk(const Descriptor& type, std::vector<const FieldDescriptor*>* chain, std::vector<SettingField>* out) {
  for (int i = 0; i < type.field_count(); ++i) {
    const FieldDescriptor* field = type.field(i);
    chain->push_back(field);
    if (has_setting(*field)) {
      SettingField s;
      for (const FieldDescriptor* f : *chain) s.path += (s.path.empty() ? "" : ".") + std::string(f->name());
      s.chain = *chain;
      s.field = field;
      s.setting = completed(field->options().GetExtension(v1::setting));
      s.kind = value_kind(*field);
      out->push_back(std::move(s));
    }
    // Into singular messages, which may hold settings (InitialState, a
    // setting itself, holds estimate, another). The requests' messages nest
    // a few levels at most; the bound keeps a recursive type finite.
    if (field->type() == FieldDescriptor::TYPE_MESSAGE && !field->is_repeated() && chain->size() < 8) {
      walk(*field->message_type(), chain, out);
    }
    chain->pop_back();
  }
}

struct Schemas {
  std::mutex mutex;
  std::map<const Descriptor*, std::vector<SettingField>> by_request;
};

Schemas& schemas() {
  static Schemas s;
  return s;
}

bool contains(const google::protobuf::RepeatedPtrField<std::string>& names, std::string_view name) {
  return std::find(names.begin(), names.end(), name) != names.end();
}

std::string joined(const google::protobuf::RepeatedPtrField<std::string>& names, std::string_view last) {
  std::string out;
  for (int i = 0; i < names.size(); ++i) {
    out += (i == 0 ? "" : i + 1 == names.size() ? std::string(" ") + std::string(last) + " " : ", ") + names[i];
  }
  return out;
}

}  // namespace

ValueKind value_kind(const FieldDescriptor& field) {
  if (field.type() == FieldDescriptor::TYPE_MESSAGE) {
    const std::string_view type = field.message_type()->full_name();
    if (type == "riccati.v1.Covariance" && !field.is_repeated()) return ValueKind::kCovariance;
    if (type == "riccati.v1.InitialState" && !field.is_repeated()) return ValueKind::kInitialState;
    if (type == "riccati.v1.ParameterBound" && field.is_repeated()) return ValueKind::kBounds;
    if (type == "riccati.v1.FixedParameter" && field.is_repeated()) return ValueKind::kFixed;
    return ValueKind::kText;
  }
  switch (field.cpp_type()) {
    case FieldDescriptor::CPPTYPE_DOUBLE:
    case FieldDescriptor::CPPTYPE_FLOAT:
      return field.is_repeated() ? ValueKind::kNumbers : ValueKind::kNumber;
    case FieldDescriptor::CPPTYPE_UINT32:
    case FieldDescriptor::CPPTYPE_UINT64:
      return ValueKind::kCount;
    case FieldDescriptor::CPPTYPE_BOOL:
      return ValueKind::kSwitch;
    case FieldDescriptor::CPPTYPE_ENUM:
      return ValueKind::kChoice;
    case FieldDescriptor::CPPTYPE_STRING:
      return field.is_repeated() ? ValueKind::kNames : ValueKind::kText;
    default:
      return ValueKind::kText;
  }
}

const char* value_kind_name(ValueKind kind) {
  switch (kind) {
    case ValueKind::kNumber: return "number";
    case ValueKind::kCount: return "count";
    case ValueKind::kSwitch: return "switch";
    case ValueKind::kText: return "text";
    case ValueKind::kChoice: return "choice";
    case ValueKind::kNumbers: return "numbers";
    case ValueKind::kNames: return "names";
    case ValueKind::kCovariance: return "covariance";
    case ValueKind::kInitialState: return "initial_state";
    case ValueKind::kBounds: return "bounds";
    case ValueKind::kFixed: return "fixed";
  }
  return "text";
}

const std::vector<SettingField>& settings_of(const Descriptor& request) {
  Schemas& s = schemas();
  const std::lock_guard lock(s.mutex);
  auto [it, made] = s.by_request.try_emplace(&request);
  if (made) {
    std::vector<const FieldDescriptor*> chain;
    walk(request, &chain, &it->second);
  }
  return it->second;
}

std::string_view implied_method(const Descriptor& request) {
  if (&request == v1::CreateSessionRequest::descriptor() || &request == v1::SmoothingSpec::descriptor()) return "filter";
  return {};
}

bool offered(const Descriptor& request, const SettingField& s) {
  const std::string_view method = implied_method(request);
  if (!method.empty() && s.setting->methods_size() > 0 && !contains(s.setting->methods(), method)) return false;
  // A smoother runs the EKF or the UKF: not the optimal filter's settings.
  if (&request == v1::SmoothingSpec::descriptor() && s.setting->filters_size() > 0) {
    return contains(s.setting->filters(), "ekf") || contains(s.setting->filters(), "ukf");
  }
  return true;
}

const SettingField* find_setting(const Descriptor& request, std::string_view path) {
  for (const SettingField& s : settings_of(request)) {
    if (s.path == path) return &s;
  }
  return nullptr;
}

const SettingField* find_setting_by_flag(const Descriptor& request, std::string_view flag) {
  for (const SettingField& s : settings_of(request)) {
    if (s.setting->flag() == flag) return &s;
  }
  return nullptr;
}

bool is_given(const Message& request, const SettingField& s) {
  const Message* holder = &request;
  for (std::size_t i = 0; i + 1 < s.chain.size(); ++i) {
    const Reflection* r = holder->GetReflection();
    if (!r->HasField(*holder, s.chain[i])) return false;
    holder = &r->GetMessage(*holder, s.chain[i]);
  }
  const Reflection* r = holder->GetReflection();
  if (s.field->is_repeated()) return r->FieldSize(*holder, s.field) > 0;
  return r->HasField(*holder, s.field);  // proto3 scalars: not the default
}

Message* mutable_holder(Message* request, const SettingField& s) {
  Message* holder = request;
  for (std::size_t i = 0; i + 1 < s.chain.size(); ++i) {
    holder = holder->GetReflection()->MutableMessage(holder, s.chain[i]);
  }
  return holder;
}

std::string keyword_of(const v1::Setting& setting) {
  std::string_view flag = setting.flag();
  while (flag.starts_with('-')) flag.remove_prefix(1);
  std::string out(flag);
  std::replace(out.begin(), out.end(), '-', '_');
  return out;
}

std::string choice_of(const Message& request, std::string_view path) {
  const SettingField* s = find_setting(*request.GetDescriptor(), path);
  if (s == nullptr || s->kind != ValueKind::kChoice) return {};
  if (!is_given(request, *s)) return s->setting->default_value();
  const Message* holder = &request;
  for (std::size_t i = 0; i + 1 < s->chain.size(); ++i) holder = &holder->GetReflection()->GetMessage(*holder, s->chain[i]);
  return enum_value_name(*holder->GetReflection()->GetEnum(*holder, s->field));
}

std::string misplaced_setting(const Message& request, std::string_view method, std::string_view filter) {
  if (method.empty()) method = implied_method(*request.GetDescriptor());
  for (const SettingField& s : settings_of(*request.GetDescriptor())) {
    if (!is_given(request, s)) continue;
    const v1::Setting& o = *s.setting;
    if (!method.empty() && o.methods_size() > 0 && !contains(o.methods(), method)) {
      return s.path + " applies to method " + joined(o.methods(), "and") + " only, not to " + std::string(method);
    }
    if (!filter.empty() && o.filters_size() > 0 && !contains(o.filters(), filter)) {
      return s.path + " applies to the " + joined(o.filters(), "and") + (o.filters_size() > 1 ? " filters" : " filter") +
             " only, not to the " + std::string(filter) + " filter";
    }
  }
  return {};
}

std::vector<const Descriptor*> setting_requests() {
  return {v1::IdentificationSpec::descriptor(), v1::SmoothingSpec::descriptor(), v1::ValidationSpec::descriptor(),
          v1::CreateSessionRequest::descriptor(), v1::RetuneSessionRequest::descriptor(),
          v1::SimulateRequest::descriptor()};
}

std::string settings_schema_json() {
  using google::protobuf::ListValue;
  using google::protobuf::Struct;
  using google::protobuf::Value;
  const auto strings = [](const auto& items) {
    Value v;
    ListValue* list = v.mutable_list_value();
    for (const auto& item : items) list->add_values()->set_string_value(std::string(item));
    return v;
  };
  Struct root;
  Struct* requests = (*root.mutable_fields())["requests"].mutable_struct_value();
  for (const Descriptor* request : setting_requests()) {
    ListValue* list = (*requests->mutable_fields())[std::string(request->name())].mutable_list_value();
    for (const SettingField& s : settings_of(*request)) {
      if (!offered(*request, s)) continue;
      Struct* item = list->add_values()->mutable_struct_value();
      auto& f = *item->mutable_fields();
      const v1::Setting& o = *s.setting;
      f["path"].set_string_value(s.path);
      f["flag"].set_string_value(o.flag());
      f["keyword"].set_string_value(keyword_of(o));
      f["kind"].set_string_value(value_kind_name(s.kind));
      f["help"].set_string_value(o.help());
      if (!o.unit().empty()) f["unit"].set_string_value(o.unit());
      if (!o.default_value().empty()) f["default"].set_string_value(o.default_value());
      if (!o.form().empty()) f["form"].set_string_value(o.form());
      if (!o.implicit().empty()) f["implicit"].set_string_value(o.implicit());
      if (!o.group().empty()) f["group"].set_string_value(o.group());
      if (o.methods_size() > 0) f["methods"] = strings(o.methods());
      if (o.filters_size() > 0) f["filters"] = strings(o.filters());
      if (o.has_minimum()) f["minimum"].set_number_value(o.minimum());
      if (o.has_maximum()) f["maximum"].set_number_value(o.maximum());
      if (s.kind == ValueKind::kChoice) {
        f["choices"] = strings(enum_choice_names(*s.field->enum_type()));
        // "values": the same choices as the JSON mapping names them
        // ("FILTER_KIND_EKF"), in the same order: what a client sends in a request's JSON.
        std::vector<std::string> values;
        for (const auto* v : enum_choices(*s.field->enum_type())) values.emplace_back(v->name());
        f["values"] = strings(values);
      }
    }
  }
  (*root.mutable_fields())["methods"] = strings(enum_choice_names(*v1::IdentificationMethod_descriptor()));
  (*root.mutable_fields())["filters"] = strings(enum_choice_names(*v1::FilterKind_descriptor()));
  std::string json;
  if (!google::protobuf::util::MessageToJsonString(root, &json).ok()) throw std::logic_error("settings schema to JSON");
  return json;
}

}  // namespace riccati::api
