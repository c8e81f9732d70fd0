// A hand-written CD-EKF for the two-tank model, the baseline that both
// engine_bench (the filter step) and stream_bench (the most a single stream
// could carry if transport cost nothing) measure the engine against.
#pragma once

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <cmath>

namespace riccati::bench {

// Hand-written CD-EKFs for the two-tank model only: fixed sizes, analytic
// Jacobian, no plugin, no checks; RK4 with 10 substeps and the Joseph update,
// to measure side by side what the general plugin path costs over code
// written for one model.
//
// `structured` is the engine's algorithm, like for like: theta' = 0, so the
// integrator carries [x; Pxx; Pxtheta] (14 values) and Pthetatheta stays
// (Q = 0). `full_covariance` is the textbook form, integrating [x; P] (42
// values): what a first hand-written filter would do.
struct HandWrittenTwoTankEkf {
  using Vec2 = Eigen::Vector2d;
  using Vec6 = Eigen::Matrix<double, 6, 1>;
  using Mat6 = Eigen::Matrix<double, 6, 6>;
  using Mat24 = Eigen::Matrix<double, 2, 4>;
  using Mat26 = Eigen::Matrix<double, 2, 6>;
  Vec6 z;
  Mat6 P;
  Eigen::Matrix2d R = Eigen::Vector2d(1e-3, 1e-3).asDiagonal();

  // f and its Jacobian [Jx Jtheta] at (x, theta).
  static void model(const Vec2& x, const double* theta, const double* u, Vec2& dx, Eigen::Matrix2d& Jx, Mat24& Jt) {
    const double h1 = x[0], h2 = x[1], A1 = theta[0], A2 = theta[1], k1 = theta[2], k2 = theta[3];
    const double s1 = h1 > 0 ? std::sqrt(h1) : 0.0, s2 = h2 > 0 ? std::sqrt(h2) : 0.0;
    const double q1 = k1 * s1, q2 = k2 * s2;
    dx[0] = (u[0] - q1) / A1;
    dx[1] = (u[1] + q1 - q2) / A2;
    const double d1 = s1 > 0 ? 0.5 * k1 / s1 : 0.0, d2 = s2 > 0 ? 0.5 * k2 / s2 : 0.0;
    Jx << -d1 / A1, 0.0, d1 / A2, -d2 / A2;
    Jt << -dx[0] / A1, 0.0, -s1 / A1, 0.0, 0.0, -dx[1] / A2, s1 / A2, -s2 / A2;
  }

  // [x; Pxx; Pxtheta] with Pthetatheta constant: the engine's structure.
  struct Structured {
    Vec2 x;
    Eigen::Matrix2d Pxx;
    Mat24 Pxt;
  };
  static void rhs(const Structured& s, const double* theta, const Eigen::Matrix4d& Ptt, const double* u,
                  Structured& d) {
    Eigen::Matrix2d Jx;
    Mat24 Jt;
    model(s.x, theta, u, d.x, Jx, Jt);
    const Eigen::Matrix2d A = Jx * s.Pxx + Jt * s.Pxt.transpose();
    d.Pxx = A + A.transpose();
    d.Pxt = Jx * s.Pxt + Jt * Ptt;
  }

  void predict_structured(double dt, const double* u) {
    const int substeps = 10;
    const double h = dt / substeps;
    const Eigen::Matrix4d Ptt = P.bottomRightCorner<4, 4>();
    const double* theta = z.data() + 2;
    Structured s{z.head<2>(), P.topLeftCorner<2, 2>(), P.topRightCorner<2, 4>()};
    auto add = [](const Structured& a, double c, const Structured& b) {
      return Structured{a.x + c * b.x, a.Pxx + c * b.Pxx, a.Pxt + c * b.Pxt};
    };
    for (int i = 0; i < substeps; ++i) {
      Structured k1, k2, k3, k4;
      rhs(s, theta, Ptt, u, k1);
      rhs(add(s, 0.5 * h, k1), theta, Ptt, u, k2);
      rhs(add(s, 0.5 * h, k2), theta, Ptt, u, k3);
      rhs(add(s, h, k3), theta, Ptt, u, k4);
      s.x += h / 6.0 * (k1.x + 2.0 * (k2.x + k3.x) + k4.x);
      s.Pxx += h / 6.0 * (k1.Pxx + 2.0 * (k2.Pxx + k3.Pxx) + k4.Pxx);
      s.Pxt += h / 6.0 * (k1.Pxt + 2.0 * (k2.Pxt + k3.Pxt) + k4.Pxt);
    }
    z.head<2>() = s.x;
    P.topLeftCorner<2, 2>() = 0.5 * (s.Pxx + s.Pxx.transpose());
    P.topRightCorner<2, 4>() = s.Pxt;
    P.bottomLeftCorner<4, 2>() = s.Pxt.transpose();
  }

  // [x; P] in full, with F = [Jx Jtheta; 0 0].
  static void rhs_full(const Vec6& z, const Mat6& P, const double* u, Vec6& dz, Mat6& dP) {
    Vec2 dx;
    Eigen::Matrix2d Jx;
    Mat24 Jt;
    model(z.head<2>(), z.data() + 2, u, dx, Jx, Jt);
    dz.setZero();
    dz.head<2>() = dx;
    Mat6 F = Mat6::Zero();
    F.topLeftCorner<2, 2>() = Jx;
    F.topRightCorner<2, 4>() = Jt;
    const Mat6 FP = F * P;
    dP = FP + FP.transpose();
  }

  void predict_full(double dt, const double* u) {
    const int substeps = 10;
    const double h = dt / substeps;
    for (int s = 0; s < substeps; ++s) {
      Vec6 k1z, k2z, k3z, k4z;
      Mat6 k1P, k2P, k3P, k4P;
      rhs_full(z, P, u, k1z, k1P);
      rhs_full(z + 0.5 * h * k1z, P + 0.5 * h * k1P, u, k2z, k2P);
      rhs_full(z + 0.5 * h * k2z, P + 0.5 * h * k2P, u, k3z, k3P);
      rhs_full(z + h * k3z, P + h * k3P, u, k4z, k4P);
      z += h / 6.0 * (k1z + 2.0 * (k2z + k3z) + k4z);
      P += h / 6.0 * (k1P + 2.0 * (k2P + k3P) + k4P);
    }
    P = 0.5 * (P + P.transpose()).eval();
  }

  void update(const double* y) {
    Mat26 G = Mat26::Zero();
    G(0, 0) = 1.0;
    G(1, 1) = 1.0;
    const Eigen::Vector2d innovation(y[0] - z[0], y[1] - z[1]);
    const Eigen::Matrix<double, 6, 2> PGt = P * G.transpose();
    const Eigen::Matrix2d S = G * PGt + R;
    const Eigen::LLT<Eigen::Matrix2d> llt(S);
    const Eigen::Matrix<double, 6, 2> K = llt.solve(PGt.transpose()).transpose();
    z += K * innovation;
    const Mat6 IKG = Mat6::Identity() - K * G;
    P = IKG * P * IKG.transpose() + K * R * K.transpose();
    P = 0.5 * (P + P.transpose()).eval();
  }
};

}  // namespace riccati::bench
