// The on-line run of a filter over measurements that come one at a time: what
// a streaming session does with each measurement a rig sends, and what a pass
// of an identification does with each sample of a dataset (the same sequence,
// so that a stream reproduces an offline run bit for bit).
//
//   the first measurement:  the initial estimate [x0; theta0], P0 at its time
//                           (x0 given, or taken from the measurement), then
//                           an update with it;
//   every later one:        a step: the inputs held over the interval from
//                           the last measurement, a prediction to its time,
//                           an update with it.
//
// A measurement that cannot be used (sizes, a value not finite, a time not
// after the last one) is refused with kInvalidArgument and changes nothing.
// An interruption of the prediction (integrators.hpp's Interrupt: cancelled,
// a deadline, a step budget spent) is returned and changes nothing either.
// Any other failure is the filter's (or the model's): the run has diverged,
// its estimate can no longer be trusted, and every later measurement gets
// that same error. The filter is created once and steps without allocating.
#pragma once

#include <Eigen/Core>
#include <memory>
#include <span>

#include "engine/filters/filter.hpp"
#include "engine/models/model.hpp"
#include "engine/status.hpp"

namespace riccati {

// Where the initial states come from.
enum class InitialState {
  kGiven,             // x0 as given
  kFirstMeasurement,  // the toolbox's "Y(t0)": each state that has an output of
                      // the same name starts at its first measurement; the
                      // others at x0 (zero if not given)
};

// The estimate a run starts from at its first measurement.
struct InitialEstimate {
  InitialState mode = InitialState::kGiven;
  Eigen::VectorXd x0;      // [nx]; may be empty with kFirstMeasurement
  Eigen::VectorXd theta0;  // [ntheta]
  Eigen::MatrixXd P0;      // [nz x nz] covariance of [x; theta]; zero variances mean "known exactly"
};

// Sizes, finiteness and P0's semi-definiteness against the model.
Status validate(const InitialEstimate& initial, const Model& model);

// The initial states [nx] for the mode, x0 and the outputs y [ny] of the first measurement.
Result<Eigen::VectorXd> initial_state(const Model& model, InitialState mode, const Eigen::VectorXd& x0,
                                      std::span<const double> y_first);

class OnlineRunner {
 public:
  // A run of a filter of `settings` on `model` that starts from `initial`
  // (both checked here).
  static Result<OnlineRunner> create(ModelPtr model, const FilterSettings& settings, InitialEstimate initial);

  // Starts over from `initial` at the next measurement (the next pass of an
  // identification); clears a divergence.
  Status restart(InitialEstimate initial);

  // Advances the run by the measurement at time t with inputs u [nu] and
  // outputs y [ny] (see the top of this file for what the errors mean).
  Status advance(double t, std::span<const double> u, std::span<const double> y);
  // Advances to time t with the inputs u [nu] and no measurement of the
  // outputs (a sample excluded, or missing): a prediction, no update. A run
  // that starts so starts from x0 as given (InitialState::kGiven).
  Status advance_without_measurement(double t, std::span<const double> u);

  // Holds the parameters' estimate within [lower, upper] [ntheta] after every
  // measurement (empty: no bounds); parameter_bound_hits() counts, per
  // parameter, the measurements after which it was held.
  Status set_parameter_bounds(Eigen::VectorXd lower, Eigen::VectorXd upper);
  const Eigen::VectorXi& parameter_bound_hits() const { return hits_; }

  // The longest step between two measurements a run takes (seconds; 0: any).
  // A longer one (a clock's glitch: t = 1e308 after t = 3) is refused like a
  // bad measurement, changing nothing, instead of being integrated into a
  // divergence that would end the run for good.
  void set_max_time_step(double seconds) { max_time_step_ = seconds; }

  bool started() const { return started_; }
  bool diverged() const { return !divergence_.is_ok(); }
  const Status& divergence() const { return divergence_; }
  const Filter& filter() const { return *filter_; }
  // Live retuning: Filter::retune, between two measurements.
  Status retune(const FilterSettings& settings) { return filter_->retune(settings); }
  const Model& model() const { return filter_->model(); }
  const InitialEstimate& initial() const { return initial_; }

  // What a run keeps between measurements besides its settings and initial
  // estimate: a snapshot of it restores it bit for bit.
  struct Snapshot {
    bool started = false;
    double t = 0.0;
    Eigen::VectorXd z;        // [nz]
    Eigen::MatrixXd P;        // [nz x nz]
    Eigen::VectorXd carried;  // Filter::carried_state()
    Eigen::VectorXd u_last;   // [nu] the inputs of the last measurement
    Status divergence;
  };
  Snapshot snapshot() const;
  // Puts back a snapshot of a run of the same model, settings and initial estimate.
  Status restore(const Snapshot& snapshot);

 private:
  OnlineRunner(std::unique_ptr<Filter> filter, InitialEstimate initial);
  // kInvalidArgument if the measurement cannot be used; nothing is changed.
  Status check(double t, std::span<const double> u, std::span<const double> y) const;
  Status start(double t, const double* u, const double* y);

  std::unique_ptr<Filter> filter_;
  InitialEstimate initial_;
  bool started_ = false;
  double max_time_step_ = 0.0;
  Status divergence_;
  Eigen::VectorXd u_last_;  // [nu]
  Eigen::VectorXd lower_, upper_;  // [ntheta], or empty
  Eigen::VectorXi hits_;           // [ntheta], since the last (re)start
};

}  // namespace riccati
