// Several riccatid sharing one PostgreSQL database: the job queue, and
// sessions resumed on another instance from their snapshots.
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
#include <cstdio>
#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <sstream>
#include <thread>

#include "engine/estimation/identification.hpp"
#include "engine/models/plugin_loader.hpp"
#include "riccati/v1/datasets.grpc.pb.h"
#include "riccati/internal/session_snapshot.pb.h"
#include "riccati/v1/jobs.grpc.pb.h"
#include "riccati/v1/sessions.grpc.pb.h"
#include "service/daemon_fixture.hpp"
#include "support/postgres.hpp"
#include "support/requests.hpp"
#include "support/two_tank_hensen.hpp"
#include "support/wait.hpp"

namespace riccati {
namespace {

using testing::DaemonProcess;
using testing::read_file;
using testing::PostgresSchema;
using testing::TempDir;

const std::string kData = RICCATI_TEST_DATA_DIR;
constexpr int kJobs = testing::kSanitized ? 9 : 30;  // the sanitized build runs ~40x slower

// Passes of job i: three different runs, so results cannot be mixed up.
int passes_of(int i) { return 12 + 4 * (i % 3); }

class Cluster {
 public:
  Cluster(const TempDir& dir, const std::string& database, int instances) {
    for (int i = 0; i < instances; ++i) {
      const std::string name = "inst-" + std::to_string(i);
      auto daemon = std::make_unique<DaemonProcess>(
          dir.path() / name,
          std::vector<std::string>{"--database", database + "&application_name=" + name, "--workers", "1",
                                   "--instance-id", name,
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
    std::vector<v1::Job> out(ids.size());
    std::size_t ended = 0;
    EXPECT_TRUE(testing::wait_until(
        [&] {
          ended = 0;
          for (std::size_t i = 0; i < ids.size(); ++i) {
            grpc::ClientContext ctx;
            v1::GetJobRequest get;
            get.set_id(ids[i]);
            if (cluster.jobs(via).GetJob(&ctx, get, &out[i]).ok() && out[i].state() >= v1::JOB_STATE_SUCCEEDED) {
              ++ended;
            }
          }
          return ended == ids.size();
        },
        std::chrono::minutes(3), "every job has ended", std::chrono::milliseconds(100)))
        << ended << " of " << ids.size() << " ended";
    return out;
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
  // (and its end go unlogged) between the look and the kill. A job's end is
  // one transaction (state and result), and its commit may have left
  // before the freeze: the store is read only once none of inst-0's
  // connections (by their application_name) is running a statement, and
  // none is in a transaction (a commit sent but not yet read), else inst-0
  // is thawed and looked at again. A statement can stay active while inst-0
  // is frozen (waiting on a row lock that another of its connections holds
  // in a transaction it cannot finish frozen): that too is a thaw and a new
  // look, not a failure.
  auto inst0_connections = [&](const std::string& states) {
    return schema.exec("SELECT count(*) FROM pg_stat_activity WHERE application_name = 'inst-0' AND state IN (" +
                       states + ")")[0][0]
        .as<int>();
  };
  std::string killed_job;
  const auto give_up = std::chrono::steady_clock::now() + std::chrono::minutes(1);
  while (killed_job.empty() && std::chrono::steady_clock::now() < give_up) {
    cluster.daemon(0).freeze();
    const bool settled = testing::wait_until([&] { return inst0_connections("'active'") == 0; },
                                             std::chrono::seconds(2),
                                             "the statements inst-0 sent before it froze have run",
                                             std::chrono::milliseconds(1));
    if (settled && inst0_connections("'idle in transaction', 'idle in transaction (aborted)'") == 0) {
      const pqxx::result r = schema.exec(
          "SELECT id FROM jobs WHERE owner = 'inst-0' AND state = 'running' AND EXISTS "
          "(SELECT 1 FROM job_passes WHERE job_passes.job_id = jobs.id) LIMIT 1");
      if (!r.empty()) killed_job = r[0][0].as<std::string>();
    }
    if (killed_job.empty()) {
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

// ---- Sessions --------------------------------------------------------------

const std::string kAlpha = "alpha-5d2e8c1f9a3b";  // tokens of two tenants
const std::string kBeta = "beta-7a1c4e9b2f6d";

// The tokens file line of `token`, from riccatid's own --hash-token.
std::string token_line(const std::string& tenant, const std::string& token) {
  const std::string command =
      "echo " + token + " | " + std::string(RICCATI_DAEMON_BIN) + " --hash-token --tenant " + tenant;
  FILE* out = popen(command.c_str(), "r");
  std::string line;
  char buffer[256];
  while (out != nullptr && std::fgets(buffer, sizeof buffer, out) != nullptr) line += buffer;
  if (out != nullptr) pclose(out);
  return line;
}

std::unique_ptr<grpc::ClientContext> as(const std::string& token) {
  auto ctx = std::make_unique<grpc::ClientContext>();
  ctx->AddMetadata("authorization", "Bearer " + token);
  ctx->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
  return ctx;
}

const Dataset& two_tank_data() {
  static const Dataset data =
      read_csv_file(kData + "/two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}}).value();
  return data;
}

// Instance A and B on one PostgreSQL, both serving tenants alpha and beta,
// a 2 s lease and a snapshot at most every second while streaming.
class SessionFailoverTest : public ::testing::Test {
 protected:
  void SetUp() override {
    RICCATI_SKIP_WITHOUT_POSTGRES();
    schema_ = std::make_unique<PostgresSchema>();
    const auto tokens = dir_.path() / "tokens";
    std::ofstream(tokens) << token_line("alpha", kAlpha) << token_line("beta", kBeta);
    for (const std::string name : {"inst-a", "inst-b"}) {
      auto daemon = std::make_unique<DaemonProcess>(
          dir_.path() / name,
          std::vector<std::string>{"--database", schema_->url(), "--instance-id", name, "--tokens-file",
                                   tokens.string(), "--job-lease-seconds", "2", "--session-snapshot-seconds", "1",
                                   "--log-level", "info"});
      logs_.push_back(dir_.path() / (name + ".log"));
      daemon->set_log_file(logs_.back());
      daemon->start();
      stubs_.push_back(v1::SessionService::NewStub(daemon->channel()));
      daemons_.push_back(std::move(daemon));
    }
  }

  DaemonProcess& a() { return *daemons_[0]; }
  v1::SessionService::Stub& on_a() { return *stubs_[0]; }
  v1::SessionService::Stub& on_b() { return *stubs_[1]; }

  static std::string create(v1::SessionService::Stub& stub) {
    v1::SessionInfo info;
    const grpc::Status s = stub.CreateSession(as(kAlpha).get(), testing::two_tank_session(), &info);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return info.id();
  }

  static grpc::Status get(v1::SessionService::Stub& stub, const std::string& id, v1::SessionInfo* info,
                          const std::string& token = kAlpha) {
    v1::GetSessionRequest request;
    request.set_id(id);
    return stub.GetSession(as(token).get(), request, info);
  }

  static std::vector<v1::SessionInfo> list(v1::SessionService::Stub& stub, const std::string& token = kAlpha) {
    v1::ListSessionsResponse response;
    const grpc::Status s = stub.ListSessions(as(token).get(), {}, &response);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return {response.sessions().begin(), response.sessions().end()};
  }

  // Streams samples [from, to) in batches of 50 and ends the stream; the
  // estimates, in order.
  static std::vector<v1::Estimate> stream(v1::SessionService::Stub& stub, const std::string& id, Eigen::Index from,
                                          Eigen::Index to) {
    auto ctx = as(kAlpha);
    return testing::stream_samples(stub, ctx.get(), id, two_tank_data(), from, to, 50);
  }

  // What an uninterrupted session estimates at every sample (on B).
  static std::vector<v1::Estimate> uninterrupted(v1::SessionService::Stub& stub) {
    return stream(stub, create(stub), 0, two_tank_data().size());
  }

  // The session's snapshot in the store (default: none yet).
  internal::SessionSnapshot stored(const std::string& id) const {
    internal::SessionSnapshot out;
    const pqxx::result r = schema_->exec("SELECT snapshot FROM session_snapshots WHERE session_id = '" + id + "'");
    if (!r.empty()) {
      EXPECT_TRUE(out.ParseFromString(pqxx::binarystring(r[0][0]).str()));
    }
    return out;
  }

  // GetSession on B until A's lease has expired (FAILED_PRECONDITION naming
  // A until then), as a client whose instance died does.
  v1::SessionInfo resume_on_b(const std::string& id) {
    v1::SessionInfo info;
    for (int attempt = 0;; ++attempt) {
      const grpc::Status s = get(on_b(), id, &info);
      if (s.ok()) return info;
      EXPECT_EQ(s.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << s.error_message();
      EXPECT_NE(s.error_message().find("inst-a"), std::string::npos) << s.error_message();
      if (attempt > 300 || s.error_code() != grpc::StatusCode::FAILED_PRECONDITION) {
        ADD_FAILURE() << "never resumed on B: " << s.error_message();
        return info;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
  }

  // Estimates of samples first, first + 1, ... equal the uninterrupted
  // session's, to the bit.
  static void expect_same(const std::vector<v1::Estimate>& got, const std::vector<v1::Estimate>& reference,
                          std::size_t first) {
    ASSERT_EQ(first + got.size(), reference.size());
    for (std::size_t i = 0; i < got.size(); ++i) {
      const v1::Estimate& e = got[i];
      const v1::Estimate& r = reference[first + i];
      ASSERT_EQ(e.t(), r.t()) << "sample " << first + i;
      ASSERT_EQ(e.state_size(), r.state_size());
      for (int j = 0; j < e.state_size(); ++j) ASSERT_EQ(e.state(j), r.state(j)) << "sample " << first + i;
      for (int j = 0; j < e.std_size(); ++j) ASSERT_EQ(e.std(j), r.std(j)) << "sample " << first + i;
      for (int j = 0; j < e.innovation_size(); ++j) {
        ASSERT_EQ(e.innovation(j), r.innovation(j)) << "sample " << first + i;
        ASSERT_EQ(e.y_predicted(j), r.y_predicted(j)) << "sample " << first + i;
      }
      ASSERT_EQ(e.nis(), r.nis()) << "sample " << first + i;
    }
  }

  std::string log_of(std::size_t i) const { return read_file(logs_[i]); }

  TempDir dir_;
  std::unique_ptr<PostgresSchema> schema_;
  std::vector<std::unique_ptr<DaemonProcess>> daemons_;
  std::vector<std::unique_ptr<v1::SessionService::Stub>> stubs_;
  std::vector<std::filesystem::path> logs_;
};

TEST_F(SessionFailoverTest, ASessionDetachedFromAKilledInstanceContinuesOnAnotherBitForBit) {
  const Dataset& data = two_tank_data();
  const std::vector<v1::Estimate> reference = uninterrupted(on_b());
  ASSERT_EQ(static_cast<Eigen::Index>(reference.size()), data.size());

  const Eigen::Index half = data.size() / 2;
  const std::string id = create(on_a());
  ASSERT_EQ(static_cast<Eigen::Index>(stream(on_a(), id, 0, half).size()), half);
  // The stream's end hands the snapshot to A's writer: wait until it is
  // stored, then kill A before anything else happens.
  for (int tries = 0; stored(id).accepted() != static_cast<std::uint64_t>(half); ++tries) {
    ASSERT_LT(tries, 1000) << "the snapshot at the stream's end was never stored";
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  EXPECT_EQ(stored(id).instance(), "inst-a");
  EXPECT_EQ(a().kill_now(), 128 + SIGKILL);

  const v1::SessionInfo info = resume_on_b(id);
  EXPECT_EQ(info.t(), data.t[half - 1]);
  EXPECT_EQ(info.measurements(), static_cast<std::uint64_t>(half));
  EXPECT_EQ(info.state(), v1::SESSION_STATE_IDLE);
  const std::vector<v1::Estimate> rest = stream(on_b(), id, half, data.size());
  expect_same(rest, reference, static_cast<std::size_t>(half));
  EXPECT_NE(log_of(1).find("session resumed id=" + id + " from_instance=inst-a"), std::string::npos) << log_of(1);
  EXPECT_EQ(stored(id).instance(), "inst-b") << "B stores it now";
}

TEST_F(SessionFailoverTest, AKillMidStreamResumesFromTheLastSnapshotAndTheClientResendsAfterT) {
  const Dataset& data = two_tank_data();
  const std::vector<v1::Estimate> reference = uninterrupted(on_b());
  const std::string id = create(on_a());

  // Stream in batches of 10 until a snapshot taken mid-stream is stored,
  // then a few batches more (within the snapshot interval: the store is
  // behind), and kill A with the stream open.
  auto ctx = as(kAlpha);
  auto rw = on_a().Stream(ctx.get());
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(id);
  ASSERT_TRUE(rw->Write(open));
  Eigen::Index sent = 0;
  int after_snapshot = -1;
  while (after_snapshot < 3) {
    ASSERT_LT(sent + 10, data.size()) << "no snapshot was stored while streaming";
    v1::StreamRequest batch;
    for (Eigen::Index k = sent; k < sent + 10; ++k) testing::add_sample(batch, data, k);
    v1::StreamResponse response;
    ASSERT_TRUE(rw->Write(batch) && rw->Read(&response));
    sent += 10;
    if (after_snapshot >= 0) {
      ++after_snapshot;
    } else if (stored(id).accepted() > 0) {
      after_snapshot = 0;
    }
  }
  EXPECT_EQ(a().kill_now(), 128 + SIGKILL);
  ctx->TryCancel();
  (void)rw->Finish();

  const v1::SessionInfo info = resume_on_b(id);
  ASSERT_GT(info.measurements(), 0u);
  ASSERT_LT(info.measurements(), static_cast<std::uint64_t>(sent)) << "the last batches came after the snapshot";
  const auto resumed_at = static_cast<Eigen::Index>(info.measurements());
  EXPECT_EQ(info.t(), data.t[resumed_at - 1]);
  // The client re-sends what came after t.
  const std::vector<v1::Estimate> rest = stream(on_b(), id, resumed_at, data.size());
  expect_same(rest, reference, static_cast<std::size_t>(resumed_at));
}

TEST_F(SessionFailoverTest, ALiveInstanceKeepsItsSessionsAndOtherTenantsSeeNone) {
  const std::string id = create(on_a());
  ASSERT_EQ(stream(on_a(), id, 0, 100).size(), 100u);

  // Both instances list the session; B as of A's snapshot at the stream's
  // end, which A stores in the background.
  std::vector<v1::SessionInfo> on_b_list;
  for (int i = 0; i < 200; ++i) {
    on_b_list = list(on_b());
    if (on_b_list.size() == 1 && on_b_list[0].measurements() == 100u) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(25));
  }
  const std::vector<v1::SessionInfo> on_a_list = list(on_a());
  ASSERT_EQ(on_b_list.size(), 1u);
  ASSERT_EQ(on_a_list.size(), 1u);
  for (const v1::SessionInfo& listed : {on_a_list[0], on_b_list[0]}) {
    EXPECT_EQ(listed.id(), id);
    EXPECT_EQ(listed.instance(), "inst-a");
    EXPECT_EQ(listed.model(), "two_tank");
    EXPECT_EQ(listed.state(), v1::SESSION_STATE_IDLE);
    EXPECT_EQ(listed.measurements(), 100u);
    EXPECT_EQ(listed.t(), two_tank_data().t[99]);
  }
  // The snapshot keeps doubles exactly.
  EXPECT_EQ(std::vector<double>(on_b_list[0].state_estimate().begin(), on_b_list[0].state_estimate().end()),
            std::vector<double>(on_a_list[0].state_estimate().begin(), on_a_list[0].state_estimate().end()));
  EXPECT_EQ(on_a_list[0].state_estimate_size(), 6);
  EXPECT_TRUE(list(on_a(), kBeta).empty());
  EXPECT_TRUE(list(on_b(), kBeta).empty());

  v1::SessionInfo info;
  grpc::Status s = get(on_b(), id, &info);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << s.error_message();
  EXPECT_NE(s.error_message().find("held by instance inst-a"), std::string::npos) << s.error_message();
  {
    auto ctx = as(kAlpha);
    auto rw = on_b().Stream(ctx.get());
    v1::StreamRequest open;
    open.mutable_open()->set_session_id(id);
    rw->Write(open);
    rw->WritesDone();
    s = rw->Finish();
    EXPECT_EQ(s.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << s.error_message();
    EXPECT_NE(s.error_message().find("inst-a"), std::string::npos) << s.error_message();
  }
  // Another tenant: no such session, on either instance, and no hint of where.
  for (auto* stub : {&on_a(), &on_b()}) {
    s = get(*stub, id, &info, kBeta);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::NOT_FOUND) << s.error_message();
    EXPECT_EQ(s.error_message().find("inst-a"), std::string::npos) << s.error_message();
  }
  // A's session is still A's, unchanged.
  ASSERT_TRUE(get(on_a(), id, &info).ok());
  EXPECT_EQ(info.measurements(), 100u);

  // A clean stop releases its sessions: no instance serves it, and B
  // resumes it at once, where A left it.
  EXPECT_EQ(a().stop(), 0) << a().exit_report();
  on_b_list = list(on_b());
  ASSERT_EQ(on_b_list.size(), 1u);
  EXPECT_EQ(on_b_list[0].instance(), "");
  s = get(on_b(), id, &info);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(info.measurements(), 100u);
  EXPECT_EQ(info.t(), two_tank_data().t[99]);
  on_b_list = list(on_b());
  ASSERT_EQ(on_b_list.size(), 1u);
  EXPECT_EQ(on_b_list[0].instance(), "inst-b");
}

}  // namespace
}  // namespace riccati
