// How a model's inputs are held between two samples (the 1999 toolbox's
// `order`), and the held input at a time inside a sample interval: what every
// integration of a model between samples uses (the filters, simulation and
// the sensitivities of the output-error method).
#pragma once

#include <Eigen/Core>
#include <string_view>

#include "engine/status.hpp"

namespace riccati {

enum class HoldOrder {
  kZero,   // u(t) = u_k on [t_k, t_k+1)
  kFirst,  // u(t) linear from u_k to u_k+1
};

const char* hold_order_name(HoldOrder hold);                // "zoh", "foh"
Result<HoldOrder> parse_hold_order(std::string_view name);  // "zoh", "foh"

class InputHold {
 public:
  InputHold(HoldOrder order, Eigen::Index nu) : order_(order), u_(Eigen::VectorXd::Zero(nu)) {}

  // The interval [t0, t1] and the inputs [nu] at its ends (u1 is used by the
  // first-order hold only, and may be null for the zero order); the
  // pointers must stay valid while the interval is integrated.
  void set_interval(double t0, double t1, const double* u0, const double* u1) {
    t0_ = t0;
    t1_ = t1;
    u0_ = u0;
    u1_ = u1;
  }

  // The input at t inside the interval, valid until the next call.
  const double* at(double t) {
    const Eigen::Index nu = u_.size();
    if (order_ == HoldOrder::kZero || u1_ == nullptr) {
      for (Eigen::Index i = 0; i < nu; ++i) u_[i] = u0_[i];
    } else {
      const double a = (t - t0_) / (t1_ - t0_);
      for (Eigen::Index i = 0; i < nu; ++i) u_[i] = u0_[i] + a * (u1_[i] - u0_[i]);
    }
    return u_.data();
  }

  double t0() const { return t0_; }
  double t1() const { return t1_; }

 private:
  HoldOrder order_;
  Eigen::VectorXd u_;
  double t0_ = 0.0, t1_ = 1.0;
  const double* u0_ = nullptr;
  const double* u1_ = nullptr;
};

}  // namespace riccati
