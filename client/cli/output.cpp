#include "output.hpp"

#include <google/protobuf/util/json_util.h>

#include <cstdio>
#include <ctime>
#include <sstream>

#include "riccati/enum_names.hpp"

namespace riccati::cli {

namespace {

using google::protobuf::Descriptor;
using google::protobuf::FieldDescriptor;

// proto3's JSON writes 64-bit integers as strings (for JavaScript, whose
// numbers end at 2^53); riccati's counts and sizes never come near that,
// and scripts compare them as numbers. Walks `j` beside the message's
// descriptor and turns those strings back into numbers. The well-known
// types (Timestamp, Duration) keep their JSON strings.
void int64_as_numbers(nlohmann::json& j, const Descriptor& d) {
  if (!j.is_object() || d.file()->package() == "google.protobuf") return;
  for (int f = 0; f < d.field_count(); ++f) {
    const FieldDescriptor& field = *d.field(f);
    const auto found = j.find(field.name());
    if (found == j.end() || field.is_map()) continue;
    const auto convert = [&](nlohmann::json& v) {
      if (field.cpp_type() == FieldDescriptor::CPPTYPE_MESSAGE) {
        int64_as_numbers(v, *field.message_type());
      } else if (v.is_string() && field.cpp_type() == FieldDescriptor::CPPTYPE_INT64) {
        v = std::stoll(v.get<std::string>());
      } else if (v.is_string() && field.cpp_type() == FieldDescriptor::CPPTYPE_UINT64) {
        v = std::stoull(v.get<std::string>());
      }
    };
    if (found->is_array()) {
      for (auto& v : *found) convert(v);
    } else {
      convert(*found);
    }
  }
}

}  // namespace

nlohmann::json json_of(const google::protobuf::Message& m) {
  std::string text;
  google::protobuf::util::JsonPrintOptions options;
  options.preserve_proto_field_names = true;
  options.always_print_primitive_fields = true;  // a zero is printed, not left out
  (void)google::protobuf::util::MessageToJsonString(m, &text, options);
  nlohmann::json j = nlohmann::json::parse(text);
  int64_as_numbers(j, *m.GetDescriptor());
  return j;
}

std::string to_json(const nlohmann::json& j) { return j.dump(2); }

std::string counted(unsigned long long n, const std::string& noun, const std::string& plural) {
  return std::to_string(n) + " " + (n == 1 ? noun : plural.empty() ? noun + "s" : plural);
}

std::string to_json(const google::protobuf::Message& m) { return to_json(json_of(m)); }

std::string format(const char* fmt, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, fmt, v);
  return buf;
}

std::string join(const google::protobuf::RepeatedPtrField<std::string>& names) {
  std::string out;
  for (const auto& n : names) out += (out.empty() ? "" : ", ") + n;
  return out;
}

std::string values_list(const google::protobuf::RepeatedField<double>& values) {
  std::string out;
  for (double v : values) out += (out.empty() ? "" : ", ") + format("%.6g", v);
  return "[" + out + "]";
}

double element(const v1::Matrix& m, uint32_t i, uint32_t j) { return m.values(static_cast<int>(i + j * m.rows())); }

std::string state_name(v1::JobState state) {
  const auto* value = v1::JobState_descriptor()->FindValueByNumber(state);
  return value != nullptr ? api::enum_value_name(*value) : "unknown";
}

std::string job_kind(const v1::Job& j) {
  if (j.has_smoothing()) return "smoothing";
  return j.has_validation() ? "validation" : "identification";
}

std::string progress_text(const v1::JobProgress& p) {
  // OE and ML report the optimiser's iterations once it runs (passes first, with --init-passes).
  if (p.iteration() > 0) return "iteration " + std::to_string(p.iteration()) + ", cost " + format("%.6g", p.cost());
  if (p.passes() > 0) return "pass " + std::to_string(p.pass_number()) + "/" + std::to_string(p.passes());
  return "";
}

std::string utc_time(const google::protobuf::Timestamp& t) {
  if (t.seconds() == 0 && t.nanos() == 0) return "-";
  const std::time_t seconds = static_cast<std::time_t>(t.seconds());
  std::tm utc{};
  gmtime_r(&seconds, &utc);
  char text[32];
  std::strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%SZ", &utc);
  return text;
}

std::string job_header() {
  char line[256];
  std::snprintf(line, sizeof line, "%-22s %-15s %-10s %-20s %-20s %-22s %s", "id", "kind", "state", "created", "model",
                "dataset", "progress");
  return line;
}

std::string job_line(const v1::Job& j) {
  const std::string& model = j.has_smoothing()    ? j.smoothing().model()
                             : j.has_validation() ? j.validation().model()
                                                  : j.identification().model();
  const std::string& dataset = j.has_smoothing()    ? j.smoothing().dataset_id()
                               : j.has_validation() ? j.validation().dataset_id()
                                                    : j.identification().dataset_id();
  char line[512];
  std::snprintf(line, sizeof line, "%-22s %-15s %-10s %-20s %-20s %-22s %s", j.id().c_str(), job_kind(j).c_str(),
                state_name(j.state()).c_str(), utc_time(j.created()).c_str(), model.c_str(),
                dataset.empty() ? "-" : dataset.c_str(), progress_text(j.progress()).c_str());
  return line;
}

std::string parameter_table(const v1::IdentificationResult& r, const std::vector<double>& initial,
                            const std::vector<double>& truth) {
  const int n = r.param_names_size();
  const bool with_truth = static_cast<int>(truth.size()) == n;
  const bool with_initial = static_cast<int>(initial.size()) == n;
  // Results stored before the intervals have none: theta_std was sqrt(diag P).
  const bool with_intervals = r.ci_lower_size() == n && r.ci_upper_size() == n;
  std::string out;
  char line[320];
  std::snprintf(line, sizeof line, "%-10s %12s %14s %11s %29s %12s %12s", "parameter", "initial", "estimate",
                "std. error", "95 % interval", "filter std", "final");
  out += line;
  if (with_truth) {
    std::snprintf(line, sizeof line, " %12s %9s", "true", "error %");
    out += line;
  }
  out += "\n";
  for (int i = 0; i < n; ++i) {
    const std::string interval =
        with_intervals ? "[" + format("%.8g", r.ci_lower(i)) + ", " + format("%.8g", r.ci_upper(i)) + "]" : "-";
    const std::string filter_std = i < r.filter_theta_std_size() ? format("%.4g", r.filter_theta_std(i)) : "-";
    std::snprintf(line, sizeof line, "%-10s %12s %14.8g %11.4g %29s %12s %12.6g", r.param_names(i).c_str(),
                  with_initial ? format("%.6g", initial[i]).c_str() : "-", r.theta_mean(i), r.theta_std(i),
                  interval.c_str(), filter_std.c_str(), r.theta(i));
    out += line;
    if (with_truth) {
      std::snprintf(line, sizeof line, " %12.6g %9.3f", truth[i], 100.0 * (r.theta_mean(i) - truth[i]) / truth[i]);
      out += line;
      if (with_intervals && (truth[i] < r.ci_lower(i) || truth[i] > r.ci_upper(i))) out += "  (outside the interval)";
    }
    out += "\n";
  }
  out += "(estimate: the mean over the last pass, as the 1999 toolbox reports; final: at its end; filter std: "
         "sqrt(diag P) at the end, the toolbox's, which counts the record once per pass)\n";
  if (!r.covariance_method().empty()) out += "std. error and interval: " + r.covariance_method() + "\n";
  if (r.warnings_size() > 0) {
    out += "warnings:\n";
    for (const auto& w : r.warnings()) out += "  " + w + "\n";
  }
  return out;
}

std::string fit_table(const google::protobuf::RepeatedPtrField<v1::OutputFit>& fits, const std::string& indent) {
  std::string out;
  char line[256];
  std::snprintf(line, sizeof line, "%s%-12s %12s %10s %10s %12s\n", indent.c_str(), "output", "RMSE", "fit %", "VAF %",
                "RRSE");
  out += line;
  for (const auto& f : fits) {
    std::snprintf(line, sizeof line, "%s%-12s %12.4g %10.3f %10.3f %12.4g\n", indent.c_str(), f.name().c_str(),
                  f.rmse(), f.fit_percent(), f.vaf_percent(), f.rrse());
    out += line;
  }
  return out;
}

std::string fit_table(const v1::ValidationResult& r) {
  std::string out;
  // Where the parameters and initial states came from (a job's estimate, fitted x0), when riccatid says.
  if (!r.parameters_from().empty()) out += "parameters: " + r.parameters_from() + " " + values_list(r.theta()) + "\n";
  if (!r.x0_from().empty()) out += "x0: " + r.x0_from() + " " + values_list(r.x0()) + "\n";
  out += r.horizon() > 0 ? "fit of the " + std::to_string(r.horizon()) + "-step-ahead predictions: " + r.predictor() + "\n"
                         : "fit of the simulation:\n";
  return out + fit_table(r.fits());
}

std::string result_table(const v1::JobResult& r, const std::vector<double>& initial, const std::vector<double>& truth,
                         const ModelNames& names) {
  if (r.has_estimation()) return estimation_table(r.estimation(), initial, truth, names);
  if (r.has_smoothing()) return smoothing_table(r.smoothing());
  if (!r.has_identification()) return fit_table(r.validation());
  std::string text = parameter_table(r.identification(), initial, truth);
  const auto& last = r.identification().passes(r.identification().passes_size() - 1);
  std::string rms;
  for (double v : last.innovation_rms()) rms += format(" %.3g", v);
  return text + "innovation RMS (last pass):" + rms + "; mean NIS " + format("%.3g", last.nis_mean()) + "\n";
}

std::string result_csv(const v1::JobResult& r, const ModelNames& names) {
  if (r.has_estimation()) return estimation_csv(r.estimation(), names);
  if (r.has_smoothing()) return smoothing_csv(r.smoothing(), names);
  std::ostringstream csv;
  csv.precision(17);
  if (r.has_identification()) {
    const auto& id_r = r.identification();
    const auto& last = id_r.passes(id_r.passes_size() - 1);
    const auto states = sized_names(names.states, id_r.x_trace().rows(), "x");
    const auto outputs = sized_names(names.outputs, id_r.y_model().rows(), "y");
    csv << "t";
    for (const auto& n : states) csv << "," << n;
    for (const auto& n : id_r.param_names()) csv << "," << n;
    for (const auto& n : outputs) csv << "," << column("y_model", n);
    for (const auto& n : outputs) csv << "," << column("innovation", n);
    csv << "\n";
    for (int k = 0; k < id_r.t_size(); ++k) {
      csv << id_r.t(k);
      for (uint32_t i = 0; i < id_r.x_trace().rows(); ++i) csv << "," << element(id_r.x_trace(), i, k);
      for (uint32_t i = 0; i < last.theta_trace().rows(); ++i) csv << "," << element(last.theta_trace(), i, k);
      for (uint32_t i = 0; i < id_r.y_model().rows(); ++i) csv << "," << element(id_r.y_model(), i, k);
      for (uint32_t i = 0; i < id_r.innovations().rows(); ++i) csv << "," << element(id_r.innovations(), i, k);
      csv << "\n";
    }
    return csv.str();
  }
  const auto& v = r.validation();
  std::vector<std::string> fitted;
  for (const auto& f : v.fits()) fitted.push_back(f.name());
  const auto outputs = sized_names(fitted.empty() ? names.outputs : fitted, v.y_measured().rows(), "y");
  csv << "t";
  for (const char* quantity : {"y", "y_model", "residual"}) {
    for (const auto& n : outputs) csv << "," << column(quantity, n);
  }
  csv << "\n";
  for (int k = 0; k < v.t_size(); ++k) {
    csv << v.t(k);
    for (uint32_t i = 0; i < v.y_measured().rows(); ++i) csv << "," << element(v.y_measured(), i, k);
    for (uint32_t i = 0; i < v.y_simulated().rows(); ++i) csv << "," << element(v.y_simulated(), i, k);
    for (uint32_t i = 0; i < v.y_measured().rows(); ++i) {
      csv << "," << element(v.y_measured(), i, k) - element(v.y_simulated(), i, k);
    }
    csv << "\n";
  }
  return csv.str();
}

}  // namespace riccati::cli
