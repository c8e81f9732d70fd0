// Lanes<W>: W points evaluated together, one lane each.
//
// The host asks for f and g at many points in one call (a UKF's sigma
// points, model_abi.h). Evaluating the model's templated code with T =
// Lanes<W> instead of double runs every operation on W points at once: each
// operator is a loop over the lanes that the compiler turns into vector
// instructions (sqrt and division above all, whose throughput bounds such
// models), and each lane does exactly the IEEE operations the one-point
// evaluation does, in the same order, so the results are the same to the bit.
//
// Branches: a comparison gives a LaneMask, and `if (h > 0)`, `c ? a : b`,
// `&&`, `||` and `!` ask it for one bool. When every lane agrees that is the
// answer; when they differ there is no single answer, and the mask throws
// DivergentLanes: the SDK then evaluates those points one at a time (see
// detail::Plugin::eval). So models branch as they always did; points that
// straddle a branch cost a little more, and nothing is ever wrong.
// min, max, sat and abs work lane by lane and never diverge. `value_of`
// gives the lanes' common value, and diverges if they differ.
#pragma once

#include <cmath>
#include <exception>

namespace riccati {

// Lanes that take different sides of a branch (caught inside the SDK).
struct DivergentLanes : std::exception {
  const char* what() const noexcept override { return "lanes take different branches"; }
};

namespace detail {
template <int W>
struct LaneVector;
template <>
struct LaneVector<2> {
  typedef double type __attribute__((vector_size(16)));
};
template <>
struct LaneVector<4> {
  typedef double type __attribute__((vector_size(32)));
};
template <>
struct LaneVector<8> {
  typedef double type __attribute__((vector_size(64)));
};
}  // namespace detail

template <int W>
struct LaneMask {
  bool m[W];

  explicit operator bool() const {
    for (int i = 1; i < W; ++i) {
      if (m[i] != m[0]) throw DivergentLanes();
    }
    return m[0];
  }
  friend LaneMask operator!(const LaneMask& a) {
    LaneMask r;
    for (int i = 0; i < W; ++i) r.m[i] = !a.m[i];
    return r;
  }
};

template <int W>
struct Lanes {
  // A vector of W doubles (GCC's and Clang's vector extension): + - * / are
  // vector instructions whatever the optimiser decides.
  using Vector = typename detail::LaneVector<W>::type;
  Vector v;

  Lanes() : v{} {}
  Lanes(double c) {  // NOLINT(google-explicit-constructor): constants mix in freely, as with Dual
    for (int i = 0; i < W; ++i) v[i] = c;
  }

  // Applies f to every lane (the functions of <cmath>).
  template <typename F>
  Lanes map(F f) const {
    Lanes r;
    for (int i = 0; i < W; ++i) r.v[i] = f(v[i]);
    return r;
  }
  template <typename F>
  static Lanes zip(const Lanes& a, const Lanes& b, F f) {
    Lanes r;
    for (int i = 0; i < W; ++i) r.v[i] = f(a.v[i], b.v[i]);
    return r;
  }
  template <typename F>
  static LaneMask<W> compare(const Lanes& a, const Lanes& b, F f) {
    LaneMask<W> r;
    for (int i = 0; i < W; ++i) r.m[i] = f(a.v[i], b.v[i]);
    return r;
  }

  Lanes& operator+=(const Lanes& o) { v += o.v; return *this; }
  Lanes& operator-=(const Lanes& o) { v -= o.v; return *this; }
  Lanes& operator*=(const Lanes& o) { v *= o.v; return *this; }
  Lanes& operator/=(const Lanes& o) { v /= o.v; return *this; }

  friend Lanes operator+(const Lanes& a) { return a; }
  friend Lanes operator-(const Lanes& a) { Lanes r; r.v = -a.v; return r; }
  friend Lanes operator+(Lanes a, const Lanes& b) { return a += b; }
  friend Lanes operator-(Lanes a, const Lanes& b) { return a -= b; }
  friend Lanes operator*(Lanes a, const Lanes& b) { return a *= b; }
  friend Lanes operator/(Lanes a, const Lanes& b) { return a /= b; }

  friend LaneMask<W> operator<(const Lanes& a, const Lanes& b) { return compare(a, b, [](double x, double y) { return x < y; }); }
  friend LaneMask<W> operator>(const Lanes& a, const Lanes& b) { return compare(a, b, [](double x, double y) { return x > y; }); }
  friend LaneMask<W> operator<=(const Lanes& a, const Lanes& b) { return compare(a, b, [](double x, double y) { return x <= y; }); }
  friend LaneMask<W> operator>=(const Lanes& a, const Lanes& b) { return compare(a, b, [](double x, double y) { return x >= y; }); }
  friend LaneMask<W> operator==(const Lanes& a, const Lanes& b) { return compare(a, b, [](double x, double y) { return x == y; }); }
  friend LaneMask<W> operator!=(const Lanes& a, const Lanes& b) { return compare(a, b, [](double x, double y) { return x != y; }); }

  friend Lanes sqrt(const Lanes& a) { return a.map([](double x) { return std::sqrt(x); }); }
  friend Lanes cbrt(const Lanes& a) { return a.map([](double x) { return std::cbrt(x); }); }
  friend Lanes exp(const Lanes& a) { return a.map([](double x) { return std::exp(x); }); }
  friend Lanes log(const Lanes& a) { return a.map([](double x) { return std::log(x); }); }
  friend Lanes sin(const Lanes& a) { return a.map([](double x) { return std::sin(x); }); }
  friend Lanes cos(const Lanes& a) { return a.map([](double x) { return std::cos(x); }); }
  friend Lanes tan(const Lanes& a) { return a.map([](double x) { return std::tan(x); }); }
  friend Lanes asin(const Lanes& a) { return a.map([](double x) { return std::asin(x); }); }
  friend Lanes acos(const Lanes& a) { return a.map([](double x) { return std::acos(x); }); }
  friend Lanes atan(const Lanes& a) { return a.map([](double x) { return std::atan(x); }); }
  friend Lanes sinh(const Lanes& a) { return a.map([](double x) { return std::sinh(x); }); }
  friend Lanes cosh(const Lanes& a) { return a.map([](double x) { return std::cosh(x); }); }
  friend Lanes tanh(const Lanes& a) { return a.map([](double x) { return std::tanh(x); }); }
  friend Lanes abs(const Lanes& a) { return a.map([](double x) { return std::abs(x); }); }
  friend Lanes fabs(const Lanes& a) { return abs(a); }
  friend Lanes pow(const Lanes& a, const Lanes& b) { return zip(a, b, [](double x, double y) { return std::pow(x, y); }); }
  friend Lanes atan2(const Lanes& y, const Lanes& x) { return zip(y, x, [](double p, double q) { return std::atan2(p, q); }); }
  friend LaneMask<W> isfinite(const Lanes& a) {
    LaneMask<W> r;
    for (int i = 0; i < W; ++i) r.m[i] = std::isfinite(a.v[i]);
    return r;
  }
  // As riccati::min, max and sat do for one point (dual.hpp), lane by lane.
  friend Lanes min(const Lanes& a, const Lanes& b) { return zip(a, b, [](double x, double y) { return y < x ? y : x; }); }
  friend Lanes max(const Lanes& a, const Lanes& b) { return zip(a, b, [](double x, double y) { return x < y ? y : x; }); }
  friend Lanes sat(const Lanes& a) {
    return a.map([](double x) { return x > 1.0 ? 1.0 : (x < -1.0 ? -1.0 : x); });
  }
  friend Lanes square(const Lanes& a) { return a * a; }
  friend double value_of(const Lanes& a) {
    for (int i = 1; i < W; ++i) {
      if (!(a.v[i] == a.v[0])) throw DivergentLanes();
    }
    return a.v[0];
  }
};

}  // namespace riccati
