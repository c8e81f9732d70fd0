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
  Eigen::MatrixXd y_simulated;     // [ny x N]
  std::vector<OutputFit> fits;     // one per output
};

Result<ValidationResult> validate_model(const Model& model, const Dataset& data, const ValidationSettings& settings);

}  // namespace riccati
