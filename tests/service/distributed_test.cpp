// Several riccatid sharing one PostgreSQL database: the job queue.
//
// Three instances on loopback ports, one worker each, a 2 s lease; 30
// identification jobs (9 in the sanitized build) submitted round-robin; one
// instance killed with SIGKILL while it runs a job. Every job must end exactly once, succeeded,
// with the result of a single in-process run; the killed instance's job is
// taken over and resumes from its last completed pass. The wall time is
// printed beside that of one instance running the same jobs (the
// OneInstanceRunsTheSameJobs test), for the record; it is not asserted.
#include <gtest/gtest.h>

#include <chrono>
#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <sstream>
#include <thread>

#include "engine/identification.hpp"
#include "engine/plugin_loader.hpp"
#include "riccati/v1/datasets.grpc.pb.h"
#include "riccati/v1/jobs.grpc.pb.h"
#include "service/daemon_fixture.hpp"
#include "support/postgres.hpp"
#include "support/requests.hpp"
#include "support/two_tank_hensen.hpp"

namespace riccati {
namespace {

using testing::DaemonProcess;
using testing::PostgresSchema;
using testing::TempDir;

const std::string kData = RICCATI_TEST_DATA_DIR;
constexpr int kJobs = testing::kSanitized ? 9 : 30;  // the sanitized build runs ~40x slower

// Passes of job i: three different runs, so results cannot be mixed up.
int passes_of(int i) { return 12 + 4 * (i % 3); }

std::string read_file(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

class Cluster {
 public:
  Cluster(const TempDir& dir, const std::string& database, int instances) {
    for (int i = 0; i < instances; ++i) {
      const std::string name = "inst-" + std::to_string(i);
      auto daemon = std::make_unique<DaemonProcess>(
          dir.path() / name,
          std::vector<std::string>{"--database", database, "--workers", "1", "--instance-id", name,
                                   "--job-lease-seconds", "2", "--job-poll-ms", "100", "--log-level", "info"});
      logs_.push_back(dir.path() / (name + ".log"));
      daemon->set_log_file(logs_.back());
      daemon->start();
      jobs_.push_back(v1::JobService::NewStub(daemon->channel()));
      datasets_.push_back(v1::DatasetService::NewStub(daemon->channel()));
      daemons_.push_back(std::move(daemon));
    }
  }

  std::size_t size() const { return daemons_.size(); }
  DaemonProcess& daemon(std::size_t i) { return *daemons_[i]; }
  v1::JobService::Stub& jobs(std::size_t i) { return *jobs_[i]; }
  v1::DatasetService::Stub& datasets(std::size_t i) { return *datasets_[i]; }
  const std::filesystem::path& log(std::size_t i) const { return logs_[i]; }

  // Ids of the jobs each instance's log says it `what` ("started", "succeeded").
  std::vector<std::multiset<std::string>> logged(const std::string& what) const {
    const std::regex line("job " + what + " id=(job-[0-9a-f]+)");
    std::vector<std::multiset<std::string>> out(logs_.size());
    for (std::size_t i = 0; i < logs_.size(); ++i) {
      std::istringstream in(read_file(logs_[i]));
      std::string text;
      std::smatch m;
      while (std::getline(in, text)) {
        if (std::regex_search(text, m, line)) out[i].insert(m[1]);
      }
    }
    return out;
  }

 private:
  std::vector<std::unique_ptr<DaemonProcess>> daemons_;
  std::vector<std::unique_ptr<v1::JobService::Stub>> jobs_;
  std::vector<std::unique_ptr<v1::DatasetService::Stub>> datasets_;
  std::vector<std::filesystem::path> logs_;
};

class DistributedTest : public ::testing::Test {
 protected:
  void SetUp() override { RICCATI_SKIP_WITHOUT_POSTGRES(); }

  // The uninterrupted single run of each pass count, in this process.
  static const std::map<int, IdentificationResult>& references() {
    static const std::map<int, IdentificationResult> refs = [] {
      auto registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
      auto data = read_csv_file(kData + "/two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}}).value();
      std::map<int, IdentificationResult> out;
      for (int i = 0; i < 3; ++i) {
        out.emplace(passes_of(i),
                    identify(registry.find("two_tank"), data, testing::two_tank_hensen(FilterKind::kEkf, passes_of(i)))
                        .value());
      }
      return out;
    }();
    return refs;
  }

  static std::string upload_two_tank(v1::DatasetService::Stub& datasets) {
    v1::DatasetInfo info;
    const grpc::Status s = testing::upload_dataset(datasets, "two_tank.csv", read_file(kData + "/two_tank.csv"),
                                                   {"F1", "F2"}, {"h1", "h2"}, &info);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return info.id();
  }

  static std::vector<std::string> submit_jobs(Cluster& cluster, const std::string& dataset) {
    std::vector<std::string> ids;
    for (int i = 0; i < kJobs; ++i) {
      grpc::ClientContext ctx;
      v1::Job job;
      const grpc::Status s =
          cluster.jobs(i % cluster.size()).SubmitIdentification(&ctx, testing::hensen_spec(dataset, passes_of(i)), &job);
      EXPECT_TRUE(s.ok()) << s.error_message();
      ids.push_back(job.id());
    }
    return ids;
  }

  // Polls until every job has ended (through instance `via`); their last states.
  static std::vector<v1::Job> wait_for_all(Cluster& cluster, std::size_t via, const std::vector<std::string>& ids) {
    const auto give_up = std::chrono::steady_clock::now() + std::chrono::minutes(3);
    std::vector<v1::Job> out(ids.size());
    for (;;) {
      std::size_t ended = 0;
      for (std::size_t i = 0; i < ids.size(); ++i) {
        grpc::ClientContext ctx;
        v1::GetJobRequest get;
        get.set_id(ids[i]);
        if (cluster.jobs(via).GetJob(&ctx, get, &out[i]).ok() && out[i].state() >= v1::JOB_STATE_SUCCEEDED) ++ended;
      }
      if (ended == ids.size() || std::chrono::steady_clock::now() > give_up) return out;
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
  }

  // Every job succeeded with the single run's numbers, fetched from any instance.
  static void expect_single_run_results(Cluster& cluster, const std::vector<std::string>& ids,
                                        const std::vector<v1::Job>& ended, std::size_t first_alive) {
    for (std::size_t i = 0; i < ids.size(); ++i) {
      ASSERT_EQ(ended[i].state(), v1::JOB_STATE_SUCCEEDED) << ids[i] << ": " << ended[i].error().message();
      grpc::ClientContext ctx;
      v1::GetResultRequest get;
      get.set_job_id(ids[i]);
      v1::JobResult result;
      const std::size_t via = first_alive + i % (cluster.size() - first_alive);
      ASSERT_TRUE(cluster.jobs(via).GetResult(&ctx, get, &result).ok()) << ids[i];
      const IdentificationResult& reference = references().at(passes_of(static_cast<int>(i)));
      const auto& remote = result.identification();
      ASSERT_EQ(remote.passes_size(), passes_of(static_cast<int>(i))) << ids[i];
      for (int k = 0; k < 4; ++k) {
        EXPECT_EQ(remote.theta(k), reference.theta[k]) << ids[i] << " theta " << k;  // the same numbers
        EXPECT_EQ(remote.theta_mean(k), reference.theta_mean[k]) << ids[i] << " theta_mean " << k;
        EXPECT_EQ(remote.theta_std(k), reference.theta_std[k]) << ids[i] << " theta_std " << k;
      }
    }
  }
};

TEST_F(DistributedTest, ThreeInstancesRunThirtyJobsOnceEachThroughAKillDashNine) {
  (void)references();  // computed before the clock starts
  PostgresSchema schema;
  TempDir dir;
  Cluster cluster(dir, schema.url(), 3);
  const std::string dataset = upload_two_tank(cluster.datasets(0));

  const auto start = std::chrono::steady_clock::now();
  const std::vector<std::string> ids = submit_jobs(cluster, dataset);

  // Kill inst-0 while it holds a job with a checkpoint (a completed pass),
  // so that the job is taken over mid-run and must resume from it. inst-0
  // is frozen while the store is read: a job seen running then cannot end
  // (and its end go unlogged) between the look and the kill.
  std::string killed_job;
  for (int tries = 0; tries < 1000 && killed_job.empty(); ++tries) {
    cluster.daemon(0).freeze();
    std::this_thread::sleep_for(std::chrono::milliseconds(20));  // a commit already sent lands
    const pqxx::result r = schema.exec(
        "SELECT id FROM jobs WHERE owner = 'inst-0' AND state = 'running' AND EXISTS "
        "(SELECT 1 FROM job_passes WHERE job_passes.job_id = jobs.id) LIMIT 1");
    if (!r.empty()) {
      killed_job = r[0][0].as<std::string>();
    } else {
      cluster.daemon(0).thaw();
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
  }
  ASSERT_FALSE(killed_job.empty()) << "inst-0 never held a job with a completed pass";
  EXPECT_EQ(cluster.daemon(0).kill_now(), 128 + SIGKILL);

  const std::vector<v1::Job> ended = wait_for_all(cluster, 1, ids);
  const double wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  expect_single_run_results(cluster, ids, ended, 1);

  // Exactly once: each job succeeded in one instance's log, once.
  const auto succeeded = cluster.logged("succeeded");
  const auto started = cluster.logged("started");
  std::map<std::string, int> times_succeeded;
  for (const auto& per_instance : succeeded) {
    for (const auto& id : per_instance) ++times_succeeded[id];
  }
  for (const auto& id : ids) EXPECT_EQ(times_succeeded[id], 1) << id << " did not succeed exactly once";
  EXPECT_EQ(succeeded[0].count(killed_job), 0u);
  int starts_of_killed = 0;
  for (const auto& per_instance : started) starts_of_killed += static_cast<int>(per_instance.count(killed_job));
  EXPECT_GE(starts_of_killed, 2) << killed_job << " was not taken over";
  // The takeover resumed after the last pass inst-0 completed.
  bool resumed = false;
  for (std::size_t i = 1; i < cluster.size(); ++i) {
    resumed = resumed || read_file(cluster.log(i)).find("job resumes id=" + killed_job) != std::string::npos;
  }
  EXPECT_TRUE(resumed) << killed_job << " started over instead of resuming from its checkpoint";
  // And nothing is left held or queued.
  EXPECT_EQ(schema.exec("SELECT count(*) FROM jobs WHERE state IN ('queued', 'running')")[0][0].as<int>(), 0);
  EXPECT_EQ(schema.exec("SELECT count(*) FROM results")[0][0].as<int>(), kJobs);

  std::size_t per_instance[3] = {succeeded[0].size(), succeeded[1].size(), succeeded[2].size()};
  std::printf("[ distributed ] 3 instances x 1 worker, %d jobs, inst-0 killed: %.2f s wall; succeeded per instance "
              "%zu/%zu/%zu\n",
              kJobs, wall_s, per_instance[0], per_instance[1], per_instance[2]);
  RecordProperty("wall_seconds", std::to_string(wall_s));
}

TEST_F(DistributedTest, OneInstanceRunsTheSameJobs) {
  (void)references();
  PostgresSchema schema;
  TempDir dir;
  Cluster cluster(dir, schema.url(), 1);
  const std::string dataset = upload_two_tank(cluster.datasets(0));
  const auto start = std::chrono::steady_clock::now();
  const std::vector<std::string> ids = submit_jobs(cluster, dataset);
  const std::vector<v1::Job> ended = wait_for_all(cluster, 0, ids);
  const double wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  expect_single_run_results(cluster, ids, ended, 0);
  std::printf("[ distributed ] 1 instance x 1 worker, %d jobs: %.2f s wall\n", kJobs, wall_s);
  RecordProperty("wall_seconds", std::to_string(wall_s));
}

}  // namespace
}  // namespace riccati
