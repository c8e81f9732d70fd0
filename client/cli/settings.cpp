#include "settings.hpp"

#include <yaml-cpp/yaml.h>

#include <charconv>
#include <cstdio>
#include <sstream>

namespace riccati::cli {

namespace {

bool parse_number(const std::string& text, double* out) {
  const char* begin = text.data();
  const char* end = begin + text.size();
  while (begin < end && *begin == ' ') ++begin;
  while (end > begin && end[-1] == ' ') --end;
  if (begin < end && *begin == '+') ++begin;
  auto [ptr, ec] = std::from_chars(begin, end, *out);
  return ec == std::errc() && ptr == end && begin != end;
}

template <typename T>
bool read_scalar(const YAML::Node& node, const std::string& key, std::optional<T>* out, std::string* error) {
  try {
    *out = node.as<T>();
    return true;
  } catch (const YAML::Exception&) {
    *error = "key \"" + key + "\" (line " + std::to_string(node.Mark().line + 1) + "): expected a " +
             (std::is_same_v<T, std::string> ? "string" : (std::is_same_v<T, bool> ? "true or false" : "number"));
    return false;
  }
}

bool read_numbers(const YAML::Node& node, const std::string& key, std::vector<double>* out, std::string* error) {
  out->clear();
  try {
    if (node.IsScalar()) {
      out->push_back(node.as<double>());
      return true;
    }
    if (node.IsSequence()) {
      for (const auto& v : node) out->push_back(v.as<double>());
      return true;
    }
  } catch (const YAML::Exception&) {
  }
  *error = "key \"" + key + "\" (line " + std::to_string(node.Mark().line + 1) + "): expected a number or a list of numbers";
  return false;
}

bool read_matrix(const YAML::Node& node, const std::string& key, std::optional<MatrixSetting>* out,
                 std::string* error) {
  MatrixSetting m;
  if (node.IsSequence() && node.size() > 0 && node[0].IsSequence()) {
    m.full = true;
    for (const auto& row : node) {
      std::vector<double> values;
      if (!read_numbers(row, key, &values, error)) return false;
      m.rows.push_back(std::move(values));
    }
  } else {
    std::vector<double> values;
    if (!read_numbers(node, key, &values, error)) return false;
    m.rows.push_back(std::move(values));
  }
  *out = std::move(m);
  return true;
}

bool read_names(const YAML::Node& node, const std::string& key, std::vector<std::string>* out, std::string* error) {
  out->clear();
  try {
    if (node.IsScalar()) {
      out->push_back(node.as<std::string>());
      return true;
    }
    for (const auto& v : node) out->push_back(v.as<std::string>());
    return true;
  } catch (const YAML::Exception&) {
    *error = "key \"" + key + "\": expected a list of names";
    return false;
  }
}

std::string join(const google::protobuf::RepeatedPtrField<std::string>& names) {
  std::string out;
  for (const auto& n : names) out += (out.empty() ? "" : ", ") + n;
  return out;
}

// n x n from the setting: one value on the whole diagonal, a diagonal, or full.
bool to_covariance(const MatrixSetting& m, int n, const std::string& what, v1::Covariance* out, std::string* error) {
  if (m.full) {
    v1::Matrix* full = out->mutable_full();
    full->set_rows(n);
    full->set_cols(n);
    if (static_cast<int>(m.rows.size()) != n) {
      *error = what + ": a full matrix needs " + std::to_string(n) + " rows, got " + std::to_string(m.rows.size());
      return false;
    }
    full->mutable_values()->Resize(n * n, 0.0);
    for (int i = 0; i < n; ++i) {
      if (static_cast<int>(m.rows[i].size()) != n) {
        *error = what + ": row " + std::to_string(i + 1) + " needs " + std::to_string(n) + " values";
        return false;
      }
      for (int j = 0; j < n; ++j) full->set_values(i + j * n, m.rows[i][j]);
    }
    return true;
  }
  const std::vector<double>& d = m.rows.empty() ? std::vector<double>{} : m.rows[0];
  if (d.size() == 1) {
    for (int i = 0; i < n; ++i) out->mutable_diagonal()->add_values(d[0]);
    return true;
  }
  if (static_cast<int>(d.size()) != n) {
    *error = what + " needs " + std::to_string(n) + " values (or one for all), got " + std::to_string(d.size());
    return false;
  }
  for (double v : d) out->mutable_diagonal()->add_values(v);
  return true;
}

}  // namespace

bool parse_list(const std::string& text, std::vector<double>* out, std::string* error) {
  out->clear();
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    double v = 0.0;
    if (!parse_number(item, &v)) {
      *error = "\"" + item + "\" is not a number";
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

MatrixSetting matrix_from_list(const std::vector<double>& values) { return MatrixSetting{{values}, false}; }

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
    const std::string key = entry.first.as<std::string>();
    const YAML::Node& v = entry.second;
    bool ok = true;
    if (key == "model") {
      ok = read_scalar(v, key, &s->model, error);
    } else if (key == "data") {
      ok = read_scalar(v, key, &s->data, error);
    } else if (key == "inputs") {
      ok = read_names(v, key, &s->inputs, error);
    } else if (key == "outputs") {
      ok = read_names(v, key, &s->outputs, error);
    } else if (key == "filter") {
      ok = read_scalar(v, key, &s->filter, error);
    } else if (key == "passes") {
      ok = read_scalar(v, key, &s->passes, error);
    } else if (key == "x0") {
      if (v.IsSequence()) {
        std::vector<double> values;
        ok = read_numbers(v, key, &values, error);
        // Kept as the flag's text, at full precision.
        std::string joined;
        for (double x : values) {
          char buf[32];
          std::snprintf(buf, sizeof buf, "%.17g", x);
          joined += (joined.empty() ? "" : ",") + std::string(buf);
        }
        s->x0 = joined;
      } else {
        ok = read_scalar(v, key, &s->x0, error);
      }
    } else if (key == "theta0" || key == "truth") {
      std::vector<double> values;
      ok = read_numbers(v, key, &values, error);
      (key == "theta0" ? s->theta0 : s->truth) = values;
    } else if (key == "P0" || key == "p0") {
      ok = read_matrix(v, key, &s->p0, error);
    } else if (key == "Q" || key == "q") {
      ok = read_matrix(v, key, &s->q, error);
    } else if (key == "R" || key == "r") {
      ok = read_matrix(v, key, &s->r, error);
    } else if (key == "hold") {
      ok = read_scalar(v, key, &s->hold, error);
    } else if (key == "integrator") {
      if (v.IsScalar()) {
        ok = read_scalar(v, key, &s->integrator, error);
      } else {
        for (const auto& sub : v) {
          const std::string k = sub.first.as<std::string>();
          if (k == "kind") {
            ok = read_scalar(sub.second, "integrator.kind", &s->integrator, error);
          } else if (k == "substeps") {
            ok = read_scalar(sub.second, "integrator.substeps", &s->substeps, error);
          } else if (k == "rtol") {
            ok = read_scalar(sub.second, "integrator.rtol", &s->rtol, error);
          } else if (k == "atol") {
            ok = read_scalar(sub.second, "integrator.atol", &s->atol, error);
          } else {
            *error = "unknown key \"integrator." + k + "\" (expected kind, substeps, rtol, atol)";
            ok = false;
          }
          if (!ok) break;
        }
      }
    } else if (key == "inversion") {
      ok = read_scalar(v, key, &s->inversion, error);
    } else if (key == "joseph") {
      ok = read_scalar(v, key, &s->joseph, error);
    } else if (key == "ukf") {
      for (const auto& sub : v) {
        const std::string k = sub.first.as<std::string>();
        if (k == "weights") {
          ok = read_scalar(sub.second, "ukf.weights", &s->weights, error);
        } else if (k == "alpha") {
          ok = read_scalar(sub.second, "ukf.alpha", &s->alpha, error);
        } else if (k == "beta") {
          ok = read_scalar(sub.second, "ukf.beta", &s->beta, error);
        } else if (k == "kappa") {
          ok = read_scalar(sub.second, "ukf.kappa", &s->kappa, error);
        } else {
          *error = "unknown key \"ukf." + k + "\" (expected weights, alpha, beta, kappa)";
          ok = false;
        }
        if (!ok) break;
      }
    } else if (key == "optimal") {
      if (!v.IsMap()) {
        *error = "key \"optimal\": expected a map (V, W, R0, form, hold_outputs)";
        ok = false;
      }
      for (const auto& sub : v) {
        if (!ok) break;
        const std::string k = sub.first.as<std::string>();
        if (k == "V" || k == "v") {
          ok = read_matrix(sub.second, "optimal.V", &s->v, error);
        } else if (k == "W" || k == "w") {
          ok = read_matrix(sub.second, "optimal.W", &s->w, error);
        } else if (k == "R0" || k == "r0") {
          ok = read_matrix(sub.second, "optimal.R0", &s->r0, error);
        } else if (k == "form") {
          ok = read_scalar(sub.second, "optimal.form", &s->form, error);
        } else if (k == "hold_outputs") {
          ok = read_scalar(sub.second, "optimal.hold_outputs", &s->hold_outputs, error);
        } else {
          *error = "unknown key \"optimal." + k + "\" (expected V, W, R0, form, hold_outputs)";
          ok = false;
        }
      }
    } else if (key == "first_sample") {
      ok = read_scalar(v, key, &s->first_sample, error);
    } else if (key == "end_sample") {
      ok = read_scalar(v, key, &s->end_sample, error);
    } else {
      *error = "unknown key \"" + key + "\" (line " + std::to_string(entry.first.Mark().line + 1) + ")";
      ok = false;
    }
    if (!ok) {
      *error = path + ": " + *error;
      return false;
    }
  }
  return true;
}

void overlay(const RunSettings& f, RunSettings* b) {
  auto take = [](const auto& from, auto& to) {
    if (from) to = from;
  };
  take(f.model, b->model);
  take(f.data, b->data);
  take(f.filter, b->filter);
  take(f.hold, b->hold);
  take(f.integrator, b->integrator);
  take(f.inversion, b->inversion);
  take(f.weights, b->weights);
  if (!f.inputs.empty()) b->inputs = f.inputs;
  if (!f.outputs.empty()) b->outputs = f.outputs;
  take(f.x0, b->x0);
  take(f.theta0, b->theta0);
  take(f.truth, b->truth);
  take(f.p0, b->p0);
  take(f.q, b->q);
  take(f.r, b->r);
  take(f.v, b->v);
  take(f.w, b->w);
  take(f.r0, b->r0);
  take(f.form, b->form);
  take(f.hold_outputs, b->hold_outputs);
  take(f.passes, b->passes);
  take(f.substeps, b->substeps);
  take(f.rtol, b->rtol);
  take(f.atol, b->atol);
  take(f.alpha, b->alpha);
  take(f.beta, b->beta);
  take(f.kappa, b->kappa);
  take(f.joseph, b->joseph);
  take(f.first_sample, b->first_sample);
  take(f.end_sample, b->end_sample);
}

bool to_integrator(const RunSettings& s, v1::IntegratorSettings* out, std::string* error) {
  const std::string kind = s.integrator.value_or("rk4");
  if (kind == "rk4") {
    out->set_kind(v1::INTEGRATOR_KIND_RK4);
  } else if (kind == "rk3") {
    out->set_kind(v1::INTEGRATOR_KIND_RK3);
  } else if (kind == "cvode-bdf") {
    out->set_kind(v1::INTEGRATOR_KIND_CVODE_BDF);
  } else if (kind == "cvode-adams") {
    out->set_kind(v1::INTEGRATOR_KIND_CVODE_ADAMS);
  } else if (kind == "arkode-erk") {
    out->set_kind(v1::INTEGRATOR_KIND_ARKODE_ERK);
  } else {
    *error = "integrator \"" + kind + "\" is unknown (rk4, rk3, cvode-bdf, cvode-adams, arkode-erk)";
    return false;
  }
  if (s.substeps) {
    if (*s.substeps < 1) {
      *error = "substeps must be at least 1";
      return false;
    }
    out->set_substeps(static_cast<uint32_t>(*s.substeps));
  }
  if (s.rtol) out->set_rtol(*s.rtol);
  if (s.atol) out->set_atol(*s.atol);
  return true;
}

bool to_hold(const std::optional<std::string>& hold, v1::HoldOrder* out, std::string* error) {
  const std::string h = hold.value_or("zoh");
  if (h == "zoh") {
    *out = v1::HOLD_ORDER_ZERO;
  } else if (h == "foh") {
    *out = v1::HOLD_ORDER_FIRST;
  } else {
    *error = "hold \"" + h + "\" is unknown (zoh or foh)";
    return false;
  }
  return true;
}

namespace {

// The optimal filter's weights V, W and R0, its form and output hold.
bool to_optimal_settings(const RunSettings& s, const v1::ModelInfo& info, v1::OptimalSettings* out,
                         std::string* error) {
  const int nz = info.state_names_size() + info.param_names_size();
  if (info.ndof() == 0) {
    *error = "model " + info.name() + " has no mechanical form (M a + h = H u): the optimal filter needs one";
    return false;
  }
  if (s.q || s.r) {
    *error = "the optimal filter takes no Q and R: give its weights V and W";
    return false;
  }
  const int L = static_cast<int>(info.ndof()) + info.input_names_size() + info.output_names_size();
  const std::string rows = std::to_string(info.ndof()) + " equations of motion, then inputs " +
                           join(info.input_names()) + ", then outputs " + join(info.output_names());
  if (!s.v || !s.w) {
    *error = "the optimal filter needs its weights V (" + std::to_string(L) + ": " + rows + ") and W (" +
             std::to_string(nz) + ": states and parameters)";
    return false;
  }
  if (!to_covariance(*s.v, L, "V (" + rows + ")", out->mutable_v(), error)) return false;
  if (!to_covariance(*s.w, nz, "W (" + std::to_string(nz) + " = states + parameters)", out->mutable_w(), error)) {
    return false;
  }
  if (s.r0 && !to_covariance(*s.r0, nz, "R0 (" + std::to_string(nz) + " = states + parameters)",
                             out->mutable_r0(), error)) {
    return false;
  }
  const std::string form = s.form.value_or("continuous");
  if (form == "continuous") {
    out->set_form(v1::OPTIMAL_FORM_CONTINUOUS);
  } else if (form == "split-step") {
    out->set_form(v1::OPTIMAL_FORM_SPLIT_STEP);
  } else {
    *error = "form \"" + form + "\" is unknown (continuous or split-step)";
    return false;
  }
  out->set_hold_outputs(s.hold_outputs.value_or(false));
  return true;
}

}  // namespace

bool to_filter_settings(const RunSettings& s, const v1::ModelInfo& info, v1::FilterSettings* out,
                        std::string* error) {
  const int nz = info.state_names_size() + info.param_names_size();
  const int ny = info.output_names_size();
  const std::string filter = s.filter.value_or("ekf");
  if (filter == "ekf") {
    out->set_kind(v1::FILTER_KIND_EKF);
  } else if (filter == "ukf") {
    out->set_kind(v1::FILTER_KIND_UKF);
  } else if (filter == "optimal") {
    out->set_kind(v1::FILTER_KIND_OPTIMAL);
  } else {
    *error = "filter \"" + filter + "\" is unknown (ekf, ukf or optimal)";
    return false;
  }
  v1::HoldOrder hold;
  if (!to_hold(s.hold, &hold, error)) return false;
  out->set_hold(hold);
  if (!to_integrator(s, out->mutable_integrator(), error)) return false;
  if (filter == "optimal") return to_optimal_settings(s, info, out->mutable_optimal(), error);
  if (s.v || s.w || s.r0 || s.form || s.hold_outputs) {
    *error = "V, W, R0, form and hold_outputs are settings of the optimal filter (filter: optimal)";
    return false;
  }
  if (s.q && !to_covariance(*s.q, nz, "Q (" + std::to_string(nz) + " = states + parameters)", out->mutable_q(), error)) {
    return false;
  }
  if (!s.r) {
    *error = "R (measurement noise variances of " + join(info.output_names()) + ") is required";
    return false;
  }
  if (!to_covariance(*s.r, ny, "R (outputs " + join(info.output_names()) + ")", out->mutable_r(), error)) return false;
  const std::string inversion = s.inversion.value_or("cholesky");
  if (inversion == "cholesky") {
    out->set_inversion(v1::GAIN_INVERSION_CHOLESKY);
  } else if (inversion == "pinv") {
    out->set_inversion(v1::GAIN_INVERSION_PSEUDO_INVERSE);
  } else {
    *error = "inversion \"" + inversion + "\" is unknown (cholesky or pinv)";
    return false;
  }
  out->set_short_covariance_update(!s.joseph.value_or(true));
  const std::string weights = s.weights.value_or("julier");
  if (weights == "julier") {
    out->mutable_ukf()->set_weights(v1::SIGMA_WEIGHTS_JULIER);
  } else if (weights == "scaled") {
    out->mutable_ukf()->set_weights(v1::SIGMA_WEIGHTS_SCALED);
  } else {
    *error = "UKF weights \"" + weights + "\" are unknown (julier or scaled)";
    return false;
  }
  if (s.alpha) out->mutable_ukf()->set_alpha(*s.alpha);
  if (s.beta) out->mutable_ukf()->set_beta(*s.beta);
  if (s.kappa) out->mutable_ukf()->set_kappa(*s.kappa);
  return true;
}

bool to_initial_state(const std::string& x0, v1::InitialState* out, std::string* error) {
  if (x0 == "first") {
    out->set_first_measurement(true);
    return true;
  }
  std::vector<double> values;
  if (!parse_list(x0, &values, error)) {
    *error = "x0: " + *error + " (give \"first\" or a list of numbers)";
    return false;
  }
  for (double v : values) out->add_x0(v);
  return true;
}

namespace {

// What a job and a session share: filter, initial state, theta0 and P0.
template <typename Request>
bool fill_run(const RunSettings& s, const v1::ModelInfo& info, Request* out, std::string* error) {
  out->set_model(info.name());
  if (!to_filter_settings(s, info, out->mutable_filter(), error)) return false;
  if (!to_initial_state(s.x0.value_or("first"), out->mutable_initial_state(), error)) return false;
  if (s.theta0) {
    for (double v : *s.theta0) out->add_theta0(v);
  }
  const int nz = info.state_names_size() + info.param_names_size();
  if (s.r0) {
    if (s.p0) {
      *error = "give P0 or R0 (its inverse, for the optimal filter), not both";
      return false;
    }
    return true;  // the optimal filter's R0 is in its settings
  }
  if (!s.p0) {
    *error = "P0 (initial variances of the " + std::to_string(nz) + " states and parameters) is required";
    return false;
  }
  return to_covariance(*s.p0, nz, "P0", out->mutable_p0(), error);
}

}  // namespace

bool to_identification_spec(const RunSettings& s, const v1::ModelInfo& info, const std::string& dataset_id,
                            v1::IdentificationSpec* out, std::string* error) {
  if (!fill_run(s, info, out, error)) return false;
  out->set_dataset_id(dataset_id);
  out->set_passes(static_cast<uint32_t>(s.passes.value_or(1)));
  if (s.first_sample) out->set_first_sample(static_cast<uint64_t>(*s.first_sample));
  if (s.end_sample) out->set_end_sample(static_cast<uint64_t>(*s.end_sample));
  return true;
}

bool to_session_request(const RunSettings& s, const v1::ModelInfo& info, v1::CreateSessionRequest* out,
                        std::string* error) {
  return fill_run(s, info, out, error);
}

}  // namespace riccati::cli
