// The variational equations of x' = f(x, theta, u, t): how the derivatives of
// the solution with respect to its initial state and the parameters evolve,
//
//     S' = f_x S + [0  f_theta],    S = [dx/dx0  dx/dtheta]  (nx x (nx + ntheta)),
//
// or S = dx/dtheta alone (S' = f_x S + f_theta) when the initial state is
// known. The EKF integrates them for its transition matrix (smoothing), the
// output-error method for its forward sensitivities. They run at every stage
// of every integration step, so they are kernels unrolled per nx.
#pragma once

namespace riccati {

// dS = f_x S + [0 f_theta] at one point. J = [f_x f_theta] (nx x (nx +
// ntheta)) and S, dS (nx x columns) are column-major; the first
// `unforced` columns of S (0, or nx for dx/dx0) have no f_theta term, the
// others take f_theta's columns in order. NX > 0 fixes nx at compile time so
// the loops over a column unroll (at these sizes the vectoriser's run-time
// checks cost more than the arithmetic, and the unrolled column stays in
// registers); NX = 0 is the general case.
template <int NX>
void variational_derivative(int nx_runtime, int columns, int unforced, const double* __restrict J,
                            const double* __restrict S, double* __restrict dS) {
  const int nx = NX > 0 ? NX : nx_runtime;
  for (int c = 0; c < columns; ++c) {
    const double* s = S + c * nx;
    double* d = dS + c * nx;
    if (c < unforced) {
      for (int i = 0; i < nx; ++i) d[i] = 0.0;
    } else {
      const double* forcing = J + (nx + c - unforced) * nx;
      for (int i = 0; i < nx; ++i) d[i] = forcing[i];
    }
    for (int k = 0; k < nx; ++k) {
      const double p = s[k];
      for (int i = 0; i < nx; ++i) d[i] += J[i + k * nx] * p;
    }
  }
}

using VariationalDerivativeFn = void (*)(int, int, int, const double*, const double*, double*);

inline VariationalDerivativeFn variational_derivative_for(int nx) {
  switch (nx) {
    case 1: return &variational_derivative<1>;
    case 2: return &variational_derivative<2>;
    case 3: return &variational_derivative<3>;
    case 4: return &variational_derivative<4>;
    case 5: return &variational_derivative<5>;
    case 6: return &variational_derivative<6>;
    default: return &variational_derivative<0>;
  }
}

}  // namespace riccati
