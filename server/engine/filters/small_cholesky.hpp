// The Cholesky factorisation and solve of a small symmetric positive
// definite matrix (the EKF's and UKF's innovation covariance S, ny x ny; the
// optimal filter's D'VD, P x P). At these sizes (2 to 6) Eigen's LLT and
// its triangular solves, blocked for large matrices, cost several times the
// arithmetic (docs/benchmarks-log.md). Private to filters/.
#pragma once

#include <cmath>

#include "engine/filters/fixed_size.hpp"

namespace riccati {

// The lower Cholesky factor of the symmetric n x n matrix a (column-major)
// into l, its diagonal stored as reciprocals (so that solving multiplies);
// false when a is not positive definite (or not finite).
inline bool cholesky(int n, const double* __restrict a, double* __restrict l) {
  for (int j = 0; j < n; ++j) {
    double d = a[j + j * n];
    for (int k = 0; k < j; ++k) d -= l[j + k * n] * l[j + k * n];
    if (!(d > 0.0)) return false;
    const double r = 1.0 / std::sqrt(d);
    l[j + j * n] = r;
    for (int i = j + 1; i < n; ++i) {
      double s = a[i + j * n];
      for (int k = 0; k < j; ++k) s -= l[i + k * n] * l[j + k * n];
      l[i + j * n] = s * r;
    }
  }
  return true;
}

// b := (l l')^-1 b for the m columns of the n x m matrix b, l from
// cholesky(); instantiated per n (fixed_size.hpp): the loops of a 3 x 3
// solve are shorter than their branches.
template <int NN>
void cholesky_solve(int n_runtime, const double* __restrict l, double* __restrict b, int m) {
  const int n = size_or<NN>(n_runtime);
  for (int c = 0; c < m; ++c) {
    double* x = b + c * n;
    for (int i = 0; i < n; ++i) {  // l y = b
      double s = x[i];
      for (int k = 0; k < i; ++k) s -= l[i + k * n] * x[k];
      x[i] = s * l[i + i * n];
    }
    for (int i = n - 1; i >= 0; --i) {  // l' x = y
      double s = x[i];
      for (int k = i + 1; k < n; ++k) s -= l[k + i * n] * x[k];
      x[i] = s * l[i + i * n];
    }
  }
}
using CholeskySolveFn = void (*)(int, const double*, double*, int);

// cholesky_solve for n, instantiated for n <= 6 (more measured outputs, or
// inputs and accelerations, than that take the general loop).
inline CholeskySolveFn cholesky_solve_for(int n) {
  return kernel_for<1, 6>(n, []<int NN>() -> CholeskySolveFn { return &cholesky_solve<NN>; });
}

}  // namespace riccati
