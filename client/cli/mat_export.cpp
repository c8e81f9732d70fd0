#include "mat_export.hpp"

#include <matio.h>

#include <memory>
#include <vector>

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

  void column(const char* name, const google::protobuf::RepeatedField<double>& v) {
    matrix(name, static_cast<std::size_t>(v.size()), 1, v.data());
  }

  void row(const char* name, const google::protobuf::RepeatedField<double>& v) {
    matrix(name, 1, static_cast<std::size_t>(v.size()), v.data());
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

}  // namespace

std::optional<std::string> write_result_mat(const v1::JobResult& r, const std::string& path) {
  if (!r.has_identification() && !r.has_validation()) {
    return "the MAT layout holds identifications by the iterated filter and validations; export this result as "
           "CSV or JSON";
  }
  MatWriter mat(path);
  if (!mat.open()) return "cannot write " + path;
  if (r.has_identification()) {
    const v1::IdentificationResult& id = r.identification();
    mat.row("T", id.t());
    mat.column("Theta", id.theta_mean());
    mat.column("ThetaFinal", id.theta());
    mat.column("ThetaStd", id.theta_std());
    if (id.passes_size() > 0) mat.matrix("Trace", id.passes(id.passes_size() - 1).theta_trace());
    mat.matrix("X", id.x_trace());
    mat.matrix("Ymod", id.y_model());
    mat.matrix("Innovations", id.innovations());
    mat.matrix("P", id.covariance());
    mat.names("ParamNames", strings(id.param_names()));
  } else {
    const v1::ValidationResult& v = r.validation();
    mat.row("T", v.t());
    mat.matrix("Y", v.y_measured());
    mat.matrix("Ymod", v.y_simulated());
    mat.column("Theta", v.theta());
    mat.column("X0", v.x0());
    std::vector<std::string> outputs;
    for (const auto& fit : v.fits()) outputs.push_back(fit.name());
    mat.names("OutputNames", outputs);
  }
  if (!mat.ok()) return "cannot write " + path;
  return std::nullopt;
}

}  // namespace riccati::cli
