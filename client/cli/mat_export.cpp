#include "mat_export.hpp"

#include <matio.h>

#include <memory>
#include <vector>

#include "output.hpp"
#include "riccati/enum_names.hpp"

namespace riccati::cli {

namespace {

struct MatCloser {
  void operator()(mat_t* mat) const { Mat_Close(mat); }
};

class MatWriter {
 public:
  explicit MatWriter(const std::string& path)
      : path_(path), mat_(Mat_CreateVer(path.c_str(), nullptr, MAT_FT_MAT5)) {}

  bool open() const { return mat_ != nullptr; }
  bool ok() const { return ok_; }

  // A rows x cols double matrix from column-major `values`.
  void matrix(const char* name, std::size_t rows, std::size_t cols, const double* values) {
    std::size_t dims[2] = {rows, cols};
    // matio does not write through the pointer (MAT_F_DONT_COPY_DATA), but takes it non-const.
    matvar_t* var = Mat_VarCreate(name, MAT_C_DOUBLE, MAT_T_DOUBLE, 2, dims, const_cast<double*>(values),
                                  MAT_F_DONT_COPY_DATA);
    write(var);
  }

  void matrix(const char* name, const v1::Matrix& m) { matrix(name, m.rows(), m.cols(), m.values().data()); }
  void matrix(const char* name, std::size_t rows, std::size_t cols, const std::vector<double>& values) {
    matrix(name, rows, cols, values.data());
  }

  void column(const char* name, const google::protobuf::RepeatedField<double>& v) {
    matrix(name, static_cast<std::size_t>(v.size()), 1, v.data());
  }

  void row(const char* name, const google::protobuf::RepeatedField<double>& v) {
    matrix(name, 1, static_cast<std::size_t>(v.size()), v.data());
  }

  void scalar(const char* name, double v) { matrix(name, 1, 1, &v); }

  // A char row 'text'.
  void text(const char* name, const std::string& value) {
    std::size_t dims[2] = {1, value.size()};
    write(Mat_VarCreate(name, MAT_C_CHAR, MAT_T_UINT8, 2, dims, const_cast<char*>(value.data()), 0));  // copied
  }

  // A cell array {'a'; 'b'} of char rows.
  void names(const char* name, const std::vector<std::string>& texts) {
    std::size_t dims[2] = {texts.size(), 1};
    matvar_t* cell = Mat_VarCreate(name, MAT_C_CELL, MAT_T_CELL, 2, dims, nullptr, 0);
    for (std::size_t i = 0; i < texts.size(); ++i) {
      std::size_t text_dims[2] = {1, texts[i].size()};
      matvar_t* text = Mat_VarCreate(nullptr, MAT_C_CHAR, MAT_T_UINT8, 2, text_dims,
                                     const_cast<char*>(texts[i].data()), 0);  // copied
      Mat_VarSetCell(cell, static_cast<int>(i), text);
    }
    write(cell);
  }

 private:
  void write(matvar_t* var) {
    if (var == nullptr || Mat_VarWrite(mat_.get(), var, MAT_COMPRESSION_NONE) != 0) ok_ = false;
    if (var != nullptr) Mat_VarFree(var);
  }

  std::string path_;
  std::unique_ptr<mat_t, MatCloser> mat_;
  bool ok_ = true;
};

template <typename Names>
std::vector<std::string> strings(const Names& names) {
  return {names.begin(), names.end()};
}

void identification(MatWriter& mat, const v1::IdentificationResult& id, const ModelNames& names) {
  mat.row("T", id.t());
  mat.column("Theta", id.theta_mean());
  mat.column("ThetaFinal", id.theta());
  mat.column("ThetaStd", id.theta_std());
  if (id.ci_lower_size() > 0) {
    mat.column("ThetaLower", id.ci_lower());
    mat.column("ThetaUpper", id.ci_upper());
    mat.column("FilterThetaStd", id.filter_theta_std());
    mat.matrix("Covariance", id.theta_covariance());
  }
  if (id.passes_size() > 0) mat.matrix("Trace", id.passes(id.passes_size() - 1).theta_trace());
  mat.matrix("X", id.x_trace());
  mat.matrix("Ymod", id.y_model());
  mat.matrix("Innovations", id.innovations());
  mat.matrix("P", id.covariance());
  mat.names("ParamNames", strings(id.param_names()));
  mat.names("StateNames", sized_names(names.states, id.x_trace().rows(), "x"));
  mat.names("OutputNames", sized_names(names.outputs, id.y_model().rows(), "y"));
}

// The experiments' samples one after the other, as the CSV's rows.
void estimation(MatWriter& mat, const v1::EstimationResult& r, const ModelNames& names) {
  const auto method = v1::IdentificationMethod_descriptor()->FindValueByNumber(r.method());
  mat.text("Method", method != nullptr ? api::enum_value_name(*method) : "");
  mat.column("Theta", r.theta());
  mat.column("ThetaStd", r.theta_std());
  mat.column("ThetaLower", r.ci_lower());
  mat.column("ThetaUpper", r.ci_upper());
  std::vector<double> fixed(r.fixed().begin(), r.fixed().end());
  mat.matrix("Fixed", fixed.size(), 1, fixed);
  mat.matrix("Covariance", r.covariance());
  mat.matrix("Correlation", r.correlation());
  mat.scalar("Cost", r.cost());
  mat.scalar("Sigma2", r.sigma2());
  mat.column("CostHistory", r.cost_history());
  mat.names("ParamNames", strings(r.param_names()));
  const std::size_t ny = r.experiments_size() > 0 ? r.experiments(0).y_measured().rows() : names.outputs.size();
  const std::size_t nx = r.experiments_size() > 0 ? static_cast<std::size_t>(r.experiments(0).x0_size()) : 0;
  std::vector<double> x0, x0_std, experiment, t, y, y_model, residuals, normalised, used;
  for (int e = 0; e < r.experiments_size(); ++e) {
    const v1::ExperimentFit& x = r.experiments(e);
    for (std::size_t i = 0; i < nx; ++i) {
      x0.push_back(i < static_cast<std::size_t>(x.x0_size()) ? x.x0(static_cast<int>(i)) : 0.0);
      x0_std.push_back(i < static_cast<std::size_t>(x.x0_std_size()) ? x.x0_std(static_cast<int>(i)) : 0.0);
    }
    const auto at = [&](const v1::Matrix& m, std::size_t i, int k, double otherwise) {
      return m.rows() == ny && static_cast<uint32_t>(k) < m.cols()
                 ? element(m, static_cast<uint32_t>(i), static_cast<uint32_t>(k))
                 : otherwise;
    };
    for (int k = 0; k < x.t_size(); ++k) {
      experiment.push_back(e + 1);
      t.push_back(x.t(k));
      for (std::size_t i = 0; i < ny; ++i) {
        y.push_back(at(x.y_measured(), i, k, 0.0));
        y_model.push_back(at(x.y_model(), i, k, 0.0));
        residuals.push_back(y.back() - y_model.back());
        normalised.push_back(at(x.residuals(), i, k, 0.0));
        used.push_back(at(x.mask(), i, k, 1.0));
      }
    }
  }
  const std::size_t experiments = static_cast<std::size_t>(r.experiments_size());
  mat.matrix("X0", nx, experiments, x0);
  mat.matrix("X0Std", nx, experiments, x0_std);
  mat.matrix("Experiment", 1, experiment.size(), experiment);
  mat.matrix("T", 1, t.size(), t);
  mat.matrix("Y", ny, t.size(), y);
  mat.matrix("Ymod", ny, t.size(), y_model);
  mat.matrix("Residuals", ny, t.size(), residuals);
  mat.matrix("ResidualsNormalised", ny, t.size(), normalised);
  mat.matrix("Used", ny, t.size(), used);
  if (r.process_noise_size() > 0) {
    mat.column("ProcessNoise", r.process_noise());
    mat.column("ProcessNoiseStd", r.process_noise_std());
  }
  if (r.measurement_noise_size() > 0) {
    mat.column("MeasurementNoise", r.measurement_noise());
    mat.column("MeasurementNoiseStd", r.measurement_noise_std());
  }
  std::vector<std::string> outputs;
  if (r.experiments_size() > 0) {
    for (const auto& f : r.experiments(0).fits()) outputs.push_back(f.name());
  }
  mat.names("StateNames", sized_names(names.states, nx, "x"));
  mat.names("OutputNames", sized_names(outputs.empty() ? names.outputs : outputs, ny, "y"));
}

void smoothing(MatWriter& mat, const v1::SmoothingResult& r, const ModelNames& names) {
  mat.row("T", r.t());
  mat.matrix("Z", r.z_smoothed());
  mat.matrix("ZStd", r.std_smoothed());
  mat.matrix("ZFiltered", r.z_filtered());
  mat.matrix("ZFilteredStd", r.std_filtered());
  mat.matrix("Ymod", r.y_model());
  mat.matrix("Innovations", r.innovations());
  mat.names("Names", strings(r.names()));
  mat.names("OutputNames", sized_names(names.outputs, r.y_model().rows(), "y"));
}

void validation(MatWriter& mat, const v1::ValidationResult& v, const ModelNames& names) {
  mat.row("T", v.t());
  mat.matrix("Y", v.y_measured());
  mat.matrix("Ymod", v.y_simulated());
  std::vector<double> residuals(v.y_measured().values().begin(), v.y_measured().values().end());
  if (v.y_simulated().values_size() == static_cast<int>(residuals.size())) {
    for (std::size_t i = 0; i < residuals.size(); ++i) residuals[i] -= v.y_simulated().values(static_cast<int>(i));
  }
  mat.matrix("Residuals", v.y_measured().rows(), v.y_measured().cols(), residuals);
  mat.column("Theta", v.theta());
  mat.column("X0", v.x0());
  std::vector<std::string> outputs;
  for (const auto& fit : v.fits()) outputs.push_back(fit.name());
  mat.names("OutputNames", sized_names(outputs.empty() ? names.outputs : outputs, v.y_measured().rows(), "y"));
  mat.names("StateNames", sized_names(names.states, static_cast<std::size_t>(v.x0_size()), "x"));
}

}  // namespace

std::optional<std::string> write_result_mat(const v1::JobResult& r, const ModelNames& names, const std::string& path) {
  if (r.result_case() == v1::JobResult::RESULT_NOT_SET) return "the job's result holds nothing to export";
  MatWriter mat(path);
  if (!mat.open()) return "cannot write " + path;
  if (r.has_identification()) identification(mat, r.identification(), names);
  if (r.has_estimation()) estimation(mat, r.estimation(), names);
  if (r.has_smoothing()) smoothing(mat, r.smoothing(), names);
  if (r.has_validation()) validation(mat, r.validation(), names);
  if (!mat.ok()) return "cannot write " + path;
  return std::nullopt;
}

}  // namespace riccati::cli
