// A loaded model: the host's view of a plugin's riccati_model_v1 table.
//
// Model checks what a plugin returns (sizes, names, finite defaults, bounds)
// once, when it is created, and checks every evaluation for NaN and Inf. It
// keeps the plugin's shared library loaded for as long as any holder of the
// shared_ptr<const Model> (a filter, a job, a session) is alive.
#pragma once

#include <Eigen/Core>
#include <memory>
#include <string>
#include <vector>

#include "engine/status.hpp"
#include "riccati/model_abi.h"

namespace riccati {

class Model {
 public:
  // Validates `table` and wraps it. `library` owns whatever keeps the table's
  // code loaded (the dlopen handle); `origin` names the plugin in messages.
  static Result<std::shared_ptr<const Model>> create(const riccati_model_v1* table, std::shared_ptr<void> library,
                                                     std::string origin);

  const std::string& name() const { return name_; }
  const std::string& version() const { return version_; }
  const std::string& description() const { return description_; }
  const std::string& origin() const { return origin_; }

  int nx() const { return nx_; }
  int ntheta() const { return ntheta_; }
  int nu() const { return nu_; }
  int ny() const { return ny_; }
  int nz() const { return nx_ + ntheta_; }  // augmented state [x; theta]
  // Degrees of freedom of the mechanical form (0: the model has none).
  int ndof() const { return ndof_; }
  bool has_mechanical_form() const { return mech_ != nullptr || mech_ctx_ != nullptr; }

  const std::vector<std::string>& state_names() const { return state_names_; }
  const std::vector<std::string>& param_names() const { return param_names_; }
  const std::vector<std::string>& input_names() const { return input_names_; }
  const std::vector<std::string>& output_names() const { return output_names_; }
  // Units as the table declares them, one per name; "" where none is given.
  const std::vector<std::string>& state_units() const { return state_units_; }
  const std::vector<std::string>& param_units() const { return param_units_; }
  const std::vector<std::string>& input_units() const { return input_units_; }
  const std::vector<std::string>& output_units() const { return output_units_; }
  const Eigen::VectorXd& theta_default() const { return theta_default_; }
  const Eigen::VectorXd& theta_lower() const { return theta_lower_; }
  const Eigen::VectorXd& theta_upper() const { return theta_upper_; }

  // Whether the plugin gives exact Jacobians (else: central finite differences).
  bool has_f_jacobian() const { return with_context_ ? table_->f_jac_ctx != nullptr : table_->f_jac != nullptr; }
  bool has_g_jacobian() const { return with_context_ ? table_->g_jac_ctx != nullptr : table_->g_jac != nullptr; }

  // Whether the plugin gives exact second derivatives of f and of g (both:
  // maximum likelihood's exact gradient needs the two).
  bool has_second_derivatives() const {
    return with_context_ ? f_hess_ctx_ != nullptr && g_hess_ctx_ != nullptr : f_hess_ != nullptr && g_hess_ != nullptr;
  }

  // f or g at n points stored variable-major with leading dimension ld (see
  // model_abi.h): x [nx * ld], theta [ntheta * ld], out [nx or ny * ld].
  Status f(double t, const double* u, int n, std::size_t ld, const double* x, const double* theta,
           double* out) const;
  Status g(double t, const double* u, int n, std::size_t ld, const double* x, const double* theta,
           double* out) const;

  // Value and Jacobian with respect to [x; theta] at one point; jac is
  // rows x nz, column-major (rows = nx for f, ny for g).
  Status f_jacobian(double t, const double* u, const double* x, const double* theta, double* out,
                    double* jac) const;
  Status g_jacobian(double t, const double* u, const double* x, const double* theta, double* out,
                    double* jac) const;

  // Value, Jacobian and second derivatives with respect to [x; theta] at one
  // point (model_abi.h, riccati_hess_fn): hess is rows x nz x nz, entry
  // d^2 out_i / d z_a d z_b at hess[i + rows (a + nz b)]. Only when
  // has_second_derivatives().
  Status f_hessian(double t, const double* u, const double* x, const double* theta, double* out, double* jac,
                   double* hess) const;
  Status g_hessian(double t, const double* u, const double* x, const double* theta, double* out, double* jac,
                   double* hess) const;

  // The mechanical form at one point (model_abi.h, riccati_mech_fn): with
  // n = ndof, c [n + ny] = [h; g], Fc [(n + ny) x (nu + n)] = [-H M; R G],
  // and their Jacobians with respect to [x; theta], c_jac [(n + ny) x nz]
  // and Fc_jac [(n + ny)(nu + n) x nz], all column-major.
  Status mechanical(double t, const double* x, const double* theta, double* c, double* Fc, double* c_jac,
                    double* Fc_jac) const;

  // Index of a state / parameter / input / output by name, or -1.
  int state_index(std::string_view n) const;
  int param_index(std::string_view n) const;
  int input_index(std::string_view n) const;
  int output_index(std::string_view n) const;

 private:
  Model() = default;
  Status eval(bool is_f, double t, const double* u, int n, std::size_t ld, const double* x, const double* theta,
              double* out) const;
  Status jacobian(bool is_f, double t, const double* u, const double* x, const double* theta, double* out,
                  double* jac) const;
  Status finite_difference_jacobian(bool is_f, double t, const double* u, const double* x, const double* theta,
                                    double* out, double* jac) const;
  Status non_finite_error(bool is_f, double t, int row) const;
  Status hessian(bool is_f, double t, const double* u, const double* x, const double* theta, double* out,
                 double* jac, double* hess) const;

  const riccati_model_v1* table_ = nullptr;
  std::shared_ptr<void> library_;
  std::string name_, version_, description_, origin_;
  int nx_ = 0, ntheta_ = 0, nu_ = 0, ny_ = 0, ndof_ = 0;
  riccati_mech_fn mech_ = nullptr;
  // The table's functions with a context (model_abi.h): set when the table
  // gives f_ctx and g_ctx, and then used instead of the plain ones.
  bool with_context_ = false;
  riccati_mech_ctx_fn mech_ctx_ = nullptr;
  // The second derivatives' functions (the table's, when it reaches them).
  riccati_hess_fn f_hess_ = nullptr, g_hess_ = nullptr;
  riccati_hess_ctx_fn f_hess_ctx_ = nullptr, g_hess_ctx_ = nullptr;
  std::vector<std::string> state_names_, param_names_, input_names_, output_names_;
  std::vector<std::string> state_units_, param_units_, input_units_, output_units_;
  Eigen::VectorXd theta_default_, theta_lower_, theta_upper_;
};

using ModelPtr = std::shared_ptr<const Model>;

}  // namespace riccati
