// Validation: simulate a model with given parameters over a dataset's inputs
// and compare its outputs with the measured ones (MATLAB's compare).
#pragma once

#include <functional>

#include <Eigen/Core>
#include <vector>

#include "engine/data/dataset.hpp"
#include "engine/filters/filter.hpp"
#include "engine/estimation/fit_metrics.hpp"
#include "engine/estimation/binding.hpp"
#include "engine/estimation/online_runner.hpp"
#include "engine/models/model.hpp"

namespace riccati {

struct SimulationSettings {
  HoldOrder hold = HoldOrder::kZero;
  IntegratorSettings integrator;
};

// Open-loop simulation from x0 with parameters theta over the times t [N] and
// inputs u [nu x N]: the model outputs [ny x N] (and the states, if wanted).
// `stopped`, when given, is asked before every sample: true ends the run
// with kCancelled (a call's client gone or past its deadline).
Result<Eigen::MatrixXd> simulate(const Model& model, const Eigen::VectorXd& t, const Eigen::MatrixXd& u,
                                 const Eigen::VectorXd& x0, const Eigen::VectorXd& theta,
                                 const SimulationSettings& settings, Eigen::MatrixXd* states = nullptr,
                                 const std::function<bool()>& stopped = {});

struct ValidationSettings {
  SimulationSettings simulation;
  InitialState initial_state = InitialState::kFirstMeasurement;
  Eigen::VectorXd x0;     // [nx], see InitialState
  Eigen::VectorXd theta;  // [ntheta]
};

struct ValidationResult {
  Eigen::VectorXd t;               // [N]
  Eigen::VectorXd x0;              // [nx] the initial states simulated from
  Eigen::MatrixXd y_measured;      // [ny x N]
  Eigen::MatrixXd y_simulated;     // [ny x N] simulated, or predicted `horizon` samples ahead
  std::vector<OutputFit> fits;     // one per output
  int horizon = 0;                 // 0: simulated
};

Result<ValidationResult> validate_model(const Model& model, const Dataset& data, const ValidationSettings& settings);

// k-step-ahead prediction (docs/identification.md, "Prediction"): a filter
// over the states (the parameters held) corrects its estimate with every
// measurement, and sample k is predicted from its estimate after sample
// k - K by integrating the model K samples on without the measurements in
// between, as nlgreyest's compare(data, model, K). The first K samples are
// predicted from x0, as the simulation does; K >= N is the simulation. K = 1
// gives the filter's one-step predictions, whose errors are its innovations.
struct PredictionSettings {
  int horizon = 1;        // K >= 1
  FilterSettings filter;  // the EKF or UKF: Q (the states' [nx x nx], or [nz x nz]: its states' block) and R
  Eigen::MatrixXd P0x;    // [nx x nx] the states' initial covariance; empty: 0
};
Result<ValidationResult> predict_model(ModelPtr model, const Dataset& data, const ValidationSettings& settings,
                                       const PredictionSettings& prediction);

}  // namespace riccati
