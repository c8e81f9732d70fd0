// Output-error, likelihood, smoothing and validation jobs through a real
// riccatid: what a client submits reaches the engine, what it asks for
// wrongly is refused at submit naming the field, and the results are those
// of the methods (the true parameters of the reference datasets, a
// smoother closer to the truth than its filter).
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <sstream>

#include "service/daemon_fixture.hpp"
#include "support/requests.hpp"

namespace riccati {
namespace {

using testing::DaemonTest;
using testing::read_file;

const std::string kData = RICCATI_TEST_DATA_DIR;

// two_tank.json: A1, A2, k1, k2, and the noise level of two_tank_noisy.csv.
const std::vector<double> kTwoTankTruth = {10.0, 5.0, 0.0791, 0.1342};
constexpr double kNoisySigma = 0.005;

// The columns of a CSV file with a header line, by name.
std::vector<std::vector<double>> read_columns(const std::string& text, std::vector<std::string>* header) {
  std::istringstream in(text);
  std::string line;
  std::getline(in, line);
  header->clear();
  for (std::istringstream names(line); std::getline(names, line, ',');) header->push_back(line);
  std::vector<std::vector<double>> columns(header->size());
  while (std::getline(in, line)) {
    std::istringstream cells(line);
    std::string cell;
    for (std::size_t c = 0; c < columns.size() && std::getline(cells, cell, ','); ++c) columns[c].push_back(std::stod(cell));
  }
  return columns;
}

double worst_relative_error(const google::protobuf::RepeatedField<double>& theta, const std::vector<double>& truth) {
  double worst = 0.0;
  for (std::size_t i = 0; i < truth.size(); ++i) {
    worst = std::max(worst, std::abs(theta.Get(static_cast<int>(i)) - truth[i]) / std::abs(truth[i]));
  }
  return worst;
}

class EstimationJobTest : public DaemonTest {
 protected:
  std::string upload(const std::string& name, const std::string& bytes) {
    v1::DatasetInfo info;
    const grpc::Status s = DaemonTest::upload(name, bytes, {"F1", "F2"}, {"h1", "h2"}, &info);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return info.id();
  }

  // Output error from Hensen's start, the level states from the first measurement.
  static v1::IdentificationSpec output_error(const std::string& dataset_id) {
    v1::IdentificationSpec spec = hensen(dataset_id);
    spec.set_method(v1::IDENTIFICATION_METHOD_OE);
    spec.clear_passes();
    spec.clear_p0();
    spec.mutable_filter()->clear_r();
    return spec;
  }

  grpc::Status try_submit(const v1::IdentificationSpec& spec, v1::Job* job) {
    grpc::ClientContext ctx;
    return jobs_->SubmitIdentification(&ctx, spec, job);
  }

  // Submits, watches to the end (every state seen kept in `seen`), returns the result.
  v1::JobResult run(const v1::IdentificationSpec& spec, std::vector<v1::Job>* seen = nullptr) {
    const v1::Job job = submit(spec);
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(testing::kSanitized ? 600 : 120));
    v1::WatchJobRequest request;
    request.set_id(job.id());
    auto reader = jobs_->WatchJob(&ctx, request);
    v1::Job state;
    while (reader->Read(&state)) {
      if (seen != nullptr) seen->push_back(state);
    }
    EXPECT_TRUE(reader->Finish().ok());
    EXPECT_EQ(state.state(), v1::JOB_STATE_SUCCEEDED) << state.error().message();
    return result_of(job.id());
  }
};

TEST_F(EstimationJobTest, OutputErrorFindsTheTwoTankTruthFromHensensStart) {
  std::vector<v1::Job> seen;
  const v1::JobResult result = run(output_error(upload_two_tank()), &seen);
  ASSERT_TRUE(result.has_estimation());
  const v1::EstimationResult& e = result.estimation();
  EXPECT_EQ(e.method(), v1::IDENTIFICATION_METHOD_OE);
  EXPECT_TRUE(e.converged()) << e.termination();
  // The target: 1e-8 (the data are noise-free; RK4's error on them is ~1e-13).
  EXPECT_LT(worst_relative_error(e.theta(), kTwoTankTruth), 1e-8) << e.ShortDebugString().substr(0, 400);
  ASSERT_EQ(e.experiments_size(), 1);
  for (const v1::OutputFit& fit : e.experiments(0).fits()) EXPECT_GT(fit.fit_percent(), 99.9999) << fit.name();
  EXPECT_EQ(e.param_names_size(), 4);
  EXPECT_EQ(e.ci_lower_size(), 4);
  for (int i = 0; i < 4; ++i) {
    EXPECT_TRUE(std::isfinite(e.theta_std(i)));
    EXPECT_LE(e.ci_lower(i), e.theta(i));
    EXPECT_GE(e.ci_upper(i), e.theta(i));
  }
  EXPECT_GT(e.iterations(), 0u);
  EXPECT_EQ(e.cost_history_size(), static_cast<int>(e.iterations()) + 1);  // the start, then each iteration
  EXPECT_TRUE(e.experiments(0).has_diagnostics());
  // WatchJob told the optimiser's progress, the cost going down.
  double first_cost = 0.0, last_cost = 0.0;
  for (const v1::Job& s : seen) {
    if (s.progress().iteration() == 0) continue;
    if (first_cost == 0.0) first_cost = s.progress().cost();
    last_cost = s.progress().cost();
  }
  EXPECT_GT(first_cost, 0.0) << "no progress with an iteration was watched";
  EXPECT_LE(last_cost, first_cost);
  // The end shows the last iteration, not the last one the throttle let through.
  ASSERT_FALSE(seen.empty());
  EXPECT_EQ(seen.back().progress().iteration(), e.iterations());
}

// CTSM-R's method on the noisy record: the truth within the intervals the
// job reports (3 standard errors: a seeded record, so this is decided once),
// the measurement noise estimated close to the level the record was made with.
TEST_F(EstimationJobTest, MaximumLikelihoodOnTheNoisyTwoTankCoversTheTruthAndEstimatesR) {
  v1::IdentificationSpec spec = output_error(upload("two_tank_noisy.csv", read_file(kData + "/two_tank_noisy.csv")));
  spec.set_method(v1::IDENTIFICATION_METHOD_ML);
  for (double r : {1e-4, 1e-4}) spec.mutable_filter()->mutable_r()->mutable_diagonal()->add_values(r);
  spec.mutable_estimation()->set_estimate_measurement_noise(true);
  // The levels start at the first (noisy) measurement: as uncertain as it.
  for (double p : {kNoisySigma * kNoisySigma, kNoisySigma * kNoisySigma, 0.0, 0.0, 0.0, 0.0}) {
    spec.mutable_p0()->mutable_diagonal()->add_values(p);
  }
  const v1::JobResult result = run(spec);
  ASSERT_TRUE(result.has_estimation());
  const v1::EstimationResult& e = result.estimation();
  EXPECT_EQ(e.method(), v1::IDENTIFICATION_METHOD_ML);
  for (int i = 0; i < 4; ++i) {
    EXPECT_LT(std::abs(e.theta(i) - kTwoTankTruth[static_cast<std::size_t>(i)]), 3.0 * e.theta_std(i))
        << e.param_names(i) << " = " << e.theta(i) << " +- " << e.theta_std(i);
    EXPECT_LT(e.theta_std(i), 0.05 * kTwoTankTruth[static_cast<std::size_t>(i)]) << e.param_names(i);
  }
  // 4000 squared residuals: the variance's relative standard error is sqrt(2/2000) ~ 3 %.
  ASSERT_EQ(e.measurement_noise_size(), 2);
  for (double r : e.measurement_noise()) EXPECT_NEAR(r, kNoisySigma * kNoisySigma, 0.15 * kNoisySigma * kNoisySigma);
  const v1::Diagnostics& d = e.experiments(0).diagnostics();
  EXPECT_TRUE(std::isfinite(d.nis_mean()));
  EXPECT_TRUE(d.nis_consistent()) << d.summary();
}

// Bounds, a fixed parameter and a log scale reach the optimiser: k2 fixed
// at a wrong value, the others end where that forces them, within bounds.
TEST_F(EstimationJobTest, FixedParametersStayAndBoundsHold) {
  v1::IdentificationSpec spec = output_error(upload_two_tank());
  spec.set_theta0(0, 5.0);
  v1::FixedParameter* k2 = spec.add_fixed();
  k2->set_name("k2");
  k2->set_value(0.15);
  v1::ParameterBound* a1 = spec.add_bounds();
  a1->set_name("A1");
  a1->set_lower(1.0);
  a1->set_upper(9.5);  // the truth, 10, is outside: A1 ends at its bound
  spec.add_log_scale("k1");
  v1::ParameterBound* k1 = spec.add_bounds();
  k1->set_name("k1");
  k1->set_lower(1e-3);
  const v1::JobResult result = run(spec);
  const v1::EstimationResult& e = result.estimation();
  ASSERT_EQ(e.theta_size(), 4);
  EXPECT_EQ(e.theta(3), 0.15);
  EXPECT_TRUE(e.fixed(3));
  EXPECT_EQ(e.theta_std(3), 0.0);
  EXPECT_LE(e.theta(0), 9.5);
  EXPECT_NEAR(e.theta(0), 9.5, 1e-9);
  bool warned = false;
  for (const std::string& w : e.warnings()) warned |= w.find("A1") != std::string::npos;
  EXPECT_TRUE(warned) << "no warning names A1 at its bound";
}

// Two records of the same tanks (different inputs, one with noise): one
// parameter vector, each record its own initial state, estimated here.
TEST_F(EstimationJobTest, TwoExperimentsShareTheParametersAndEachFitsItsOwnInitialState) {
  v1::IdentificationSpec spec = output_error(upload_two_tank());
  spec.mutable_initial_state()->set_first_measurement(false);
  for (double v : {0.3, 0.3}) spec.mutable_initial_state()->add_x0(v);
  spec.mutable_initial_state()->add_estimate("all");
  v1::Experiment* second = spec.add_experiments();
  second->set_dataset_id(upload("two_tank_noisy.csv", read_file(kData + "/two_tank_noisy.csv")));
  second->mutable_initial_state()->set_first_measurement(true);
  const v1::JobResult result = run(spec);
  const v1::EstimationResult& e = result.estimation();
  ASSERT_EQ(e.experiments_size(), 2);
  // two_tank.json's true initial state, from 0.3: the noise-free record
  // pins it, to within what the noisy record's pull on the parameters
  // moves it (a few 1e-4).
  ASSERT_EQ(e.experiments(0).x0_size(), 2);
  EXPECT_NEAR(e.experiments(0).x0(0), 0.4, 1e-3);
  EXPECT_NEAR(e.experiments(0).x0(1), 0.15, 1e-3);
  EXPECT_TRUE(e.experiments(0).x0_estimated(0));
  EXPECT_FALSE(e.experiments(1).x0_estimated(0));
  // The noisy record pulls the estimate off the noise-free one's, but not far.
  EXPECT_LT(worst_relative_error(e.theta(), kTwoTankTruth), 0.02) << e.ShortDebugString().substr(0, 300);
  EXPECT_EQ(e.experiments(1).dataset_id(), spec.experiments(0).dataset_id());
}

// A mask leaves samples out: excluding the record's second half gives a
// result from the first half alone, the same as a trial range would.
TEST_F(EstimationJobTest, ExcludedSamplesAreLeftOut) {
  v1::IdentificationSpec spec = output_error(upload_two_tank());
  v1::SampleRange* range = spec.mutable_mask()->add_excluded();
  range->set_first(1000);
  range->set_end(2000);
  const v1::JobResult result = run(spec);
  const v1::ExperimentFit& fit = result.estimation().experiments(0);
  ASSERT_EQ(fit.mask().cols(), 2000u);
  double used = 0.0;
  for (double m : fit.mask().values()) used += m;
  EXPECT_EQ(used, 2.0 * 1000);
  EXPECT_EQ(fit.diagnostics().samples(), 1000u);
  EXPECT_LT(worst_relative_error(result.estimation().theta(), kTwoTankTruth), 1e-6);
}

// A noisy record made here from the noise-free one (whose levels are then
// the truth): the smoothed levels are closer to it than the filtered ones,
// and surer.
TEST_F(EstimationJobTest, SmoothingJobIsCloserToTheTruthThanItsFilter) {
  std::vector<std::string> header;
  const auto columns = read_columns(read_file(kData + "/two_tank.csv"), &header);
  ASSERT_EQ(header, (std::vector<std::string>{"t", "F1", "F2", "h1", "h2"}));
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, kNoisySigma);
  std::ostringstream noisy;
  noisy.precision(17);
  noisy << "t,F1,F2,h1,h2\n";
  const std::size_t N = columns[0].size();
  for (std::size_t k = 0; k < N; ++k) {
    noisy << columns[0][k] << ',' << columns[1][k] << ',' << columns[2][k] << ',' << columns[3][k] + noise(rng) << ','
          << columns[4][k] + noise(rng) << '\n';
  }
  v1::SmoothingSpec spec;
  spec.set_model("two_tank");
  spec.set_dataset_id(upload("noisy_here.csv", noisy.str()));
  spec.mutable_filter()->set_kind(v1::FILTER_KIND_EKF);
  for (double r : {kNoisySigma * kNoisySigma, kNoisySigma * kNoisySigma}) {
    spec.mutable_filter()->mutable_r()->mutable_diagonal()->add_values(r);
  }
  for (double q : {1e-8, 1e-8, 0.0, 0.0, 0.0, 0.0}) spec.mutable_filter()->mutable_q()->mutable_diagonal()->add_values(q);
  for (double x : {0.4, 0.15}) spec.mutable_initial_state()->add_x0(x);
  for (double v : kTwoTankTruth) spec.add_theta0(v);
  for (double p : {1e-4, 1e-4, 0.0, 0.0, 0.0, 0.0}) spec.mutable_p0()->mutable_diagonal()->add_values(p);
  v1::Job job;
  {
    grpc::ClientContext ctx;
    const grpc::Status s = jobs_->SubmitSmoothing(&ctx, spec, &job);
    ASSERT_TRUE(s.ok()) << s.error_message();
  }
  const v1::Job done = wait_for(job.id());
  EXPECT_EQ(done.state(), v1::JOB_STATE_SUCCEEDED);
  EXPECT_EQ(done.progress().pass_number(), 2u) << "the backward pass";
  EXPECT_EQ(done.progress().sample(), done.progress().samples());
  const v1::JobResult result = result_of(job.id());
  ASSERT_TRUE(result.has_smoothing());
  const v1::SmoothingResult& s = result.smoothing();
  ASSERT_EQ(s.names_size(), 6);
  EXPECT_EQ(s.names(0), "h1");
  EXPECT_EQ(s.names(2), "A1");
  ASSERT_EQ(s.z_smoothed().rows(), 6u);
  ASSERT_EQ(s.z_smoothed().cols(), N);
  ASSERT_EQ(s.t_size(), static_cast<int>(N));
  const auto at = [](const v1::Matrix& m, std::size_t i, std::size_t k) { return m.values(static_cast<int>(k * m.rows() + i)); };
  double filtered_sq = 0.0, smoothed_sq = 0.0;
  for (std::size_t k = 0; k < N; ++k) {
    for (std::size_t i = 0; i < 2; ++i) {
      const double truth = columns[3 + i][k];
      filtered_sq += std::pow(at(s.z_filtered(), i, k) - truth, 2);
      smoothed_sq += std::pow(at(s.z_smoothed(), i, k) - truth, 2);
      EXPECT_LE(at(s.std_smoothed(), i, k), at(s.std_filtered(), i, k) * (1 + 1e-9)) << "sample " << k;
    }
  }
  EXPECT_LT(smoothed_sq, filtered_sq);
  EXPECT_LT(std::sqrt(smoothed_sq / (2.0 * N)), kNoisySigma);  // below the measurements' own error
}

// Validation from a wrong initial state, fitted on the first 100 samples:
// the rest of the record is then simulated as well as from the true one.
TEST_F(EstimationJobTest, ValidationFitsTheInitialStateAndSaysWhereEverythingCameFrom) {
  const std::string dataset = upload_two_tank();
  v1::ValidationSpec spec;
  spec.set_model("two_tank");
  spec.set_dataset_id(dataset);
  for (double v : kTwoTankTruth) spec.mutable_theta()->add_values(v);
  for (double v : {0.2, 0.5}) spec.mutable_initial_state()->add_x0(v);
  spec.mutable_initial_state()->add_estimate("all");
  spec.set_estimate_x0_samples(100);
  v1::Job job;
  {
    grpc::ClientContext ctx;
    const grpc::Status s = jobs_->SubmitValidation(&ctx, spec, &job);
    ASSERT_TRUE(s.ok()) << s.error_message();
  }
  EXPECT_EQ(wait_for(job.id()).state(), v1::JOB_STATE_SUCCEEDED);
  const v1::ValidationResult v = result_of(job.id()).validation();
  ASSERT_EQ(v.x0_size(), 2);
  EXPECT_NEAR(v.x0(0), 0.4, 1e-6);
  EXPECT_NEAR(v.x0(1), 0.15, 1e-6);
  EXPECT_NE(v.x0_from().find("100"), std::string::npos) << v.x0_from();
  EXPECT_EQ(v.parameters_from(), "given");
  for (const v1::OutputFit& fit : v.fits()) EXPECT_GT(fit.fit_percent(), 99.99) << fit.name();

  // From an iterated-filter job: the estimate at the end of its last pass
  // when asked, the mean over it otherwise; each says which.
  const v1::Job filter_job = submit(hensen(dataset, 2));
  ASSERT_EQ(wait_for(filter_job.id()).state(), v1::JOB_STATE_SUCCEEDED);
  const v1::IdentificationResult identified = result_of(filter_job.id()).identification();
  for (const auto choice : {v1::ESTIMATE_CHOICE_FINAL, v1::ESTIMATE_CHOICE_UNSPECIFIED}) {
    v1::ValidationSpec from_job;
    from_job.set_model("two_tank");
    from_job.set_dataset_id(dataset);
    from_job.set_identification_job_id(filter_job.id());
    from_job.mutable_initial_state()->set_first_measurement(true);
    from_job.set_estimate(choice);
    grpc::ClientContext ctx;
    ASSERT_TRUE(jobs_->SubmitValidation(&ctx, from_job, &job).ok());
    ASSERT_EQ(wait_for(job.id()).state(), v1::JOB_STATE_SUCCEEDED);
    const v1::ValidationResult r = result_of(job.id()).validation();
    const auto& expected = choice == v1::ESTIMATE_CHOICE_FINAL ? identified.theta() : identified.theta_mean();
    ASSERT_EQ(r.theta_size(), 4);
    for (int i = 0; i < 4; ++i) EXPECT_EQ(r.theta(i), expected.Get(i));
    EXPECT_NE(r.parameters_from().find(filter_job.id()), std::string::npos);
    EXPECT_NE(r.parameters_from().find(choice == v1::ESTIMATE_CHOICE_FINAL ? "end of the last pass" : "mean"),
              std::string::npos)
        << r.parameters_from();
    EXPECT_EQ(r.x0_from(), "the first measurement");
  }
}

// Every new field is checked at submit: INVALID_ARGUMENT with a message
// that names what is wrong, no job made, and the daemon serving on.
TEST_F(EstimationJobTest, BadSettingsAreRefusedAtSubmitNamingTheField) {
  const std::string dataset = upload_two_tank();
  struct Case {
    std::string what;
    std::function<void(v1::IdentificationSpec&)> change;
    std::string message;  // a part of the error's message
  };
  const auto bound = [](v1::IdentificationSpec& s, const std::string& name, std::optional<double> lo,
                        std::optional<double> hi) {
    v1::ParameterBound* b = s.add_bounds();
    b->set_name(name);
    if (lo) b->set_lower(*lo);
    if (hi) b->set_upper(*hi);
  };
  const std::vector<Case> cases = {
      {"a bound on an unknown parameter", [&](auto& s) { bound(s, "A3", 0.0, 1.0); }, "no parameter \"A3\""},
      {"lower above upper", [&](auto& s) { bound(s, "A1", 30.0, 25.0); }, "A1"},
      {"theta0 outside its bounds", [&](auto& s) { bound(s, "A2", 1.0, 10.0); }, "A2"},
      {"fixing an unknown parameter",
       [](auto& s) { s.add_fixed()->set_name("k3"); },
       "no parameter \"k3\""},
      {"a log scale without a positive lower bound", [](auto& s) { s.add_log_scale("k1"); }, "k1"},
      {"a log scale on an unknown parameter", [](auto& s) { s.add_log_scale("volume"); }, "no parameter \"volume\""},
      {"an excluded range past the record",
       [](auto& s) {
         auto* r = s.mutable_mask()->add_excluded();
         r->set_first(1990);
         r->set_end(2500);
       },
       "goes past its 2000 samples"},
      {"an empty excluded range",
       [](auto& s) {
         auto* r = s.mutable_mask()->add_excluded();
         r->set_first(10);
         r->set_end(10);
       },
       "is empty"},
      {"a limit on an unknown output", [](auto& s) { s.mutable_mask()->add_limits()->set_output("h3"); },
       "no output \"h3\""},
      {"an unknown state to estimate", [](auto& s) { s.mutable_initial_state()->add_estimate("h9"); }, "no state \"h9\""},
      {"a second experiment on a dataset that does not exist",
       [](auto& s) {
         v1::Experiment* e = s.add_experiments();
         e->set_dataset_id("ds-none");
         e->mutable_initial_state()->set_first_measurement(true);
       },
       "ds-none"},
      {"noise estimation for output error",
       [](auto& s) { s.mutable_estimation()->set_estimate_measurement_noise(true); }, "estimation.estimate_measurement_noise applies to method ml only, not to oe"},
      {"init passes for the iterated filter",
       [&](auto& s) {
         s = testing::hensen_spec(dataset);
         s.set_init_passes(3);
       },
       "init_passes applies to method oe and ml only, not to filter"},
      {"a non-positive output sigma",
       [](auto& s) {
         s.mutable_estimation()->add_output_sigma(0.01);
         s.mutable_estimation()->add_output_sigma(-1.0);
       },
       "output_sigma"},
      {"an unknown method", [](auto& s) { s.set_method(static_cast<v1::IdentificationMethod>(42)); }, "method"},
  };
  for (const Case& c : cases) {
    v1::IdentificationSpec spec = output_error(dataset);
    c.change(spec);
    v1::Job job;
    const grpc::Status s = try_submit(spec, &job);
    EXPECT_TRUE(s.error_code() == grpc::StatusCode::INVALID_ARGUMENT || s.error_code() == grpc::StatusCode::NOT_FOUND)
        << c.what << ": " << s.error_code() << " " << s.error_message();
    EXPECT_NE(s.error_message().find(c.message), std::string::npos) << c.what << ": " << s.error_message();
  }
  // A validation that asks an output-error job for the iterated filter's choice of estimate.
  const v1::Job oe = submit(output_error(dataset));
  v1::ValidationSpec validation;
  validation.set_model("two_tank");
  validation.set_dataset_id(dataset);
  validation.set_identification_job_id(oe.id());
  validation.set_estimate(v1::ESTIMATE_CHOICE_FINAL);
  {
    grpc::ClientContext ctx;
    v1::Job job;
    const grpc::Status s = jobs_->SubmitValidation(&ctx, validation, &job);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
    EXPECT_NE(s.error_message().find("iterated filter"), std::string::npos) << s.error_message();
  }
  // A validation of another model with the job's estimate (the workbench's
  // Validate page did this): refused naming both models, not a FAILED job.
  validation.set_estimate(v1::ESTIMATE_CHOICE_UNSPECIFIED);
  validation.set_model("rotating_arm");
  {
    grpc::ClientContext ctx;
    v1::Job job;
    const grpc::Status s = jobs_->SubmitValidation(&ctx, validation, &job);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
    EXPECT_NE(s.error_message().find("job " + oe.id() + " identified model two_tank (A1, A2, k1, k2), not rotating_arm"),
              std::string::npos)
        << s.error_message();
  }
  {
    grpc::ClientContext ctx;
    v1::ListJobsResponse list;
    ASSERT_TRUE(jobs_->ListJobs(&ctx, {}, &list).ok());
    EXPECT_EQ(list.jobs_size(), 1) << "a refused job was made";
  }
  expect_serving();
}

}  // namespace
// A dataset whose columns do not fit the model is refused at submit by every
// kind of job, naming the model's columns and the dataset's, and no job is made.
TEST_F(EstimationJobTest, ADatasetWhoseColumnsDoNotFitTheModelIsRefusedAtSubmit) {
  const std::string bytes = read_file(kData + "/two_tank.csv");
  v1::DatasetInfo one_output, one_input;
  ASSERT_TRUE(DaemonTest::upload("one_output.csv", bytes, {"F1", "F2"}, {"h2"}, &one_output).ok());
  ASSERT_TRUE(DaemonTest::upload("one_input.csv", bytes, {"F1"}, {"h1", "h2"}, &one_input).ok());
  const std::string outputs = "model two_tank has 2 outputs (h1, h2), the dataset has 1 (h2)";
  const std::string inputs = "model two_tank has 2 inputs (F1, F2), the dataset has 1 (F1)";
  const auto expect_refused = [&](const grpc::Status& s, const std::string& what, const std::string& dataset,
                                  const std::string& message) {
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << what << ": " << s.error_message();
    EXPECT_NE(s.error_message().find(message), std::string::npos) << what << ": " << s.error_message();
    EXPECT_NE(s.error_message().find(dataset), std::string::npos) << what << ": " << s.error_message();
  };
  for (const auto& [dataset, message] : {std::pair{one_output.id(), outputs}, std::pair{one_input.id(), inputs}}) {
    v1::Job job;
    expect_refused(try_submit(testing::hensen_spec(dataset), &job), "filter", dataset, message);
    expect_refused(try_submit(output_error(dataset), &job), "oe", dataset, message);
    {
      v1::SmoothingSpec spec;
      spec.set_model("two_tank");
      spec.set_dataset_id(dataset);
      spec.mutable_filter()->mutable_r()->set_scalar(1e-3);
      spec.mutable_initial_state()->set_first_measurement(true);
      grpc::ClientContext ctx;
      expect_refused(jobs_->SubmitSmoothing(&ctx, spec, &job), "smoothing", dataset, message);
    }
    {
      v1::ValidationSpec spec;
      spec.set_model("two_tank");
      spec.set_dataset_id(dataset);
      for (double v : kTwoTankTruth) spec.mutable_theta()->add_values(v);
      spec.mutable_initial_state()->set_first_measurement(true);
      grpc::ClientContext ctx;
      expect_refused(jobs_->SubmitValidation(&ctx, spec, &job), "validation", dataset, message);
    }
  }
  // A second experiment that does not fit: named as that experiment.
  v1::IdentificationSpec two = output_error(upload_two_tank());
  v1::Experiment* second = two.add_experiments();
  second->set_dataset_id(one_output.id());
  second->mutable_initial_state()->set_first_measurement(true);
  v1::Job job;
  expect_refused(try_submit(two, &job), "experiment 2", "experiment 2 (" + one_output.id() + ")", outputs);
  grpc::ClientContext ctx;
  v1::ListJobsResponse list;
  ASSERT_TRUE(jobs_->ListJobs(&ctx, {}, &list).ok());
  EXPECT_EQ(list.jobs_size(), 0) << "a refused job was made";
}

}  // namespace riccati
