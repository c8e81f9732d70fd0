// Rotary inverted pendulum driven by a DC motor (Zheng, Ikeda, Shimomura
// 2010, eqs 55-57; dataset tests/data/rotary_pendulum.json).
//
//   (m r^2 + Jb) phi'' - m r l cos(a) a'' + m r l sin(a) a'^2 = tau
//   -m r l cos(a) phi'' + 4/3 m l^2 a''   + m g l sin(a)      = 0
//   tau = Kg Km / Rm v - Kg^2 Km^2 / Rm phi'
//   y = [phi, a]
//
// Arm angle phi [rad], pendulum angle a = alpha [rad] (0 hanging down),
// motor voltage v [V]. Parameters: pendulum mass m [kg], arm length r [m],
// distance from pivot to the pendulum's centre of mass l [m]. Known
// constants: g [m/s^2], arm inertia Jb [kg m^2], motor resistance Rm [Ohm],
// motor constant Km [V s/rad = N m/A], gear ratio Kg.
//
// The paper's eq 60 prints cos(a) a'^2 where eq 55 has sin(a) a'^2; the
// dataset and this model follow eq 55 (the centripetal term is sin).
#include <riccati/model.hpp>

namespace {

struct RotaryPendulum {
  static constexpr riccati::ModelSpec<4, 3, 1, 2> spec{
      .name = "rotary_pendulum",
      .version = "1.0",
      .description = "Rotary inverted pendulum with DC motor (Zheng, Ikeda, Shimomura 2010, eqs 55-57)",
      .states = {"phi", "alpha", "dphi", "dalpha"},
      .params = {"m", "r", "l"},
      .inputs = {"v"},
      .outputs = {"phi", "alpha"},
      .theta_default = {0.05, 0.175, 0.198},
      .theta_lower = {0.0, 0.0, 0.0},
      .state_units = {"rad", "rad", "rad/s", "rad/s"},
      .param_units = {"kg", "m", "m"},
      .input_units = {"V"},
      .output_units = {"rad", "rad"},
  };

  static constexpr double kG = 9.8;
  static constexpr double kJb = 0.0122;
  static constexpr double kRm = 8.3;
  static constexpr double kKm = 0.0625;
  static constexpr double kKg = 7.5;

  template <typename T>
  void f(const T* x, const T* theta, const double* u, double /*t*/, T* dx) const {
    using namespace riccati::math;
    const T& alpha = x[1];
    const T& dphi = x[2];
    const T& dalpha = x[3];
    const T& m = theta[0];
    const T& r = theta[1];
    const T& l = theta[2];

    const T tau = kKg * kKm / kRm * u[0] - kKg * kKg * kKm * kKm / kRm * dphi;
    const T mrl = m * r * l;
    const T sin_a = sin(alpha);
    const T cos_a = cos(alpha);

    // M [phi''; a''] = rhs, M symmetric; solved by Cramer's rule.
    const T m11 = m * r * r + kJb;
    const T m12 = -mrl * cos_a;
    const T m22 = 4.0 / 3.0 * m * l * l;
    const T rhs1 = tau - mrl * sin_a * dalpha * dalpha;
    const T rhs2 = -m * kG * l * sin_a;
    const T det = m11 * m22 - m12 * m12;

    dx[0] = dphi;
    dx[1] = dalpha;
    dx[2] = (rhs1 * m22 - m12 * rhs2) / det;
    dx[3] = (m11 * rhs2 - m12 * rhs1) / det;
  }

  template <typename T>
  void g(const T* x, const T* /*theta*/, const double* /*u*/, double /*t*/, T* y) const {
    y[0] = x[0];
    y[1] = x[1];
  }
};

}  // namespace

RICCATI_MODEL_PLUGIN(RotaryPendulum)
