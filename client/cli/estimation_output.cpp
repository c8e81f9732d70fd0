#include "estimation_output.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "output.hpp"
#include "riccati/enum_names.hpp"

namespace riccati::cli {

namespace {

std::string name_or_number(const std::vector<std::string>& names, int i, const char* prefix) {
  if (i < static_cast<int>(names.size())) return names[static_cast<std::size_t>(i)];
  std::string numbered = prefix;  // (not prefix + to_string: GCC 12 warns falsely of an overlap)
  return numbered += std::to_string(i + 1);
}

// An experiment's output names: its fits', else the model's, else numbered.
std::vector<std::string> output_names(const v1::ExperimentFit& e, const ModelNames& names) {
  std::vector<std::string> out;
  for (const auto& f : e.fits()) out.push_back(f.name());
  if (out.empty()) out = names.outputs;
  for (int i = static_cast<int>(out.size()); i < static_cast<int>(e.y_measured().rows()); ++i) {
    out.push_back(name_or_number({}, i, "y"));
  }
  return out;
}

const char* verdict(bool pass) { return pass ? "pass" : "FAIL"; }

std::string method_name(v1::IdentificationMethod method) {
  const auto* value = v1::IdentificationMethod_descriptor()->FindValueByNumber(method);
  return value != nullptr ? api::enum_value_name(*value) : "?";
}

// Lines of a noise level estimated (or given): "h1 2.5e-05 (std 1.1e-06)".
std::string noise_line(const char* what, const google::protobuf::RepeatedField<double>& values,
                       const google::protobuf::RepeatedField<double>& stds, const std::vector<std::string>& names,
                       const char* prefix) {
  if (values.empty()) return "";
  std::string line = what;
  for (int i = 0; i < values.size(); ++i) {
    line += (i > 0 ? ", " : " ") + name_or_number(names, i, prefix) + " " + format("%.4g", values[i]);
    if (i < stds.size() && stds[i] > 0.0) line += " (std " + format("%.2g", stds[i]) + ")";
  }
  return line + (std::any_of(stds.begin(), stds.end(), [](double s) { return s > 0.0; }) ? "\n" : " (given)\n");
}

}  // namespace

ModelNames model_names(const v1::ModelInfo& model) {
  ModelNames names;
  names.states.assign(model.state_names().begin(), model.state_names().end());
  names.inputs.assign(model.input_names().begin(), model.input_names().end());
  names.outputs.assign(model.output_names().begin(), model.output_names().end());
  return names;
}

// Q(a, x), the regularised upper incomplete gamma function: the series for
// P = 1 - Q below x = a + 1, Lentz's continued fraction above (Numerical
// Recipes, 3rd ed., sec. 6.2).
double chi_square_p_value(double x, double dof) {
  if (!(x > 0.0)) return 1.0;
  if (!std::isfinite(x)) return 0.0;
  const double a = dof / 2.0, z = x / 2.0;
  const double front = std::exp(-z + a * std::log(z) - std::lgamma(a));
  if (z < a + 1.0) {
    double term = 1.0 / a, sum = term;
    for (int n = 1; n < 10000 && std::abs(term) > std::abs(sum) * 1e-16; ++n) {
      term *= z / (a + n);
      sum += term;
    }
    return std::clamp(1.0 - front * sum, 0.0, 1.0);
  }
  constexpr double kTiny = 1e-300;
  double b = z + 1.0 - a, c = 1.0 / kTiny, d = 1.0 / b, h = d;
  for (int i = 1; i < 10000; ++i) {
    const double an = -i * (i - a);
    b += 2.0;
    d = an * d + b;
    if (std::abs(d) < kTiny) d = kTiny;
    c = b + an / c;
    if (std::abs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    const double step = d * c;
    h *= step;
    if (std::abs(step - 1.0) < 1e-16) break;
  }
  return std::clamp(front * h, 0.0, 1.0);
}

int chi_square_dof(double limit, int max_dof) {
  if (!(limit > 0.0)) return 0;
  for (int dof = 1; dof <= max_dof; ++dof) {
    if (std::abs(chi_square_p_value(limit, dof) - 0.05) < 1e-4) return dof;
  }
  return 0;
}

std::string correlation_table(const v1::EstimationResult& r) {
  std::vector<int> free;
  for (int i = 0; i < r.param_names_size(); ++i) {
    if (!(i < r.fixed_size() && r.fixed(i))) free.push_back(i);
  }
  const v1::Matrix& c = r.correlation();
  if (free.size() < 2 || c.rows() != static_cast<uint32_t>(r.param_names_size()) || c.cols() != c.rows()) return "";
  std::string out = "correlation (* |r| > " + format("%.2g", kHighCorrelation) +
                    ": the data hardly tell these apart)\n" + std::string(10, ' ');
  for (std::size_t j = 0; j + 1 < free.size(); ++j) {
    char column[32];
    std::snprintf(column, sizeof column, "%8s ", r.param_names(free[j]).substr(0, 8).c_str());
    out += column;
  }
  out += "\n";
  bool any = false;
  for (std::size_t i = 1; i < free.size(); ++i) {
    char name[32];
    std::snprintf(name, sizeof name, "%-10s", r.param_names(free[i]).substr(0, 10).c_str());
    out += name;
    for (std::size_t j = 0; j < i; ++j) {
      const double rho = element(c, static_cast<uint32_t>(free[i]), static_cast<uint32_t>(free[j]));
      const bool high = std::abs(rho) > kHighCorrelation;
      any |= high;
      out += format("%8.3f", rho) + (high ? "*" : " ");
    }
    out += "\n";
  }
  if (any) out += "(|r| near 1: a change of one is made up by the other; fix one, or add data that tell them apart)\n";
  return out;
}

std::string diagnostics_table(const v1::Diagnostics& d, const ModelNames& names) {
  std::string out;
  char line[256];
  std::snprintf(line, sizeof line, "  residual diagnostics (each at 95 %%; %s, lags 1..%u, band +-%.3g)\n",
                counted(d.samples(), "sample").c_str(), d.lags(), d.band());
  out += line;
  std::snprintf(line, sizeof line, "    %-28s %12s %10s %9s  %s\n", "test", "statistic", "limit", "p-value", "verdict");
  out += line;
  const int ny = d.ljung_box_size();
  for (int i = 0; i < ny; ++i) {
    const double q = d.ljung_box(i);
    std::snprintf(line, sizeof line, "    %-28s %12.4g %10.4g %9.3g  %s\n",
                  ("white " + name_or_number(names.outputs, i, "y")).c_str(), q, d.ljung_box_limit(),
                  chi_square_p_value(q, d.lags()), verdict(q <= d.ljung_box_limit()));
    out += line;
  }
  const int pairs = d.cross_statistic_size();
  const int nu = ny > 0 ? pairs / ny : 0;
  for (int pair = 0; pair < pairs && nu > 0; ++pair) {
    const double s = d.cross_statistic(pair);
    const double limit = pair < d.cross_limit_size() ? d.cross_limit(pair) : 0.0;
    const std::string what = name_or_number(names.outputs, pair / nu, "y") + " independent of " +
                             name_or_number(names.inputs, pair % nu, "u");
    const int dof = chi_square_dof(limit, static_cast<int>(d.lags()) + 1);
    const std::string p = limit == 0.0 ? "-" : dof > 0 ? format("%.3g", chi_square_p_value(s, dof)) : "?";
    std::snprintf(line, sizeof line, "    %-28s %12.4g %10.4g %9s  %s%s\n", what.substr(0, 28).c_str(),
                  s, limit, p.c_str(), verdict(limit == 0.0 || s <= limit),
                  limit == 0.0 ? " (constant input)" : "");
    out += line;
  }
  if (std::isfinite(d.nis_mean())) {
    std::snprintf(line, sizeof line, "    %-28s %12.4g %10s %9s  %s (band [%.4g, %.4g])\n", "mean NIS in its band",
                  d.nis_mean(), "", "", verdict(d.nis_consistent()), d.nis_lower(), d.nis_upper());
    out += line;
  }
  return out;
}

std::string estimation_table(const v1::EstimationResult& r, const std::vector<double>& initial,
                             const std::vector<double>& truth, const ModelNames& names) {
  const int n = r.param_names_size();
  const bool with_truth = static_cast<int>(truth.size()) == n;
  const bool with_initial = static_cast<int>(initial.size()) == n;
  std::string out;
  char line[512];
  const std::string method = method_name(r.method());
  std::snprintf(line, sizeof line, "method %s: %s after %s (%s); cost %.6g\n", method.c_str(),
                r.converged() ? "converged" : "NOT converged", counted(r.iterations(), "iteration").c_str(),
                r.termination().c_str(), r.cost());
  out += line;
  std::snprintf(line, sizeof line, "%s, %u of the Jacobian; gradient: %s%s\n",
                counted(r.evaluations(), "evaluation").c_str(), r.jacobian_evaluations(), r.gradient().c_str(),
                r.sigma2() != 1.0 ? ("; residual variance " + format("%.4g", r.sigma2()) + " (scales the covariance)").c_str()
                                  : "");
  out += line;
  if (r.has_init_passes() && r.init_passes().passes_size() > 0) {
    out += "start: the mean over the last of " +
           counted(static_cast<unsigned>(r.init_passes().passes_size()), "pass", "passes") + " of the iterated filter " + values_list(r.init_passes().theta_mean()) + "\n";
  }
  out += "\n";
  std::snprintf(line, sizeof line, "%-10s %10s %14s %11s %29s %9s", "parameter", "initial", "estimate", "std. error",
                "95 % interval", "rel. std");
  out += line;
  if (with_truth) {
    std::snprintf(line, sizeof line, " %12s %9s", "true", "error %");
    out += line;
  }
  out += "\n";
  for (int i = 0; i < n; ++i) {
    const bool fixed = i < r.fixed_size() && r.fixed(i);
    const double theta = r.theta(i);
    const double std = i < r.theta_std_size() ? r.theta_std(i) : 0.0;
    std::string std_text, interval, relative;
    if (fixed) {
      std_text = "fixed";
      interval = "-";
      relative = "-";
    } else {
      std_text = format("%.4g", std);
      interval = "[" + format("%.8g", r.ci_lower(i)) + ", " + format("%.8g", r.ci_upper(i)) + "]";
      relative = theta != 0.0 ? format("%.3g %%", 100.0 * std / std::abs(theta)) : "-";
    }
    std::snprintf(line, sizeof line, "%-10s %10s %14.9g %11s %29s %9s", r.param_names(i).c_str(),
                  with_initial ? format("%.6g", initial[static_cast<std::size_t>(i)]).c_str() : "-", theta,
                  std_text.c_str(), interval.c_str(), relative.c_str());
    out += line;
    if (with_truth) {
      const double t = truth[static_cast<std::size_t>(i)];
      std::snprintf(line, sizeof line, " %12.6g %9.3g", t, t != 0.0 ? 100.0 * (theta - t) / t : theta - t);
      out += line;
      if (!fixed && std::isfinite(std)) out += (t >= r.ci_lower(i) && t <= r.ci_upper(i)) ? "" : "  (outside the interval)";
    }
    out += "\n";
  }
  const std::string correlations = correlation_table(r);
  if (!correlations.empty()) out += "\n" + correlations;
  if (r.warnings_size() > 0) {
    out += "\nwarnings:\n";
    for (const auto& w : r.warnings()) out += "  " + w + "\n";
  }
  const std::string q = noise_line("process noise Q (states' diagonal):", r.process_noise(), r.process_noise_std(),
                                   names.states, "x");
  const std::string rr = noise_line("measurement noise R (diagonal):", r.measurement_noise(),
                                    r.measurement_noise_std(), names.outputs, "y");
  if (!q.empty() || !rr.empty()) out += "\n" + q + rr;

  for (int e = 0; e < r.experiments_size(); ++e) {
    const v1::ExperimentFit& x = r.experiments(e);
    out += "\nexperiment " + std::to_string(e + 1) + " (" + x.dataset_id() + "): " +
           counted(static_cast<unsigned>(x.t_size()), "sample") + "\n";
    std::string x0 = "  x0:";
    for (int i = 0; i < x.x0_size(); ++i) {
      const bool estimated = i < x.x0_estimated_size() && x.x0_estimated(i);
      x0 += (i > 0 ? ", " : " ") + name_or_number(names.states, i, "x") + " = " + format("%.6g", x.x0(i)) +
            (estimated ? " (std " + format("%.2g", i < x.x0_std_size() ? x.x0_std(i) : 0.0) + ")" : " (given)");
    }
    out += x0 + "\n";
    out += fit_table(x.fits(), "  ");
    if (x.has_diagnostics()) {
      ModelNames with_outputs = names;
      with_outputs.outputs = output_names(x, names);
      out += diagnostics_table(x.diagnostics(), with_outputs);
    }
  }
  return out;
}

std::string estimation_csv(const v1::EstimationResult& r, const ModelNames& names) {
  std::ostringstream csv;
  csv.precision(17);
  const std::vector<std::string> outputs =
      r.experiments_size() > 0 ? output_names(r.experiments(0), names) : names.outputs;
  csv << "experiment,t";
  for (const char* prefix : {"", "model_", "residual_", "used_"}) {
    for (const auto& y : outputs) csv << "," << prefix << y;
  }
  csv << "\n";
  for (int e = 0; e < r.experiments_size(); ++e) {
    const v1::ExperimentFit& x = r.experiments(e);
    const uint32_t ny = x.y_measured().rows();
    for (int k = 0; k < x.t_size(); ++k) {
      const auto col = static_cast<uint32_t>(k);
      csv << e + 1 << "," << x.t(k);
      for (const v1::Matrix* m : {&x.y_measured(), &x.y_model(), &x.residuals(), &x.mask()}) {
        for (uint32_t i = 0; i < ny; ++i) csv << "," << (m->rows() == ny && col < m->cols() ? element(*m, i, col) : 1.0);
      }
      csv << "\n";
    }
  }
  return csv.str();
}

std::string smoothing_table(const v1::SmoothingResult& r) {
  std::string out;
  char line[256];
  const int N = r.t_size();
  if (N == 0) return "no samples smoothed\n";
  std::snprintf(line, sizeof line, "smoothed over %s, t = %.6g to %.6g\n",
                counted(static_cast<unsigned>(N), "sample").c_str(), r.t(0), r.t(N - 1));
  out += line;
  std::snprintf(line, sizeof line, "%-10s %14s %11s %14s %11s %15s %15s\n", "", "start", "std", "end", "std",
                "mean std filt.", "mean std smooth.");
  out += line;
  const auto last = static_cast<uint32_t>(N - 1);
  for (int i = 0; i < r.names_size(); ++i) {
    const auto row = static_cast<uint32_t>(i);
    double filtered = 0.0, smoothed = 0.0;
    for (uint32_t k = 0; k <= last; ++k) {
      filtered += element(r.std_filtered(), row, k);
      smoothed += element(r.std_smoothed(), row, k);
    }
    std::snprintf(line, sizeof line, "%-10s %14.8g %11.4g %14.8g %11.4g %15.4g %15.4g\n", r.names(i).c_str(),
                  element(r.z_smoothed(), row, 0), element(r.std_smoothed(), row, 0),
                  element(r.z_smoothed(), row, last), element(r.std_smoothed(), row, last), filtered / N,
                  smoothed / N);
    out += line;
  }
  return out;
}

std::string smoothing_csv(const v1::SmoothingResult& r, const ModelNames& names) {
  std::ostringstream csv;
  csv.precision(17);
  const uint32_t ny = r.y_model().rows();
  std::vector<std::string> outputs;
  for (uint32_t i = 0; i < ny; ++i) outputs.push_back(name_or_number(names.outputs, static_cast<int>(i), "y"));
  csv << "t";
  for (const char* prefix : {"", "std_", "filtered_", "std_filtered_"}) {
    for (const auto& n : r.names()) csv << "," << prefix << n;
  }
  for (const char* prefix : {"model_", "innovation_"}) {
    for (const auto& y : outputs) csv << "," << prefix << y;
  }
  csv << "\n";
  for (int k = 0; k < r.t_size(); ++k) {
    const auto col = static_cast<uint32_t>(k);
    csv << r.t(k);
    for (const v1::Matrix* m : {&r.z_smoothed(), &r.std_smoothed(), &r.z_filtered(), &r.std_filtered()}) {
      for (uint32_t i = 0; i < m->rows(); ++i) csv << "," << element(*m, i, col);
    }
    for (const v1::Matrix* m : {&r.y_model(), &r.innovations()}) {
      for (uint32_t i = 0; i < m->rows(); ++i) csv << "," << element(*m, i, col);
    }
    csv << "\n";
  }
  return csv.str();
}

}  // namespace riccati::cli
