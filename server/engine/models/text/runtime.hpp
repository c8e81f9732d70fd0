// The runtime of a text model: the compiled model behind its
// riccati_model_v1 table (model_abi.h), whose functions run the compiler's
// tapes (tape.hpp) as a plugin's would run its code: f and g at one point or
// a batch (16 lanes at a time), their Jacobians from the tapes of their
// symbolic derivatives, and for the mechanical form the accelerations solved
// from M a = H u - h as the SDK solves them (riccati/model.hpp).
#pragma once

#include <cstddef>
#include <memory>
#include <string>
#include <vector>

#include "engine/models/text/tape.hpp"
#include "riccati/model_abi.h"

namespace riccati::text {

// What the compiler fills in (compiler.cpp), then fill_table().
struct CompiledModel {
 public:
  std::string name, version, description;
  std::vector<std::string> states, params, inputs, outputs;
  std::vector<const char*> state_ptrs, param_ptrs, input_ptrs, output_ptrs;
  std::vector<std::string> state_units, param_units, input_units, output_units;  // "" where none
  std::vector<const char*> state_unit_ptrs, param_unit_ptrs, input_unit_ptrs, output_unit_ptrs;
  std::vector<double> theta_default, theta_lower, theta_upper;
  Tape f, g, f_jac, g_jac;  // f_jac: f then df/dz column-major; g_jac likewise
  // f, df/dz, then d^2 f/dz^2 (model_abi.h's layout); g_hess likewise. Only
  // for a model written with der: (and small enough for the graph).
  Tape f_hess, g_hess;
  bool has_second_derivatives = false;
  int nx = 0, ntheta = 0, nu = 0, ny = 0;
  // The mechanical form (ndof > 0): f and g come from M, h, H, g, G, R,
  // whose values (mech) and derivatives (mech_jac: the values, then entry e
  // of z_j at count + e + j count) the tapes give; the accelerations are
  // solved for as the SDK does (riccati/model.hpp, detail::gaussian_elimination), with the
  // same dual arithmetic for the Jacobians, so that a text model and a
  // plugin agree to rounding.
  int ndof = 0;
  Tape mech, mech_jac;
  std::size_t mech_count = 0;  // entries of M, h, H, g, G, R
  std::size_t mech_scratch = 0;
  std::size_t registers = 0;  // the most any tape needs, plus room for outputs
  riccati_model_v1 table{};

  // Points `table` at the names, units, bounds and the functions that run
  // the tapes, with this model as their user_data; once every field above
  // is set. The model must come from new_compiled_model().
  void fill_table();
};

// A CompiledModel whose table's functions can run it.
std::shared_ptr<CompiledModel> new_compiled_model();

// What check_jacobians() (jacobian_check.cpp) costs on this model, in tape
// instructions and arithmetic operations, from the sizes of its tapes: at
// each of generic_points()' 3 points, an exact Jacobian and 4 evaluations
// per column z_j for its fourth-order differences, of f and g, and of the
// mechanical form's c and Fc, each of which runs the derivatives' tape and
// copies every entry with its derivatives (about nz^2 n^2 a call: what makes
// a dense mass matrix cost n^5). About the time in nanoseconds on a current
// core (n = 32, 40, 48: 0.6, 1.6, 3.3 s for 0.6e9, 1.6e9, 3.2e9).
double check_operations(const CompiledModel& m);

}  // namespace riccati::text
