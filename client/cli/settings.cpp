#include "settings.hpp"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <charconv>
#include <limits>
#include <sstream>
#include <type_traits>
#include <variant>

#include "riccati/enum_names.hpp"

namespace riccati::cli {

namespace {

using google::protobuf::EnumDescriptor;

template <typename T>
using Member = std::optional<T> RunSettings::*;
using Names = std::vector<std::string> RunSettings::*;

// Where a setting goes in RunSettings; its type says how the value is read.
// (int: an enum's number, with the enum's descriptor in the setting.)
using Target = std::variant<Member<std::string>, Member<int>, Member<double>, Member<std::uint64_t>, Member<bool>,
                            Member<std::vector<double>>, Member<v1::Covariance>, Member<v1::InitialState>, Names,
                            Member<std::vector<NamedRange>>, Member<std::vector<NamedValue>>,
                            Member<std::vector<SampleSpan>>>;

struct Setting {
  std::string key;                   // in the job file; "integrator.kind" is kind: under integrator:
  std::vector<std::string> aliases;  // other spellings of the key ("integrator": the kind alone)
  std::string flag;                  // CLI11's names of the flag
  unsigned commands = 0;             // the commands whose flags include it (a bit per Command)
  std::string help;
  Target target;
  const EnumDescriptor* choices = nullptr;  // enum settings: the API enum
  bool flag_value = true;                   // bool settings: what the flag sets
  std::string form;      // how a value is written, for --help ("NAME=LO:HI"); empty: its type's name
  std::string implicit;  // lists of names: the value of the flag given alone ("all"); empty: it needs one
};

constexpr unsigned bit(Command c) { return static_cast<unsigned>(c); }
constexpr unsigned kIdentify = bit(Command::kIdentify);
constexpr unsigned kValidate = bit(Command::kValidate);
constexpr unsigned kSmooth = bit(Command::kSmooth);
constexpr unsigned kFilter = kIdentify | bit(Command::kStream);    // runs of a filter from theta0, any kind
constexpr unsigned kKalman = kFilter | kSmooth;                    // runs of a filter (smooth: the EKF or UKF)
constexpr unsigned kColumns = kKalman | kValidate;                 // runs on measured data
constexpr unsigned kSimulation = kColumns | bit(Command::kSimulate);  // runs that integrate the model
constexpr unsigned kParams = kValidate | bit(Command::kSimulate) | kSmooth;  // commands with --params
constexpr unsigned kRetune = bit(Command::kRetune);  // what RetuneSession changes: Q, R, V, W

// Every setting, once. The job-file reader and the flags are made from it.
const std::vector<Setting>& settings() {
  static const std::vector<Setting> table = {
      {.key = "model", .flag = "--model,-m", .commands = kSimulation, .help = "Model name",
       .target = &RunSettings::model},
      {.key = "data", .flag = "--data,-d", .commands = kIdentify | kValidate | kSmooth,
       .help = "Dataset id, or a local CSV/MAT file to upload", .target = &RunSettings::data},
      {.key = "inputs", .flag = "--inputs", .commands = kColumns, .help = "Input columns, in the model's order",
       .target = &RunSettings::inputs},
      {.key = "outputs", .flag = "--outputs", .commands = kColumns, .help = "Output columns, in the model's order",
       .target = &RunSettings::outputs},
      {.key = "filter", .flag = "--filter", .commands = kKalman, .help = "Filter kind (default ekf)",
       .target = &RunSettings::filter, .choices = v1::FilterKind_descriptor()},
      {.key = "passes", .flag = "--passes", .commands = kIdentify, .help = "Passes over the data",
       .target = &RunSettings::passes},
      {.key = "x0", .flag = "--x0", .commands = kColumns,
       .help = "Initial state: first (the first measurement, the default) or a list", .target = &RunSettings::x0},
      {.key = "theta0", .flag = "--theta0", .commands = kFilter, .help = "Initial parameters (default: the model's)",
       .target = &RunSettings::theta0},
      {.key = "P0", .aliases = {"p0"}, .flag = "--p0", .commands = kKalman,
       .help = "Initial variances of [x; theta] (one value: all; default: 0 for a state that starts at its "
               "measurement, 1 for another, theta0_i^2 for parameter i)",
       .target = &RunSettings::p0},
      {.key = "Q", .aliases = {"q"}, .flag = "--q", .commands = kKalman | kRetune,
       .help = "Process noise intensities of [x; theta] (one value: all)", .target = &RunSettings::q},
      {.key = "R", .aliases = {"r"}, .flag = "--r", .commands = kKalman | kRetune,
       .help = "Measurement noise variances (one value: all)", .target = &RunSettings::r},
      {.key = "hold", .flag = "--hold", .commands = kSimulation, .help = "Input hold", .target = &RunSettings::hold,
       .choices = v1::HoldOrder_descriptor()},
      {.key = "integrator.kind", .aliases = {"integrator"}, .flag = "--integrator", .commands = kSimulation,
       .help = "Integrator", .target = &RunSettings::integrator, .choices = v1::IntegratorKind_descriptor()},
      {.key = "integrator.substeps", .flag = "--substeps", .commands = kSimulation,
       .help = "Fixed-step integrators: steps per sample", .target = &RunSettings::substeps},
      {.key = "integrator.rtol", .flag = "--rtol", .commands = kSimulation,
       .help = "Adaptive integrators: relative tolerance", .target = &RunSettings::rtol},
      {.key = "integrator.atol", .flag = "--atol", .commands = kSimulation,
       .help = "Adaptive integrators: absolute tolerance", .target = &RunSettings::atol},
      {.key = "inversion", .flag = "--inversion", .commands = kKalman, .help = "Gain solve",
       .target = &RunSettings::inversion, .choices = v1::GainInversion_descriptor()},
      {.key = "joseph", .flag = "--no-joseph", .commands = kKalman, .help = "EKF: short covariance update",
       .target = &RunSettings::joseph, .flag_value = false},
      {.key = "ukf.weights", .flag = "--weights", .commands = kKalman, .help = "UKF weights",
       .target = &RunSettings::weights, .choices = v1::SigmaWeights_descriptor()},
      {.key = "ukf.alpha", .flag = "--alpha", .commands = kKalman, .help = "UKF scaled weights: alpha",
       .target = &RunSettings::alpha},
      {.key = "ukf.beta", .flag = "--beta", .commands = kKalman, .help = "UKF scaled weights: beta",
       .target = &RunSettings::beta},
      {.key = "ukf.kappa", .flag = "--kappa", .commands = kKalman, .help = "UKF kappa", .target = &RunSettings::kappa},
      {.key = "optimal.V", .aliases = {"optimal.v"}, .flag = "--v", .commands = kFilter | kRetune,
       .help = "Optimal filter: weights of the equations of motion, inputs, outputs", .target = &RunSettings::v},
      {.key = "optimal.W", .aliases = {"optimal.w"}, .flag = "--w", .commands = kFilter | kRetune,
       .help = "Optimal filter: weights of the states and parameters", .target = &RunSettings::w},
      {.key = "optimal.R0", .aliases = {"optimal.r0"}, .flag = "--r0", .commands = kFilter,
       .help = "Optimal filter: confidence in x0 and theta0 (instead of --p0)", .target = &RunSettings::r0},
      {.key = "optimal.form", .flag = "--form", .commands = kFilter, .help = "Optimal filter: form",
       .target = &RunSettings::form, .choices = v1::OptimalForm_descriptor()},
      {.key = "optimal.hold_outputs", .flag = "--hold-outputs", .commands = kFilter,
       .help = "Optimal filter: hold outputs over a step (strict real time)", .target = &RunSettings::hold_outputs},
      {.key = "first_sample", .flag = "--first-sample", .commands = kIdentify | kSmooth,
       .help = "First sample used, 0-based (identify: a trial on a slice of the data; default 0)",
       .target = &RunSettings::first_sample},
      {.key = "end_sample", .flag = "--end-sample", .commands = kIdentify | kSmooth,
       .help = "Sample after the last used, 0-based (default 0: to the end)", .target = &RunSettings::end_sample},
      {.key = "truth", .flag = "--truth", .commands = kIdentify, .help = "True parameters, to print the error",
       .target = &RunSettings::truth},
      // Output error and maximum likelihood.
      {.key = "method", .flag = "--method", .commands = kIdentify,
       .help = "How the parameters are found: the iterated filter's passes (the default), output error (the "
               "simulated outputs' squared errors) or maximum likelihood (the EKF's or UKF's innovations)",
       .target = &RunSettings::method, .choices = v1::IdentificationMethod_descriptor()},
      {.key = "init_passes", .flag = "--init-passes", .commands = kIdentify,
       .help = "oe, ml: passes of the iterated filter (--filter, --p0, --q, --r) first; their estimate (the mean "
               "over the last pass, within the bounds) starts the optimiser (default 0: it starts at --theta0)",
       .target = &RunSettings::init_passes},
      {.key = "bounds", .flag = "--bound", .commands = kIdentify,
       .help = "A parameter's bounds, in its unit; LO or HI may be left empty (the model's bound stays). "
               "Repeatable. The filter method holds its estimate within them",
       .target = &RunSettings::bounds, .form = "NAME=LO:HI"},
      {.key = "fixed", .flag = "--fix", .commands = kIdentify,
       .help = "Hold a parameter fixed: at its --theta0 (NAME) or at VALUE. Repeatable",
       .target = &RunSettings::fixed, .form = "NAME[=VALUE]"},
      {.key = "log_scale", .flag = "--log-scale", .commands = kIdentify,
       .help = "oe, ml: estimate these parameters as log(theta), for positive ones spanning decades (each needs "
               "a positive lower bound). Names, comma-separated or repeated",
       .target = &RunSettings::log_scale, .form = "NAME"},
      {.key = "estimate_x0", .flag = "--estimate-x0", .commands = kIdentify,
       .help = "oe, ml: estimate these initial states, starting from --x0, in every experiment: names, "
               "comma-separated, or all (the flag alone: all)",
       .target = &RunSettings::estimate_x0, .form = "[STATE,...|all]", .implicit = "all"},
      {.key = "experiments", .flag = "--experiment", .commands = kIdentify,
       .help = "oe, ml: another record of the system, a dataset id or a local file (uploaded with --inputs and "
               "--outputs), with the same parameters and its own initial state (as --x0 and --estimate-x0 say). "
               "Repeatable: experiments 2, 3, ... in order; --data is experiment 1",
       .target = &RunSettings::experiments, .form = "DATA"},
      {.key = "exclude", .flag = "--exclude", .commands = kIdentify,
       .help = "Leave samples FIRST to END-1 (0-based) of experiment E out (E: 1, the default, is --data; 2, 3, ... "
               "the --experiment records). Repeatable",
       .target = &RunSettings::exclude, .form = "[E@]FIRST:END"},
      {.key = "output_limits", .flag = "--output-limit", .commands = kIdentify,
       .help = "An output's saturation, in its unit: samples where it is at or below LO, or at or above HI, are "
               "left out, in every experiment; LO or HI may be left empty. Repeatable",
       .target = &RunSettings::output_limits, .form = "OUTPUT=LO:HI"},
      {.key = "estimation.output_sigma", .flag = "--output-sigma", .commands = kIdentify,
       .help = "oe: each output's noise standard deviation, in its unit, when known: the residuals are weighted by "
               "1/sigma and the covariance is absolute (default: every output weighted 1, the covariance scaled "
               "by the residuals' variance)",
       .target = &RunSettings::output_sigma},
      {.key = "estimation.estimate_q", .flag = "--estimate-q", .commands = kIdentify,
       .help = "ml: also estimate the diagonal of the states' process noise Q, from --q (positive for every state)",
       .target = &RunSettings::estimate_q},
      {.key = "estimation.estimate_r", .flag = "--estimate-r", .commands = kIdentify,
       .help = "ml: also estimate the diagonal of the measurement noise R, from --r",
       .target = &RunSettings::estimate_r},
      {.key = "estimation.max_iterations", .flag = "--max-iterations", .commands = kIdentify,
       .help = "oe, ml: the optimiser's iterations at most (default 200)", .target = &RunSettings::max_iterations},
      {.key = "estimation.function_tolerance", .flag = "--function-tolerance", .commands = kIdentify,
       .help = "oe, ml: stop when an iteration changes the criterion by less than this, relatively (default 1e-14)",
       .target = &RunSettings::function_tolerance},
      {.key = "estimation.gradient_tolerance", .flag = "--gradient-tolerance", .commands = kIdentify,
       .help = "oe, ml: stop when the largest gradient entry is below this, relatively (default 1e-14)",
       .target = &RunSettings::gradient_tolerance},
      {.key = "estimation.parameter_tolerance", .flag = "--parameter-tolerance", .commands = kIdentify,
       .help = "oe, ml: stop when an iteration changes the unknowns by less than this, relatively (default 1e-12)",
       .target = &RunSettings::parameter_tolerance},
      // Which estimate --params takes, and validate's fitted initial states.
      {.key = "estimate", .flag = "--estimate", .commands = kParams,
       .help = "Which estimate of an iterated-filter job --params takes: the mean over its last pass (the default, "
               "as the 1999 toolbox reports) or the estimate at its end; oe and ml jobs have one",
       .target = &RunSettings::estimate, .choices = v1::EstimateChoice_descriptor()},
      {.key = "estimate_x0_samples", .flag = "--estimate-x0", .commands = kValidate,
       .help = "Fit every initial state (from --x0) by output error on the first M samples, the parameters held, "
               "then simulate the whole record from them (default: x0 as given)",
       .target = &RunSettings::x0_samples, .form = "M"},
  };
  return table;
}

const Setting* find_setting(std::string_view key) {
  for (const Setting& setting : settings()) {
    if (setting.key == key) return &setting;
    for (const std::string& alias : setting.aliases) {
      if (alias == key) return &setting;
    }
  }
  return nullptr;
}

// The keys grouped under `group` in a job file ("kind, substeps, rtol, atol"); empty: it is no group.
std::string group_keys(std::string_view group) {
  std::string keys;
  for (const Setting& setting : settings()) {
    const std::string_view key = setting.key;
    if (key.size() > group.size() && key.starts_with(group) && key[group.size()] == '.') {
      keys += (keys.empty() ? "" : ", ") + std::string(key.substr(group.size() + 1));
    }
  }
  return keys;
}

// How --help shows the value a flag takes.
std::string type_name(const Setting& setting) {
  if (!setting.form.empty()) return setting.form;
  if (std::holds_alternative<Member<double>>(setting.target)) return "FLOAT";
  if (std::holds_alternative<Member<std::uint64_t>>(setting.target)) return "UINT";
  return "TEXT";
}

// Settings whose flag is repeated (or given a comma-separated list), one item each.
bool takes_items(const Target& target) {
  return std::holds_alternative<Names>(target) || std::holds_alternative<Member<std::vector<NamedRange>>>(target) ||
         std::holds_alternative<Member<std::vector<NamedValue>>>(target) ||
         std::holds_alternative<Member<std::vector<SampleSpan>>>(target);
}

std::string help_of(const Setting& setting) {
  if (setting.choices == nullptr) return setting.help;
  return setting.help + " (" + api::enum_choice_list(*setting.choices) + ")";
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

bool read_value(const Setting& setting, const YAML::Node& node, RunSettings* s, std::string* error) {
  return std::visit(
      [&](auto member) {
        auto& to = s->*member;
        if constexpr (std::is_same_v<decltype(member), Names>) {
          return read(node, &to, error);
        } else {
          using Value = typename std::remove_reference_t<decltype(to)>::value_type;
          Value value{};
          bool ok = false;
          if constexpr (std::is_same_v<Value, int>) {
            ok = read_choice(node, *setting.choices, &value, error);
          } else {
            ok = read(node, &value, error);
          }
          if (ok) to = std::move(value);
          return ok;
        }
      },
      setting.target);
}

// A flag's text as a job file would have it: commas make a list, for the
// settings that take one.
YAML::Node written(const Setting& setting, const std::string& text) {
  const bool takes_list = std::holds_alternative<Member<std::vector<double>>>(setting.target) ||
                          std::holds_alternative<Member<v1::Covariance>>(setting.target) ||
                          std::holds_alternative<Member<v1::InitialState>>(setting.target);
  if (!takes_list || text.find(',') == std::string::npos) return YAML::Node(text);
  YAML::Node list(YAML::NodeType::Sequence);
  std::stringstream items(text);
  for (std::string item; std::getline(items, item, ',');) list.push_back(item);
  return list;
}

// One key of a job file (under `group`, if any): a setting, or a group of them.
bool read_entry(const std::string& group, const YAML::Node& key_node, const YAML::Node& value, RunSettings* s,
                std::string* error) {
  const std::string key = (group.empty() ? "" : group + ".") + key_node.Scalar();
  const std::string where = in_quotes(key) + " (line " + std::to_string(key_node.Mark().line + 1) + ")";
  const Setting* setting = find_setting(key);
  const std::string grouped = group.empty() ? group_keys(key) : "";
  if (!grouped.empty() && (value.IsMap() || setting == nullptr)) {
    if (!value.IsMap()) {
      *error = "key " + where + ": expected a map (" + grouped + ")";
      return false;
    }
    for (const auto& entry : value) {
      if (!read_entry(key, entry.first, entry.second, s, error)) return false;
    }
    return true;
  }
  if (setting == nullptr) {
    *error = "unknown key " + where + (group.empty() ? "" : " (expected " + group_keys(group) + ")");
    return false;
  }
  if (!read_value(*setting, value, s, error)) {
    *error = "key " + where + ": " + *error;
    return false;
  }
  return true;
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
  const Setting* setting;
  CLI::Option* option = nullptr;
  std::string text;
  std::vector<std::string> names;
  bool on = false;
};

RunFlags::RunFlags(CLI::App* cmd, Command command) {
  for (const Setting& setting : settings()) {
    if ((setting.commands & bit(command)) == 0) continue;
    Flag& flag = flags_.emplace_back(Flag{&setting});
    if (std::holds_alternative<Member<bool>>(setting.target)) {
      flag.option = cmd->add_flag(setting.flag, flag.on, help_of(setting));
    } else if (takes_items(setting.target)) {
      // One item per occurrence (or a comma-separated list); never the next word.
      flag.option = cmd->add_option(setting.flag, flag.names, help_of(setting))
                        ->delimiter(',')
                        ->allow_extra_args(false)
                        ->type_name(type_name(setting));
      if (!setting.implicit.empty()) flag.option->expected(0, 1);
    } else {
      flag.option = cmd->add_option(setting.flag, flag.text, help_of(setting))->type_name(type_name(setting));
    }
  }
}

RunFlags::~RunFlags() = default;

bool RunFlags::apply(RunSettings* s, std::string* error) const {
  for (const Flag& flag : flags_) {
    if (flag.option->count() == 0) continue;
    const Setting& setting = *flag.setting;
    if (const auto* member = std::get_if<Member<bool>>(&setting.target)) {
      s->**member = setting.flag_value;
    } else if (const auto* names = std::get_if<Names>(&setting.target)) {
      // The flag without a value (CLI11 gives one empty text).
      const bool alone = !setting.implicit.empty() &&
                         std::all_of(flag.names.begin(), flag.names.end(), [](const std::string& n) { return n.empty(); });
      s->**names = alone ? std::vector<std::string>{setting.implicit} : flag.names;
    } else if (takes_items(setting.target)) {
      YAML::Node items(YAML::NodeType::Sequence);
      for (const std::string& item : flag.names) items.push_back(item);
      if (!read_value(setting, items, s, error)) {
        *error = flag.option->get_name() + ": " + *error;
        return false;
      }
    } else if (!read_value(setting, written(setting, flag.text), s, error)) {
      *error = flag.option->get_name() + ": " + *error;
      return false;
    }
  }
  return true;
}

void RunFlags::require(std::string_view key) {
  for (Flag& flag : flags_) {
    if (flag.setting->key == key) flag.option->required();
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

namespace {

// A count for a uint32 field: past its range is past riccatid's limits too,
// and riccatid says so.
uint32_t saturated(std::uint64_t count) {
  return static_cast<uint32_t>(std::min<std::uint64_t>(count, std::numeric_limits<uint32_t>::max()));
}

}  // namespace

std::optional<v1::IntegratorSettings> to_integrator(const RunSettings& s) {
  if (!s.integrator && !s.substeps && !s.rtol && !s.atol) return std::nullopt;
  v1::IntegratorSettings out;
  if (s.integrator) out.set_kind(static_cast<v1::IntegratorKind>(*s.integrator));
  if (s.substeps) out.set_substeps(saturated(*s.substeps));
  if (s.rtol) out.set_rtol(*s.rtol);
  if (s.atol) out.set_atol(*s.atol);
  return out;
}

v1::FilterSettings to_filter_settings(const RunSettings& s) {
  v1::FilterSettings out;
  if (s.filter) out.set_kind(static_cast<v1::FilterKind>(*s.filter));
  if (s.hold) out.set_hold(static_cast<v1::HoldOrder>(*s.hold));
  if (auto integrator = to_integrator(s)) *out.mutable_integrator() = *integrator;
  if (s.q) *out.mutable_q() = *s.q;
  if (s.r) *out.mutable_r() = *s.r;
  if (s.inversion) out.set_inversion(static_cast<v1::GainInversion>(*s.inversion));
  if (s.joseph) out.set_short_covariance_update(!*s.joseph);
  if (s.weights) out.mutable_ukf()->set_weights(static_cast<v1::SigmaWeights>(*s.weights));
  if (s.alpha) out.mutable_ukf()->set_alpha(*s.alpha);
  if (s.beta) out.mutable_ukf()->set_beta(*s.beta);
  if (s.kappa) out.mutable_ukf()->set_kappa(*s.kappa);
  if (s.v) *out.mutable_optimal()->mutable_v() = *s.v;
  if (s.w) *out.mutable_optimal()->mutable_w() = *s.w;
  if (s.r0) *out.mutable_optimal()->mutable_r0() = *s.r0;
  if (s.form) out.mutable_optimal()->set_form(static_cast<v1::OptimalForm>(*s.form));
  if (s.hold_outputs) out.mutable_optimal()->set_hold_outputs(*s.hold_outputs);
  return out;
}

namespace {

v1::InitialState initial_state(const RunSettings& s) {
  if (s.x0) return *s.x0;
  v1::InitialState first;
  first.set_first_measurement(true);
  return first;
}

// What a job and a session share: model, filter, initial state, theta0 and P0.
template <typename Request>
void fill_run(const RunSettings& s, Request* out) {
  out->set_model(s.model.value_or(""));
  *out->mutable_filter() = to_filter_settings(s);
  *out->mutable_initial_state() = initial_state(s);
  if (s.theta0) out->mutable_theta0()->Add(s.theta0->begin(), s.theta0->end());
  if (s.p0) *out->mutable_p0() = *s.p0;
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

// Only what was given: riccatid refuses estimation settings for the filter method.
std::optional<v1::EstimationSettings> estimation_settings(const RunSettings& s) {
  if (!s.output_sigma && !s.estimate_q && !s.estimate_r && !s.max_iterations && !s.function_tolerance &&
      !s.gradient_tolerance && !s.parameter_tolerance) {
    return std::nullopt;
  }
  v1::EstimationSettings out;
  if (s.output_sigma) out.mutable_output_sigma()->Add(s.output_sigma->begin(), s.output_sigma->end());
  if (s.estimate_q) out.set_estimate_process_noise(*s.estimate_q);
  if (s.estimate_r) out.set_estimate_measurement_noise(*s.estimate_r);
  if (s.max_iterations) out.set_max_iterations(saturated(*s.max_iterations));
  if (s.function_tolerance) out.set_function_tolerance(*s.function_tolerance);
  if (s.gradient_tolerance) out.set_gradient_tolerance(*s.gradient_tolerance);
  if (s.parameter_tolerance) out.set_parameter_tolerance(*s.parameter_tolerance);
  return out;
}

}  // namespace

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

v1::IdentificationSpec to_identification_spec(const RunSettings& s, const std::string& dataset_id,
                                              const std::vector<std::string>& more_datasets) {
  v1::IdentificationSpec out;
  fill_run(s, &out);
  out.set_dataset_id(dataset_id);
  if (s.passes) out.set_passes(saturated(*s.passes));
  if (s.first_sample) out.set_first_sample(*s.first_sample);
  if (s.end_sample) out.set_end_sample(*s.end_sample);
  if (s.method) out.set_method(static_cast<v1::IdentificationMethod>(*s.method));
  if (s.init_passes) out.set_init_passes(saturated(*s.init_passes));
  for (const NamedRange& b : s.bounds.value_or(std::vector<NamedRange>{})) {
    v1::ParameterBound* bound = out.add_bounds();
    bound->set_name(b.name);
    if (b.lower) bound->set_lower(*b.lower);
    if (b.upper) bound->set_upper(*b.upper);
  }
  for (const NamedValue& f : s.fixed.value_or(std::vector<NamedValue>{})) {
    v1::FixedParameter* fixed = out.add_fixed();
    fixed->set_name(f.name);
    if (f.value) fixed->set_value(*f.value);
  }
  for (const std::string& name : s.log_scale) out.add_log_scale(name);
  for (const std::string& state : s.estimate_x0) out.mutable_initial_state()->add_estimate(state);
  if (const v1::SampleMask mask = sample_mask(s, 1); mask.ByteSizeLong() > 0) *out.mutable_mask() = mask;
  for (std::size_t e = 0; e < more_datasets.size(); ++e) {
    v1::Experiment* experiment = out.add_experiments();
    experiment->set_dataset_id(more_datasets[e]);
    *experiment->mutable_initial_state() = out.initial_state();
    if (const v1::SampleMask mask = sample_mask(s, e + 2); mask.ByteSizeLong() > 0) *experiment->mutable_mask() = mask;
  }
  if (auto estimation = estimation_settings(s)) *out.mutable_estimation() = *estimation;
  return out;
}

v1::SmoothingSpec to_smoothing_spec(const RunSettings& s, const std::string& dataset_id) {
  v1::SmoothingSpec out;
  fill_run(s, &out);
  out.set_dataset_id(dataset_id);
  if (s.first_sample) out.set_first_sample(*s.first_sample);
  if (s.end_sample) out.set_end_sample(*s.end_sample);
  return out;
}

v1::CreateSessionRequest to_session_request(const RunSettings& s) {
  v1::CreateSessionRequest out;
  fill_run(s, &out);
  return out;
}

v1::ValidationSpec to_validation_spec(const RunSettings& s, const std::string& dataset_id) {
  v1::ValidationSpec out;
  out.set_model(s.model.value_or(""));
  out.set_dataset_id(dataset_id);
  *out.mutable_initial_state() = initial_state(s);
  if (s.hold) out.set_hold(static_cast<v1::HoldOrder>(*s.hold));
  if (auto integrator = to_integrator(s)) *out.mutable_integrator() = *integrator;
  if (s.estimate) out.set_estimate(static_cast<v1::EstimateChoice>(*s.estimate));
  if (s.x0_samples) {
    out.set_estimate_x0_samples(*s.x0_samples);
    out.mutable_initial_state()->add_estimate("all");
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
