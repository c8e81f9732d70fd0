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

std::string method_name(v1::IdentificationMethod method) {
  const auto* value = v1::IdentificationMethod_descriptor()->FindValueByNumber(method);
  return value != nullptr ? api::enum_value_name(*value) : "?";
}

std::string column(const std::string& quantity, const std::string& name) {
  return quantity.empty() ? name : quantity + "." + name;
}

std::vector<std::string> sized_names(const std::vector<std::string>& names, std::size_t count, const char* prefix) {
  if (names.size() == count) return names;
  std::vector<std::string> numbered;
  for (std::size_t i = 0; i < count; ++i) numbered.push_back(name_or_number({}, static_cast<int>(i), prefix));
  return numbered;
}

ModelNames model_names(const v1::ModelInfo& model) {
  ModelNames names;
  names.states.assign(model.state_names().begin(), model.state_names().end());
  names.inputs.assign(model.input_names().begin(), model.input_names().end());
  names.outputs.assign(model.output_names().begin(), model.output_names().end());
  return names;
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
  // A table per test; p-values and degrees of freedom are riccatid's (the
  // engine's diagnostics), printed as they come.
  const auto p_text = [](double p) { return std::isnan(p) ? std::string("-") : format("%.3g", p); };
  const auto padded = [](const std::string& s, std::size_t width) {
    return s.size() >= width ? s : s + std::string(width - s.size(), ' ');
  };
  const int ny = d.ljung_box_size();
  const int pairs = d.cross_statistic_size();
  const int nu = ny > 0 ? pairs / ny : 0;
  std::size_t out_w = 6, in_w = 5;  // "output", "input"
  for (int i = 0; i < ny; ++i) out_w = std::max(out_w, name_or_number(names.outputs, i, "y").size());
  for (int j = 0; j < nu; ++j) in_w = std::max(in_w, name_or_number(names.inputs, j, "u").size());

  std::string out = "  residual diagnostics (each at 95 %; " + counted(d.samples(), "sample") + ", lags 1.." +
                    std::to_string(d.lags()) + ", band +-" + format("%.3g", d.band()) + ")\n";
  out += "    whiteness: Ljung-Box Q over lags 1.." + std::to_string(d.lags()) + "\n";
  char head[128];
  std::snprintf(head, sizeof head, " %12s %10s %9s %5s  %s\n", "Q", "limit", "p-value", "dof", "verdict");
  out += "      " + padded("output", out_w) + head;
  for (int i = 0; i < ny; ++i) {
    const double q = d.ljung_box(i);
    const double p = i < d.ljung_box_p_size() ? d.ljung_box_p(i) : std::nan("");
    char line[128];
    // (a result stored before riccatid sent p-values and dof has neither: "-")
    std::snprintf(line, sizeof line, " %12.4g %10.4g %9s %5s  %s\n", q, d.ljung_box_limit(), p_text(p).c_str(),
                  d.ljung_box_dof() > 0 ? std::to_string(d.ljung_box_dof()).c_str() : "-",
                  verdict(q <= d.ljung_box_limit()));
    out += "      " + padded(name_or_number(names.outputs, i, "y"), out_w) + line;
  }
  if (nu > 0) {
    out += "    independence from inputs: N R^2 of the residual on the input at lags 0.." + std::to_string(d.lags()) +
           "\n";
    std::snprintf(head, sizeof head, " %12s %10s %9s %5s  %s\n", "S", "limit", "p-value", "dof", "verdict");
    out += "      " + padded("output", out_w) + " " + padded("input", in_w) + head;
    for (int pair = 0; pair < pairs; ++pair) {
      const double s = d.cross_statistic(pair);
      const double limit = pair < d.cross_limit_size() ? d.cross_limit(pair) : 0.0;
      const bool tested = limit > 0.0;  // a constant input has no limit (and 0 degrees of freedom)
      char line[160];
      std::snprintf(line, sizeof line, " %12.4g %10.4g %9s %5s  %s%s\n", s, limit,
                    tested && pair < d.cross_p_size() ? p_text(d.cross_p(pair)).c_str() : "-",
                    pair < d.cross_dof_size() ? std::to_string(d.cross_dof(pair)).c_str() : "-",
                    verdict(!tested || s <= limit), tested ? "" : " (constant input: not tested)");
      out += "      " + padded(name_or_number(names.outputs, pair / nu, "y"), out_w) + " " +
             padded(name_or_number(names.inputs, pair % nu, "u"), in_w) + line;
    }
  }
  if (std::isfinite(d.nis_mean())) {
    out += "    noise consistency: mean NIS in its band (two-sided)\n";
    std::snprintf(head, sizeof head, "      %12s %22s %9s %11s  %s\n", "mean NIS", "band", "p-value", "dof", "verdict");
    out += head;
    char line[200];
    std::snprintf(line, sizeof line, "      %12.4g %22s %9s %11s  %s\n", d.nis_mean(),
                  ("[" + format("%.4g", d.nis_lower()) + ", " + format("%.4g", d.nis_upper()) + "]").c_str(),
                  d.nis_dof() > 0 ? p_text(d.nis_p()).c_str() : "-",
                  d.nis_dof() > 0 ? std::to_string(d.nis_dof()).c_str() : "-", verdict(d.nis_consistent()));
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
  if (r.samples() > 0) {  // (results stored before the criteria have none)
    std::snprintf(line, sizeof line, "log-likelihood %.10g; AIC %.10g, AICc %.10g, BIC %.10g (k = %u estimated, n = %llu)\n",
                  r.log_likelihood(), r.aic(), r.aicc(), r.bic(), r.estimated_quantities(),
                  static_cast<unsigned long long>(r.samples()));
    out += line;
  }
  if (!r.covariance_method().empty()) out += "covariance: " + r.covariance_method() + "\n";
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
    // ML's model output is the predictor's one step ahead, OE's the simulation.
    out += r.method() == v1::IDENTIFICATION_METHOD_ML ? "  fit of the one-step-ahead predictions:\n"
                                                       : "  fit of the simulation:\n";
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
  for (const char* quantity : {"y", "y_model", "residual", "residual_normalised", "used"}) {
    for (const auto& y : outputs) csv << "," << column(quantity, y);
  }
  csv << "\n";
  for (int e = 0; e < r.experiments_size(); ++e) {
    const v1::ExperimentFit& x = r.experiments(e);
    const uint32_t ny = x.y_measured().rows();
    // A matrix's value, or `otherwise` when the result has none (no mask: every sample used).
    const auto at = [&](const v1::Matrix& m, uint32_t i, uint32_t col, double otherwise) {
      return m.rows() == ny && col < m.cols() ? element(m, i, col) : otherwise;
    };
    for (int k = 0; k < x.t_size(); ++k) {
      const auto col = static_cast<uint32_t>(k);
      csv << e + 1 << "," << x.t(k);
      for (uint32_t i = 0; i < ny; ++i) csv << "," << at(x.y_measured(), i, col, 0.0);
      for (uint32_t i = 0; i < ny; ++i) csv << "," << at(x.y_model(), i, col, 0.0);
      for (uint32_t i = 0; i < ny; ++i) csv << "," << at(x.y_measured(), i, col, 0.0) - at(x.y_model(), i, col, 0.0);
      for (uint32_t i = 0; i < ny; ++i) csv << "," << at(x.residuals(), i, col, 0.0);
      for (uint32_t i = 0; i < ny; ++i) csv << "," << at(x.mask(), i, col, 1.0);
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
  const std::vector<std::string> outputs = sized_names(names.outputs, ny, "y");
  csv << "t";
  for (const char* quantity : {"", "std", "filtered", "filtered_std"}) {
    for (const auto& n : r.names()) csv << "," << column(quantity, n);
  }
  for (const char* quantity : {"y_model", "innovation"}) {
    for (const auto& y : outputs) csv << "," << column(quantity, y);
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
