// Forward-mode dual numbers: a value and its N partial derivatives.
//
// Evaluating a function templated on its scalar type with Dual<N> instead of
// double gives the exact derivatives of its result with respect to the N
// inputs that were seeded with unit derivatives (the idea of Ceres' Jet).
//
// Math functions are found by argument-dependent lookup, so model code must
// call them unqualified: write `sqrt(h)`, not `std::sqrt(h)`. Every function
// below is also declared for double (through `using std::...`), so inside
// namespace riccati, or after `using namespace riccati::math;`, the same line
// compiles for both scalar types.
#pragma once

#include <array>
#include <cmath>
#include <cstddef>

namespace riccati {

template <int N>
struct Dual {
  double v = 0.0;                // value
  std::array<double, N> d{};     // d v / d input_j

  constexpr Dual() = default;
  constexpr Dual(double value) : v(value) {}  // NOLINT(google-explicit-constructor): constants mix in freely
  // A variable: value and a unit derivative with respect to input `index`.
  static constexpr Dual variable(double value, int index) {
    Dual r(value);
    r.d[index] = 1.0;
    return r;
  }

  constexpr Dual& operator+=(const Dual& o) { v += o.v; for (int i = 0; i < N; ++i) d[i] += o.d[i]; return *this; }
  constexpr Dual& operator-=(const Dual& o) { v -= o.v; for (int i = 0; i < N; ++i) d[i] -= o.d[i]; return *this; }
  constexpr Dual& operator*=(const Dual& o) { *this = *this * o; return *this; }
  constexpr Dual& operator/=(const Dual& o) { *this = *this / o; return *this; }
  constexpr Dual& operator+=(double o) { v += o; return *this; }
  constexpr Dual& operator-=(double o) { v -= o; return *this; }
  constexpr Dual& operator*=(double o) { v *= o; for (auto& x : d) x *= o; return *this; }
  constexpr Dual& operator/=(double o) { return *this *= (1.0 / o); }

  // The chain rule for a scalar function: value fv, derivative dfdv at v.
  constexpr Dual chain(double fv, double dfdv) const {
    Dual r(fv);
    for (int i = 0; i < N; ++i) r.d[i] = dfdv * d[i];
    return r;
  }

  friend constexpr Dual operator+(Dual a) { return a; }
  friend constexpr Dual operator-(const Dual& a) { return a.chain(-a.v, -1.0); }
  friend constexpr Dual operator+(Dual a, const Dual& b) { return a += b; }
  friend constexpr Dual operator-(Dual a, const Dual& b) { return a -= b; }
  friend constexpr Dual operator*(const Dual& a, const Dual& b) {
    Dual r(a.v * b.v);
    for (int i = 0; i < N; ++i) r.d[i] = a.d[i] * b.v + a.v * b.d[i];
    return r;
  }
  friend constexpr Dual operator/(const Dual& a, const Dual& b) {
    const double inv = 1.0 / b.v;
    const double q = a.v * inv;
    Dual r(q);
    for (int i = 0; i < N; ++i) r.d[i] = (a.d[i] - q * b.d[i]) * inv;
    return r;
  }
  friend constexpr Dual operator+(Dual a, double b) { return a += b; }
  friend constexpr Dual operator+(double a, Dual b) { return b += a; }
  friend constexpr Dual operator-(Dual a, double b) { return a -= b; }
  friend constexpr Dual operator-(double a, const Dual& b) { return b.chain(a - b.v, -1.0); }
  friend constexpr Dual operator*(Dual a, double b) { return a *= b; }
  friend constexpr Dual operator*(double a, Dual b) { return b *= a; }
  friend constexpr Dual operator/(Dual a, double b) { return a /= b; }
  friend constexpr Dual operator/(double a, const Dual& b) {
    const double q = a / b.v;
    return b.chain(q, -q / b.v);
  }

  // Comparisons look at values only (for branches such as a saturation).
  friend constexpr bool operator<(const Dual& a, const Dual& b) { return a.v < b.v; }
  friend constexpr bool operator>(const Dual& a, const Dual& b) { return a.v > b.v; }
  friend constexpr bool operator<=(const Dual& a, const Dual& b) { return a.v <= b.v; }
  friend constexpr bool operator>=(const Dual& a, const Dual& b) { return a.v >= b.v; }
  friend constexpr bool operator==(const Dual& a, const Dual& b) { return a.v == b.v; }
  friend constexpr bool operator<(const Dual& a, double b) { return a.v < b; }
  friend constexpr bool operator>(const Dual& a, double b) { return a.v > b; }
  friend constexpr bool operator<=(const Dual& a, double b) { return a.v <= b; }
  friend constexpr bool operator>=(const Dual& a, double b) { return a.v >= b; }
  friend constexpr bool operator<(double a, const Dual& b) { return a < b.v; }
  friend constexpr bool operator>(double a, const Dual& b) { return a > b.v; }
  friend constexpr bool operator<=(double a, const Dual& b) { return a <= b.v; }
  friend constexpr bool operator>=(double a, const Dual& b) { return a >= b.v; }

  // Elementary functions (derivatives in the comments where not obvious).
  friend Dual sqrt(const Dual& a) { const double s = std::sqrt(a.v); return a.chain(s, 0.5 / s); }
  friend Dual cbrt(const Dual& a) { const double c = std::cbrt(a.v); return a.chain(c, 1.0 / (3.0 * c * c)); }
  friend Dual exp(const Dual& a) { const double e = std::exp(a.v); return a.chain(e, e); }
  friend Dual log(const Dual& a) { return a.chain(std::log(a.v), 1.0 / a.v); }
  friend Dual sin(const Dual& a) { return a.chain(std::sin(a.v), std::cos(a.v)); }
  friend Dual cos(const Dual& a) { return a.chain(std::cos(a.v), -std::sin(a.v)); }
  friend Dual tan(const Dual& a) { const double t = std::tan(a.v); return a.chain(t, 1.0 + t * t); }
  friend Dual asin(const Dual& a) { return a.chain(std::asin(a.v), 1.0 / std::sqrt(1.0 - a.v * a.v)); }
  friend Dual acos(const Dual& a) { return a.chain(std::acos(a.v), -1.0 / std::sqrt(1.0 - a.v * a.v)); }
  friend Dual atan(const Dual& a) { return a.chain(std::atan(a.v), 1.0 / (1.0 + a.v * a.v)); }
  friend Dual sinh(const Dual& a) { return a.chain(std::sinh(a.v), std::cosh(a.v)); }
  friend Dual cosh(const Dual& a) { return a.chain(std::cosh(a.v), std::sinh(a.v)); }
  friend Dual tanh(const Dual& a) { const double t = std::tanh(a.v); return a.chain(t, 1.0 - t * t); }
  // |a|: derivative sign(a), taken as 0 at a = 0.
  friend Dual abs(const Dual& a) { return a.chain(std::abs(a.v), a.v > 0 ? 1.0 : (a.v < 0 ? -1.0 : 0.0)); }
  friend Dual fabs(const Dual& a) { return abs(a); }
  friend Dual pow(const Dual& a, double p) { return a.chain(std::pow(a.v, p), p * std::pow(a.v, p - 1.0)); }
  // a^b = exp(b log a): d = b a^(b-1) da + a^b log(a) db
  friend Dual pow(const Dual& a, const Dual& b) {
    const double r = std::pow(a.v, b.v);
    Dual out(r);
    const double da = b.v * std::pow(a.v, b.v - 1.0);
    const double db = a.v > 0 ? r * std::log(a.v) : 0.0;
    for (int i = 0; i < N; ++i) out.d[i] = da * a.d[i] + db * b.d[i];
    return out;
  }
  friend Dual pow(double a, const Dual& b) { const double r = std::pow(a, b.v); return b.chain(r, r * std::log(a)); }
  // atan2(y, x): d = (x dy - y dx) / (x^2 + y^2)
  friend Dual atan2(const Dual& y, const Dual& x) {
    const double den = x.v * x.v + y.v * y.v;
    Dual out(std::atan2(y.v, x.v));
    for (int i = 0; i < N; ++i) out.d[i] = (x.v * y.d[i] - y.v * x.d[i]) / den;
    return out;
  }
  friend bool isfinite(const Dual& a) { return std::isfinite(a.v); }
};

// Second-order dual numbers: a value, its N partial derivatives and its
// N x N second derivatives (a truncated Taylor expansion, a "hyper-dual"
// number). Evaluating a model with Dual2<nz> gives its exact Hessians with
// respect to [x; theta], which maximum likelihood's exact gradient needs
// (the derivative of the filter's covariance equation involves d(df/dx)).
// The rules are the first-order ones of Dual plus the second-order term of
// the chain rule, f(a)'' = f'(a) a'' + f''(a) a' a'^T.
template <int N>
struct Dual2 {
  double v = 0.0;
  std::array<double, N> d{};      // d v / d input_j
  // d^2 v / d input_i d input_j for i >= j (the matrix is symmetric): the
  // lower triangle packed column by column, (0,0) (1,0) .. (N-1,0) (1,1) ..
  static constexpr int kPacked = N * (N + 1) / 2;
  std::array<double, kPacked> h{};

  constexpr Dual2() = default;
  constexpr Dual2(double value) : v(value) {}  // NOLINT(google-explicit-constructor): constants mix in freely
  static constexpr Dual2 variable(double value, int index) {
    Dual2 r(value);
    r.d[index] = 1.0;
    return r;
  }

  // f(a) with f = fv, f' = f1 and f'' = f2 at a's value.
  constexpr Dual2 chain(double fv, double f1, double f2) const {
    Dual2 r(fv);
    for (int i = 0; i < N; ++i) r.d[i] = f1 * d[i];
    for (int j = 0, k = 0; j < N; ++j) {
      for (int i = j; i < N; ++i, ++k) r.h[k] = f1 * h[k] + f2 * d[i] * d[j];
    }
    return r;
  }

  constexpr Dual2& operator+=(const Dual2& o) {
    v += o.v;
    for (int i = 0; i < N; ++i) d[i] += o.d[i];
    for (int i = 0; i < kPacked; ++i) h[i] += o.h[i];
    return *this;
  }
  constexpr Dual2& operator-=(const Dual2& o) {
    v -= o.v;
    for (int i = 0; i < N; ++i) d[i] -= o.d[i];
    for (int i = 0; i < kPacked; ++i) h[i] -= o.h[i];
    return *this;
  }
  constexpr Dual2& operator*=(const Dual2& o) { *this = *this * o; return *this; }
  constexpr Dual2& operator/=(const Dual2& o) { *this = *this / o; return *this; }
  constexpr Dual2& operator+=(double o) { v += o; return *this; }
  constexpr Dual2& operator-=(double o) { v -= o; return *this; }
  constexpr Dual2& operator*=(double o) {
    v *= o;
    for (auto& x : d) x *= o;
    for (auto& x : h) x *= o;
    return *this;
  }
  constexpr Dual2& operator/=(double o) { return *this *= (1.0 / o); }

  friend constexpr Dual2 operator+(Dual2 a) { return a; }
  friend constexpr Dual2 operator-(Dual2 a) { return a *= -1.0; }
  friend constexpr Dual2 operator+(Dual2 a, const Dual2& b) { return a += b; }
  friend constexpr Dual2 operator-(Dual2 a, const Dual2& b) { return a -= b; }
  friend constexpr Dual2 operator*(const Dual2& a, const Dual2& b) {
    Dual2 r(a.v * b.v);
    for (int i = 0; i < N; ++i) r.d[i] = a.d[i] * b.v + a.v * b.d[i];
    for (int j = 0, k = 0; j < N; ++j) {
      for (int i = j; i < N; ++i, ++k) r.h[k] = a.h[k] * b.v + a.v * b.h[k] + a.d[i] * b.d[j] + b.d[i] * a.d[j];
    }
    return r;
  }
  // a / b = a * (1 / b).
  friend constexpr Dual2 operator/(const Dual2& a, const Dual2& b) {
    const double inv = 1.0 / b.v;
    return a * b.chain(inv, -inv * inv, 2.0 * inv * inv * inv);
  }
  friend constexpr Dual2 operator+(Dual2 a, double b) { return a += b; }
  friend constexpr Dual2 operator+(double a, Dual2 b) { return b += a; }
  friend constexpr Dual2 operator-(Dual2 a, double b) { return a -= b; }
  friend constexpr Dual2 operator-(double a, Dual2 b) { return (b *= -1.0) += a; }
  friend constexpr Dual2 operator*(Dual2 a, double b) { return a *= b; }
  friend constexpr Dual2 operator*(double a, Dual2 b) { return b *= a; }
  friend constexpr Dual2 operator/(Dual2 a, double b) { return a /= b; }
  friend constexpr Dual2 operator/(double a, const Dual2& b) {
    const double inv = 1.0 / b.v;
    return b.chain(a * inv, -a * inv * inv, 2.0 * a * inv * inv * inv);
  }

  friend constexpr bool operator<(const Dual2& a, const Dual2& b) { return a.v < b.v; }
  friend constexpr bool operator>(const Dual2& a, const Dual2& b) { return a.v > b.v; }
  friend constexpr bool operator<=(const Dual2& a, const Dual2& b) { return a.v <= b.v; }
  friend constexpr bool operator>=(const Dual2& a, const Dual2& b) { return a.v >= b.v; }
  friend constexpr bool operator==(const Dual2& a, const Dual2& b) { return a.v == b.v; }
  friend constexpr bool operator<(const Dual2& a, double b) { return a.v < b; }
  friend constexpr bool operator>(const Dual2& a, double b) { return a.v > b; }
  friend constexpr bool operator<=(const Dual2& a, double b) { return a.v <= b; }
  friend constexpr bool operator>=(const Dual2& a, double b) { return a.v >= b; }
  friend constexpr bool operator<(double a, const Dual2& b) { return a < b.v; }
  friend constexpr bool operator>(double a, const Dual2& b) { return a > b.v; }
  friend constexpr bool operator<=(double a, const Dual2& b) { return a <= b.v; }
  friend constexpr bool operator>=(double a, const Dual2& b) { return a >= b.v; }

  friend Dual2 sqrt(const Dual2& a) {
    const double s = std::sqrt(a.v);
    return a.chain(s, 0.5 / s, -0.25 / (s * a.v));
  }
  friend Dual2 cbrt(const Dual2& a) {
    const double c = std::cbrt(a.v);
    return a.chain(c, 1.0 / (3.0 * c * c), -2.0 / (9.0 * c * c * c * c * c));
  }
  friend Dual2 exp(const Dual2& a) { const double e = std::exp(a.v); return a.chain(e, e, e); }
  friend Dual2 log(const Dual2& a) { return a.chain(std::log(a.v), 1.0 / a.v, -1.0 / (a.v * a.v)); }
  friend Dual2 sin(const Dual2& a) {
    const double s = std::sin(a.v);
    return a.chain(s, std::cos(a.v), -s);
  }
  friend Dual2 cos(const Dual2& a) {
    const double c = std::cos(a.v);
    return a.chain(c, -std::sin(a.v), -c);
  }
  friend Dual2 tan(const Dual2& a) {
    const double t = std::tan(a.v), s = 1.0 + t * t;
    return a.chain(t, s, 2.0 * t * s);
  }
  friend Dual2 asin(const Dual2& a) {
    const double q = 1.0 - a.v * a.v;
    return a.chain(std::asin(a.v), 1.0 / std::sqrt(q), a.v / (q * std::sqrt(q)));
  }
  friend Dual2 acos(const Dual2& a) {
    const double q = 1.0 - a.v * a.v;
    return a.chain(std::acos(a.v), -1.0 / std::sqrt(q), -a.v / (q * std::sqrt(q)));
  }
  friend Dual2 atan(const Dual2& a) {
    const double q = 1.0 + a.v * a.v;
    return a.chain(std::atan(a.v), 1.0 / q, -2.0 * a.v / (q * q));
  }
  friend Dual2 sinh(const Dual2& a) { const double s = std::sinh(a.v); return a.chain(s, std::cosh(a.v), s); }
  friend Dual2 cosh(const Dual2& a) { const double c = std::cosh(a.v); return a.chain(c, std::sinh(a.v), c); }
  friend Dual2 tanh(const Dual2& a) {
    const double t = std::tanh(a.v), s = 1.0 - t * t;
    return a.chain(t, s, -2.0 * t * s);
  }
  friend Dual2 abs(const Dual2& a) { return a.chain(std::abs(a.v), a.v > 0 ? 1.0 : (a.v < 0 ? -1.0 : 0.0), 0.0); }
  friend Dual2 fabs(const Dual2& a) { return abs(a); }
  friend Dual2 pow(const Dual2& a, double p) {
    return a.chain(std::pow(a.v, p), p * std::pow(a.v, p - 1.0), p * (p - 1.0) * std::pow(a.v, p - 2.0));
  }
  // a^b = exp(b log a) for a > 0; elsewhere b's derivative is left out, as Dual's rule does.
  friend Dual2 pow(const Dual2& a, const Dual2& b) { return a.v > 0 ? exp(b * log(a)) : pow(a, b.v); }
  friend Dual2 pow(double a, const Dual2& b) {
    const double r = std::pow(a, b.v), l = std::log(a);
    return b.chain(r, r * l, r * l * l);
  }
  // atan2(y, x): gradient (x, -y) / (x^2 + y^2), Hessian (-2xy, y^2 - x^2; y^2 - x^2, 2xy) / (x^2 + y^2)^2.
  friend Dual2 atan2(const Dual2& y, const Dual2& x) {
    const double den = x.v * x.v + y.v * y.v, den2 = den * den;
    const double gy = x.v / den, gx = -y.v / den;
    const double hyy = -2.0 * x.v * y.v / den2, hxx = -hyy, hxy = (y.v * y.v - x.v * x.v) / den2;
    Dual2 r(std::atan2(y.v, x.v));
    for (int i = 0; i < N; ++i) r.d[i] = gy * y.d[i] + gx * x.d[i];
    for (int j = 0, k = 0; j < N; ++j) {
      for (int i = j; i < N; ++i, ++k) {
        r.h[k] = gy * y.h[k] + gx * x.h[k] + hyy * y.d[i] * y.d[j] + hxx * x.d[i] * x.d[j] +
                 hxy * (y.d[i] * x.d[j] + x.d[i] * y.d[j]);
      }
    }
    return r;
  }
  friend bool isfinite(const Dual2& a) { return std::isfinite(a.v); }
};

using std::abs;
using std::acos;
using std::asin;
using std::atan;
using std::atan2;
using std::cbrt;
using std::cos;
using std::cosh;
using std::exp;
using std::fabs;
using std::isfinite;
using std::log;
using std::pow;
using std::sin;
using std::sinh;
using std::sqrt;
using std::tan;
using std::tanh;

// Dual numbers of a width known only at run time, stored as w consecutive
// doubles (the value, then w - 1 derivatives), for hosts whose sizes come
// from data (the host's text models): the operations of Dual<N> above, the
// same formulas in the same order, on caller-given storage (no allocation).
// Width 1 is plain doubles (a division then divides, as double arithmetic does).
struct DualArithmetic {
  std::size_t w;
  void mul(const double* a, const double* b, double* out) const {  // out may not alias a or b
    out[0] = a[0] * b[0];
    for (std::size_t i = 1; i < w; ++i) out[i] = a[i] * b[0] + a[0] * b[i];
  }
  void div(const double* a, const double* b, double* out) const {
    if (w == 1) {
      out[0] = a[0] / b[0];
      return;
    }
    const double inv = 1.0 / b[0];
    const double q = a[0] * inv;
    out[0] = q;
    for (std::size_t i = 1; i < w; ++i) out[i] = (a[i] - q * b[i]) * inv;
  }
  void sub_from(double* a, const double* b) const {
    for (std::size_t i = 0; i < w; ++i) a[i] -= b[i];
  }
  void add_to(double* a, const double* b) const {
    for (std::size_t i = 0; i < w; ++i) a[i] += b[i];
  }
  void add_scaled(double* a, const double* b, double s) const {  // a += b * s (a dual times a double)
    for (std::size_t i = 0; i < w; ++i) a[i] += b[i] * s;
  }
  void copy(double* a, const double* b) const {
    for (std::size_t i = 0; i < w; ++i) a[i] = b[i];
  }
};

inline double value_of(double a) { return a; }
template <int N>
double value_of(const Dual<N>& a) { return a.v; }
template <int N>
double value_of(const Dual2<N>& a) { return a.v; }

// min/max by value, keeping the derivative of the chosen argument.
template <typename T>
T min(const T& a, const T& b) { return b < a ? b : a; }
template <typename T>
T max(const T& a, const T& b) { return a < b ? b : a; }

// Saturation: a clamped to [-1, 1] (derivative 0 outside), as in c*sat(v/vg).
template <typename T>
T sat(const T& a) {
  if (a > 1.0) return T(1.0);
  if (a < -1.0) return T(-1.0);
  return a;
}

// Square, which reads better than pow(a, 2) and costs one product.
template <typename T>
T square(const T& a) { return a * a; }

namespace math {
using riccati::abs;
using riccati::acos;
using riccati::asin;
using riccati::atan;
using riccati::atan2;
using riccati::cbrt;
using riccati::cos;
using riccati::cosh;
using riccati::exp;
using riccati::fabs;
using riccati::isfinite;
using riccati::log;
using riccati::max;
using riccati::min;
using riccati::pow;
using riccati::sat;
using riccati::sin;
using riccati::sinh;
using riccati::sqrt;
using riccati::square;
using riccati::tan;
using riccati::tanh;
}  // namespace math

}  // namespace riccati
