// The Store contract, run against every implementation: SQLite, and
// PostgreSQL on the server of RICCATI_TEST_POSTGRES_URL (skipped without
// one, unless RICCATI_REQUIRE_POSTGRES=1; scripts/with-postgres.sh runs a
// command beside a throw-away server).
#include <gtest/gtest.h>

#include <algorithm>

#include <cmath>
#include <filesystem>
#include <functional>
#include <limits>
#include <atomic>
#include <bit>
#include <chrono>
#include <cstring>
#include <latch>
#include <random>
#include <set>
#include <thread>

#include <sqlite3.h>

#include "store/postgres_store.hpp"
#include "store/store.hpp"
#include "support/manual_clock.hpp"
#include "support/postgres.hpp"

namespace riccati {
namespace {

class TempDir {
 public:
  TempDir() {
    std::string tmpl = (std::filesystem::temp_directory_path() / "riccati-store-XXXXXX").string();
    path_ = mkdtemp(tmpl.data());
  }
  ~TempDir() { std::filesystem::remove_all(path_); }
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

using testing::PostgresSchema;
using namespace std::chrono_literals;

// Where a test keeps its store: made for the test, removed after it.
class StorePlace {
 public:
  virtual ~StorePlace() = default;
  // Opens the store kept here (every open finds the same data).
  virtual Result<std::unique_ptr<Store>> open(std::shared_ptr<StoreClock> clock) = 0;
};

class SqlitePlace final : public StorePlace {
 public:
  Result<std::unique_ptr<Store>> open(std::shared_ptr<StoreClock> clock) override {
    return open_sqlite_store((dir_.path() / "riccati.db").string(), std::move(clock));
  }

 private:
  TempDir dir_;
};

class PostgresPlace final : public StorePlace {
 public:
  Result<std::unique_ptr<Store>> open(std::shared_ptr<StoreClock> clock) override {
    return open_postgres_store(schema_.url(), std::move(clock));
  }

 private:
  PostgresSchema schema_;
};

struct StoreKind {
  const char* name;
  bool needs_postgres;
  std::function<std::unique_ptr<StorePlace>()> make_place;
};

// For test names and messages: the kind, not the struct's bytes.
void PrintTo(const StoreKind& kind, std::ostream* out) { *out << kind.name; }

class StoreTest : public ::testing::TestWithParam<StoreKind> {
 protected:
  void SetUp() override {
    if (GetParam().needs_postgres) RICCATI_SKIP_WITHOUT_POSTGRES();
    place_ = GetParam().make_place();
  }

  // The store on the test's clock: leases expire when the test advances it.
  std::unique_ptr<Store> open() {
    auto s = place_->open(clock_);
    EXPECT_TRUE(s.is_ok()) << s.status().to_string();
    return std::move(s).value();
  }

  static Dataset random_dataset(int n, unsigned seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> uniform(-1.0, 1.0);
    Dataset d;
    d.name = "random.csv";
    d.input_names = {"u1", "u2"};
    d.output_names = {"y"};
    d.t.resize(n);
    d.u.resize(2, n);
    d.y.resize(1, n);
    for (int k = 0; k < n; ++k) {
      d.t[k] = 0.001 * k;
      d.u(0, k) = uniform(rng) * 1e300;
      d.u(1, k) = uniform(rng) * 1e-300;
      d.y(0, k) = uniform(rng);
    }
    d.y(0, 0) = -0.0;  // the sign of zero survives too
    return d;
  }

  static DatasetRecord record_for(const std::string& id, const std::string& tenant, const Dataset& d,
                                  std::int64_t created) {
    DatasetRecord r;
    r.id = id;
    r.tenant = tenant;
    r.name = d.name;
    r.format = "csv";
    r.input_names = d.input_names;
    r.output_names = d.output_names;
    r.samples = d.size();
    r.t_start = d.t[0];
    r.t_end = d.t[d.size() - 1];
    r.size_bytes = 1234;
    r.created_ms = created;
    return r;
  }

  static JobRecord job(const std::string& id, const std::string& tenant, std::int64_t created) {
    JobRecord j;
    j.id = id;
    j.tenant = tenant;
    j.kind = JobKind::kIdentification;
    j.spec = std::string("\x00\x01spec", 6);  // binary-safe
    j.passes = 10;
    j.samples = 2000;
    j.created_ms = created;
    return j;
  }

  std::unique_ptr<StorePlace> place_;
  std::shared_ptr<testing::ManualClock> clock_ = std::make_shared<testing::ManualClock>();
};

TEST_P(StoreTest, DatasetRoundTripIsBitExact) {
  auto store = open();
  const Dataset d = random_dataset(500, 1);
  DatasetRecord record = record_for("ds-1", "alice", d, 10);
  record.sha256 = std::string(64, 'a');
  // Declared true parameters come back to the bit (0.1 and 1/3 have no short form).
  record.true_parameters = {{"A1", 10.0}, {"k_1", 0.1}, {"third", 1.0 / 3.0}, {"tiny", -4.9e-324}};
  ASSERT_TRUE(store->put_dataset(record, d).is_ok());
  auto loaded = store->load_dataset("alice", "ds-1");
  ASSERT_TRUE(loaded.is_ok()) << loaded.status().to_string();
  EXPECT_EQ(std::memcmp(loaded.value().u.data(), d.u.data(), sizeof(double) * d.u.size()), 0);
  EXPECT_EQ(std::memcmp(loaded.value().y.data(), d.y.data(), sizeof(double) * d.y.size()), 0);
  EXPECT_EQ(std::memcmp(loaded.value().t.data(), d.t.data(), sizeof(double) * d.t.size()), 0);
  EXPECT_TRUE(std::signbit(loaded.value().y(0, 0)));
  EXPECT_EQ(loaded.value().input_names, d.input_names);
  auto rec = store->get_dataset("alice", "ds-1");
  ASSERT_TRUE(rec.is_ok());
  EXPECT_EQ(rec.value().samples, 500);
  EXPECT_EQ(rec.value().output_names, std::vector<std::string>{"y"});
  EXPECT_EQ(std::bit_cast<std::uint64_t>(rec.value().t_end), std::bit_cast<std::uint64_t>(d.t[499]));
  EXPECT_EQ(rec.value().sha256, std::string(64, 'a'));
  EXPECT_EQ(store->list_datasets("alice").value().at(0).sha256, std::string(64, 'a'));
  EXPECT_EQ(rec.value().true_parameters, record.true_parameters);
  EXPECT_EQ(store->list_datasets("alice").value().at(0).true_parameters, record.true_parameters);
  ASSERT_TRUE(store->put_dataset(record_for("ds-2", "alice", d, 11), d).is_ok());
  EXPECT_TRUE(store->get_dataset("alice", "ds-2").value().true_parameters.empty());
}

TEST_P(StoreTest, NamesAndMetadataSurviveAnyCharacters) {
  auto store = open();
  Dataset d = random_dataset(3, 5);
  d.input_names = {"a,b", "q\"uote", "back\\slash"};
  d.output_names = {"NULL", "{brace} sp ace", "\u00fcnic\u00f6de", "'single'", "", "trailing\\"};
  d.u.resize(3, 3);
  d.u.setConstant(0.1);
  d.y.resize(6, 3);
  d.y.setConstant(1.0 / 3.0);
  DatasetRecord r = record_for("ds-odd", "tenant with spaces", d, 1);
  r.name = "file \"name\".csv";
  r.t_start = 0.1 + 0.2;  // 0.30000000000000004: every bit kept
  ASSERT_TRUE(store->put_dataset(r, d).is_ok());
  const DatasetRecord back = store->get_dataset("tenant with spaces", "ds-odd").value();
  EXPECT_EQ(back.input_names, d.input_names);
  EXPECT_EQ(back.output_names, d.output_names);
  EXPECT_EQ(back.name, r.name);
  EXPECT_EQ(back.t_start, 0.1 + 0.2);
  const Dataset loaded = store->load_dataset("tenant with spaces", "ds-odd").value();
  EXPECT_EQ(loaded.output_names, d.output_names);
  EXPECT_EQ(loaded.y, d.y);
  EXPECT_EQ(store->list_datasets("tenant with spaces").value().size(), 1u);
}

TEST_P(StoreTest, TenantsSeeOnlyTheirOwnRecords) {
  auto store = open();
  const Dataset d = random_dataset(10, 2);
  ASSERT_TRUE(store->put_dataset(record_for("ds-a", "alice", d, 1), d).is_ok());
  ASSERT_TRUE(store->put_job(job("job-a", "alice", 1)).is_ok());
  ASSERT_TRUE(store->put_result("alice", "job-a", "result").is_ok());
  ASSERT_TRUE(store->put_session_snapshot("alice", "ses-a", "inst-1", 60000, "snap").is_ok());

  EXPECT_EQ(store->get_dataset("bob", "ds-a").status().code(), StatusCode::kNotFound);
  EXPECT_EQ(store->load_dataset("bob", "ds-a").status().code(), StatusCode::kNotFound);
  EXPECT_TRUE(store->list_datasets("bob").value().empty());
  EXPECT_EQ(store->delete_dataset("bob", "ds-a").code(), StatusCode::kNotFound);
  EXPECT_EQ(store->get_job("bob", "job-a").status().code(), StatusCode::kNotFound);
  EXPECT_TRUE(store->list_jobs("bob").value().empty());
  JobRecord stolen = job("job-a", "bob", 1);
  stolen.state = JobState::kCancelled;
  EXPECT_EQ(store->update_job(stolen).code(), StatusCode::kNotFound);
  EXPECT_EQ(store->get_result("bob", "job-a").status().code(), StatusCode::kNotFound);
  // Not even the instance holding it is revealed to another tenant.
  EXPECT_EQ(store->claim_session_snapshot("bob", "ses-a", "inst-2", 60000).status().code(), StatusCode::kNotFound);
  EXPECT_EQ(store->claim_session_snapshot("bob", "ses-a", "inst-2", 60000).status().message(), "no session ses-a");
  EXPECT_EQ(store->put_session_snapshot("bob", "ses-a", "inst-1", 60000, "overwrite").code(), StatusCode::kNotFound);
  EXPECT_EQ(store->delete_session_snapshot("bob", "ses-a", "inst-1").code(), StatusCode::kNotFound);
  EXPECT_TRUE(store->list_session_snapshots("bob").value().empty());
  EXPECT_EQ(store->put_result("bob", "job-a", "theirs").code(), StatusCode::kNotFound);
  // Another tenant's id reads exactly as a missing one: no hint that it exists.
  EXPECT_EQ(store->get_job("bob", "job-a").status().message(), "no job job-a");
  // Alice still has everything, unchanged.
  EXPECT_EQ(store->get_job("alice", "job-a").value().state, JobState::kQueued);
  EXPECT_EQ(store->claim_session_snapshot("alice", "ses-a", "inst-1", 60000).value(), "snap");
}

// Text models: every upload of a name is its next revision; a deleted name
// is hidden but its revisions stay readable for the jobs that name them;
// another tenant sees none of it.
TEST_P(StoreTest, TextModelsKeepEveryRevisionPerTenant) {
  auto store = open();
  auto model = [](const std::string& tenant, const std::string& name, const std::string& source) {
    ModelRecord m;
    m.tenant = tenant;
    m.name = name;
    m.source = source;
    m.sha256 = std::string(64, 'a');
    m.created_ms = 5;
    return m;
  };
  const std::string binary("model: m\0\xff", 11);  // bytes, whatever they are
  EXPECT_EQ(store->put_model(model("alice", "tank", "v1")).value().revision, 1);
  EXPECT_EQ(store->put_model(model("alice", "tank", binary)).value().revision, 2);
  EXPECT_EQ(store->put_model(model("alice", "arm", "a1")).value().revision, 1);
  EXPECT_EQ(store->put_model(model("bob", "tank", "b1")).value().revision, 1);
  EXPECT_EQ(store->get_model("alice", "tank", 0).value().source, binary);
  EXPECT_EQ(store->get_model("alice", "tank", 0).value().revision, 2);
  EXPECT_EQ(store->get_model("alice", "tank", 1).value().source, "v1");
  EXPECT_EQ(store->get_model("bob", "tank", 0).value().source, "b1");
  EXPECT_EQ(store->get_model("bob", "arm", 0).status().code(), StatusCode::kNotFound);
  EXPECT_EQ(store->get_model("bob", "tank", 2).status().code(), StatusCode::kNotFound);
  auto listed = store->list_models("alice").value();
  ASSERT_EQ(listed.size(), 2u);
  EXPECT_EQ(listed[0].name, "arm");
  EXPECT_EQ(listed[1].name, "tank");
  EXPECT_EQ(listed[1].revision, 2);
  EXPECT_EQ(listed[1].sha256, std::string(64, 'a'));

  EXPECT_EQ(store->delete_model("bob", "arm").code(), StatusCode::kNotFound);
  ASSERT_TRUE(store->delete_model("alice", "tank").is_ok());
  EXPECT_EQ(store->delete_model("alice", "tank").code(), StatusCode::kNotFound);
  EXPECT_EQ(store->get_model("alice", "tank", 0).status().code(), StatusCode::kNotFound);
  EXPECT_TRUE(store->get_model("alice", "tank", 2).value().deleted);
  EXPECT_EQ(store->list_models("alice").value().size(), 1u);
  EXPECT_EQ(store->get_model("bob", "tank", 0).value().revision, 1);
  // Uploaded again, the name continues its count: tank@2 stays what it was.
  EXPECT_EQ(store->put_model(model("alice", "tank", "v3")).value().revision, 3);
  EXPECT_EQ(store->get_model("alice", "tank", 0).value().source, "v3");
  EXPECT_EQ(store->get_model("alice", "tank", 2).value().source, binary);
  // The revisions not deleted, with their sizes: arm@1, then tank@3 alone.
  const auto revisions = store->list_model_revisions("alice").value();
  ASSERT_EQ(revisions.size(), 2u);
  EXPECT_EQ(revisions[0].name, "arm");
  EXPECT_EQ(revisions[0].revision, 1);
  EXPECT_EQ(revisions[0].source_bytes, 2);
  EXPECT_EQ(revisions[1].name, "tank");
  EXPECT_EQ(revisions[1].revision, 3);
  EXPECT_EQ(revisions[1].source_bytes, 2);
  ASSERT_TRUE(store->put_model(model("alice", "tank", binary)).is_ok());
  const auto more = store->list_model_revisions("alice").value();
  ASSERT_EQ(more.size(), 3u);
  EXPECT_EQ(more[2].revision, 4);
  EXPECT_EQ(more[2].source_bytes, 11);  // bytes, NUL included
  EXPECT_TRUE(store->list_model_revisions("carol").value().empty());
}

TEST_P(StoreTest, DuplicatesAndMissingRecords) {
  auto store = open();
  const Dataset d = random_dataset(10, 3);
  ASSERT_TRUE(store->put_dataset(record_for("ds-1", "t", d, 1), d).is_ok());
  EXPECT_EQ(store->put_dataset(record_for("ds-1", "t", d, 2), d).code(), StatusCode::kAlreadyExists);
  ASSERT_TRUE(store->put_job(job("job-1", "t", 1)).is_ok());
  EXPECT_EQ(store->put_job(job("job-1", "t", 2)).code(), StatusCode::kAlreadyExists);
  ASSERT_TRUE(store->put_result("t", "job-1", "first").is_ok());
  EXPECT_EQ(store->put_result("t", "job-1", "second").code(), StatusCode::kAlreadyExists);
  EXPECT_EQ(store->get_result("t", "job-1").value(), "first");
  EXPECT_EQ(store->put_result("t", "job-2", "no job").code(), StatusCode::kNotFound);
  EXPECT_EQ(store->update_job(job("job-2", "t", 1)).code(), StatusCode::kNotFound);
  EXPECT_EQ(store->delete_dataset("t", "ds-2").code(), StatusCode::kNotFound);
  ASSERT_TRUE(store->delete_dataset("t", "ds-1").is_ok());
  EXPECT_EQ(store->load_dataset("t", "ds-1").status().code(), StatusCode::kNotFound);
}

TEST_P(StoreTest, JobsUpdateListAndUnfinishedStates) {
  auto store = open();
  for (int i = 0; i < 4; ++i) ASSERT_TRUE(store->put_job(job("job-" + std::to_string(i), i % 2 ? "a" : "b", 100 - i)).is_ok());
  JobRecord j = store->get_job("b", "job-0").value();
  j.state = JobState::kRunning;
  j.pass = 3;
  j.sample = 17;
  j.theta = {1.5, -2.5};
  j.started_ms = 5;
  j.iteration = 12;
  j.cost = 0.1 + 1e-17;  // a double kept exactly
  ASSERT_TRUE(store->update_job(j).is_ok());
  JobRecord done = store->get_job("a", "job-1").value();
  done.state = JobState::kFailed;
  done.error_code = 9;
  done.error_message = "diverged";
  ASSERT_TRUE(store->update_job(done).is_ok());

  const JobRecord back = store->get_job("b", "job-0").value();
  EXPECT_EQ(back.state, JobState::kRunning);
  EXPECT_EQ(back.pass, 3);
  EXPECT_EQ(back.theta, (std::vector<double>{1.5, -2.5}));
  EXPECT_EQ(back.iteration, 12);
  EXPECT_EQ(back.cost, j.cost);
  EXPECT_EQ(back.spec, j.spec);
  EXPECT_EQ(store->get_job("a", "job-1").value().error_message, "diverged");

  const auto unfinished = store->jobs_in_states({JobState::kQueued, JobState::kRunning}).value();
  std::vector<std::string> ids;
  for (const auto& u : unfinished) ids.push_back(u.id);
  EXPECT_EQ(ids, (std::vector<std::string>{"job-3", "job-2", "job-0"}));  // oldest first, every tenant
  const auto listed = store->list_jobs("a").value();
  ASSERT_EQ(listed.size(), 2u);
  EXPECT_EQ(listed[0].id, "job-3");
  // Counted as listed, without reading a spec: job-2 and job-3 queued (b, a),
  // job-0 running (b), job-1 failed.
  const UnfinishedJobs counts = store->count_unfinished_jobs("b").value();
  EXPECT_EQ(counts.queued, 2);
  EXPECT_EQ(counts.running, 1);
  EXPECT_EQ(counts.of_tenant, 2);
  EXPECT_EQ(store->count_unfinished_jobs("a").value().of_tenant, 1);
  EXPECT_EQ(store->count_unfinished_jobs("nobody").value().of_tenant, 0);
  // The pinned model a job names is kept.
  JobRecord pinned = job("job-9", "a", 200);
  pinned.model = "tank@3";
  ASSERT_TRUE(store->put_job(pinned).is_ok());
  EXPECT_EQ(store->get_job("a", "job-9").value().model, "tank@3");
}

TEST_P(StoreTest, AResultsSizeIsReadWithoutTheResult) {
  auto store = open();
  ASSERT_TRUE(store->put_job(job("job-1", "t", 1)).is_ok());
  EXPECT_EQ(store->result_size("t", "job-1").status().code(), StatusCode::kNotFound);
  ASSERT_TRUE(store->put_result("t", "job-1", std::string(12345, '\0')).is_ok());
  EXPECT_EQ(store->result_size("t", "job-1").value(), 12345);
  EXPECT_EQ(store->result_size("u", "job-1").status().code(), StatusCode::kNotFound) << "another tenant's";
}

// A deleted model's revisions go once no queued or running job names them;
// the name's newest stays, emptied, so that its number is not given again.
TEST_P(StoreTest, DeletedModelsArePurgedUnlessAJobThatMayRunNamesThem) {
  auto store = open();
  auto model = [](const std::string& tenant, const std::string& name, const std::string& source) {
    ModelRecord m;
    m.tenant = tenant;
    m.name = name;
    m.source = source;
    m.sha256 = std::string(64, 'a');
    return m;
  };
  for (const char* source : {"v1", "v2", "v3"}) ASSERT_TRUE(store->put_model(model("t", "tank", source)).is_ok());
  ASSERT_TRUE(store->put_model(model("t", "arm", "a1")).is_ok());
  ASSERT_TRUE(store->put_model(model("u", "tank", "other")).is_ok());
  JobRecord queued = job("job-1", "t", 1);
  queued.model = "tank@2";
  ASSERT_TRUE(store->put_job(queued).is_ok());
  ASSERT_TRUE(store->delete_model("t", "tank").is_ok());
  // tank@1 deleted; tank@2 kept (job-1 may run on it); tank@3 emptied (the newest).
  EXPECT_EQ(store->purge_unused_models().value(), 2);
  EXPECT_EQ(store->get_model("t", "tank", 1).status().code(), StatusCode::kNotFound);
  EXPECT_EQ(store->get_model("t", "tank", 2).value().source, "v2");
  EXPECT_EQ(store->get_model("t", "tank", 3).value().source, "");
  EXPECT_EQ(store->get_model("t", "arm", 0).value().source, "a1") << "a model not deleted is left alone";
  EXPECT_EQ(store->get_model("u", "tank", 0).value().source, "other") << "another tenant's is left alone";
  // The job ends: tank@2 goes too.
  JobRecord ended = store->get_job("t", "job-1").value();
  ended.state = JobState::kSucceeded;
  ASSERT_TRUE(store->update_job(ended).is_ok());
  EXPECT_EQ(store->purge_unused_models().value(), 1);
  EXPECT_EQ(store->get_model("t", "tank", 2).status().code(), StatusCode::kNotFound);
  EXPECT_EQ(store->put_model(model("t", "tank", "v4")).value().revision, 4);
  // The emptied tank@3 goes: tank@4 keeps the count now.
  EXPECT_EQ(store->purge_unused_models().value(), 1);
  EXPECT_EQ(store->get_model("t", "tank", 3).status().code(), StatusCode::kNotFound);
  EXPECT_EQ(store->purge_unused_models().value(), 0);
}

TEST_P(StoreTest, JobPassRecordsComeBackInPassOrderAndBelongToTheJobsTenant) {
  auto store = open();
  ASSERT_TRUE(store->put_job(job("job-1", "a", 1)).is_ok());
  EXPECT_TRUE(store->list_job_passes("a", "job-1").value().empty());
  for (int pass : {2, 1, 10}) {  // out of order; 10 after 2 (not "10" < "2")
    ASSERT_TRUE(store->put_job_pass("a", "job-1", pass, std::string("\x00pass ", 6) + std::to_string(pass)).is_ok());
  }
  ASSERT_TRUE(store->put_job_pass("a", "job-1", 2, std::string("\x00again", 6)).is_ok());  // replaces
  EXPECT_EQ(store->list_job_passes("a", "job-1").value(),
            (std::vector<std::string>{std::string("\x00pass 1", 7), std::string("\x00again", 6),
                                      std::string("\x00pass 10", 8)}));
  // Another tenant can neither read nor write them; no records without the job.
  EXPECT_TRUE(store->list_job_passes("b", "job-1").value().empty());
  EXPECT_EQ(store->put_job_pass("b", "job-1", 3, "theirs").code(), StatusCode::kNotFound);
  EXPECT_EQ(store->put_job_pass("a", "job-2", 1, "none").code(), StatusCode::kNotFound);
  EXPECT_EQ(store->list_job_passes("a", "job-1").value().size(), 3u);
}

TEST_P(StoreTest, AnEndedJobIsDeletedWithItsResultAndPassesAndARunningOneIsNot) {
  auto store = open();
  for (const char* id : {"job-1", "job-2"}) ASSERT_TRUE(store->put_job(job(id, "a", 1)).is_ok());
  JobRecord ended = store->get_job("a", "job-1").value();
  ended.state = JobState::kSucceeded;
  ended.finished_ms = 10;
  ASSERT_TRUE(store->update_job(ended).is_ok());
  ASSERT_TRUE(store->put_result("a", "job-1", std::string(1000, 'r')).is_ok());
  ASSERT_TRUE(store->put_job_pass("a", "job-1", 1, "p").is_ok());
  EXPECT_EQ(store->result_bytes("a").value(), 1000);
  EXPECT_EQ(store->result_bytes("b").value(), 0);
  EXPECT_EQ(store->usage().value().result_bytes, 1000);

  EXPECT_EQ(store->delete_job("b", "job-1").code(), StatusCode::kNotFound);  // another tenant's
  const Status queued = store->delete_job("a", "job-2");
  EXPECT_EQ(queued.code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(queued.message().find("job-2 is queued"), std::string::npos) << queued.message();
  ASSERT_TRUE(store->delete_job("a", "job-1").is_ok());
  EXPECT_EQ(store->get_job("a", "job-1").status().code(), StatusCode::kNotFound);
  EXPECT_EQ(store->get_result("a", "job-1").status().code(), StatusCode::kNotFound);
  EXPECT_TRUE(store->list_job_passes("a", "job-1").value().empty());
  EXPECT_EQ(store->result_bytes("a").value(), 0);
  EXPECT_EQ(store->delete_job("a", "job-1").code(), StatusCode::kNotFound);
  EXPECT_TRUE(store->get_job("a", "job-2").is_ok());
}

TEST_P(StoreTest, RetentionDeletesEndedJobsByAgeAndKeepsTheNewestOfEachTenant) {
  auto store = open();
  // Tenant a: five ended jobs finished at 10..50 and one running; tenant b: two ended.
  auto end = [&](const std::string& id, const std::string& tenant, std::int64_t finished, JobState state) {
    ASSERT_TRUE(store->put_job(job(id, tenant, finished)).is_ok());
    JobRecord j = store->get_job(tenant, id).value();
    j.state = state;
    j.finished_ms = finished;
    ASSERT_TRUE(store->update_job(j).is_ok());
    if (state == JobState::kSucceeded) {
      ASSERT_TRUE(store->put_result(tenant, id, "r").is_ok());
    }
  };
  for (int i = 1; i <= 5; ++i) end("a-" + std::to_string(i), "a", 10 * i, i % 2 ? JobState::kSucceeded : JobState::kFailed);
  end("a-run", "a", 0, JobState::kRunning);
  end("b-1", "b", 15, JobState::kCancelled);
  end("b-2", "b", 25, JobState::kSucceeded);
  auto ids = [&](const std::string& tenant) {
    std::vector<std::string> out;
    const std::vector<JobRecord> jobs = store->list_jobs(tenant).value();
    for (const JobRecord& j : jobs) out.push_back(j.id);
    std::sort(out.begin(), out.end());
    return out;
  };
  // Nothing is old enough and every tenant has fewer than 10.
  EXPECT_EQ(store->delete_ended_jobs(0, 10).value(), 0);
  // By count: the newest three ended jobs of each tenant stay; a running job is never deleted.
  EXPECT_EQ(store->delete_ended_jobs(0, 3).value(), 2);
  EXPECT_EQ(ids("a"), (std::vector<std::string>{"a-3", "a-4", "a-5", "a-run"}));
  EXPECT_EQ(ids("b"), (std::vector<std::string>{"b-1", "b-2"}));
  // By age: those that finished before 40.
  EXPECT_EQ(store->delete_ended_jobs(40, 100).value(), 3);
  EXPECT_EQ(ids("a"), (std::vector<std::string>{"a-4", "a-5", "a-run"}));
  EXPECT_TRUE(ids("b").empty());
  EXPECT_EQ(store->get_result("b", "b-2").status().code(), StatusCode::kNotFound);
}

TEST_P(StoreTest, UsageCountsDatasetsResultsAndTheDatabase) {
  auto store = open();
  const StoreUsage empty = store->usage().value();
  EXPECT_EQ(empty.dataset_bytes, 0);
  EXPECT_EQ(empty.result_bytes, 0);
  EXPECT_GT(empty.database_bytes, 0);
  const Dataset d = random_dataset(20000, 4);
  ASSERT_TRUE(store->put_dataset(record_for("ds-1", "t", d, 1), d).is_ok());
  ASSERT_TRUE(store->put_job(job("job-1", "t", 1)).is_ok());
  ASSERT_TRUE(store->put_result("t", "job-1", std::string(300'000, 'r')).is_ok());
  const StoreUsage used = store->usage().value();
  EXPECT_EQ(used.dataset_bytes, 1234);  // as uploaded (record_for's size_bytes)
  EXPECT_EQ(used.result_bytes, 300'000);
  // The samples and the result take room in the database itself.
  EXPECT_GT(used.database_bytes, empty.database_bytes + 300'000);
}

TEST_P(StoreTest, ReopeningFindsEverything) {
  const Dataset d = random_dataset(20, 4);
  {
    auto store = open();
    ASSERT_TRUE(store->put_dataset(record_for("ds-1", "t", d, 1), d).is_ok());
    ASSERT_TRUE(store->put_job(job("job-1", "t", 1)).is_ok());
    ASSERT_TRUE(store->put_result("t", "job-1", "r").is_ok());
    ASSERT_TRUE(store->put_job_pass("t", "job-1", 1, "c").is_ok());
  }
  auto store = open();
  EXPECT_TRUE(store->load_dataset("t", "ds-1").value().y.isApprox(d.y));
  EXPECT_EQ(store->get_job("t", "job-1").value().kind, JobKind::kIdentification);
  EXPECT_EQ(store->get_result("t", "job-1").value(), "r");
  EXPECT_EQ(store->list_job_passes("t", "job-1").value(), std::vector<std::string>{"c"});
}

TEST_P(StoreTest, ConcurrentWritersAndReaders) {
  auto store = open();
  std::vector<std::thread> threads;
  std::atomic<int> failures{0};
  for (int w = 0; w < 4; ++w) {
    threads.emplace_back([&, w] {
      for (int i = 0; i < 50; ++i) {
        const std::string id = "job-" + std::to_string(w) + "-" + std::to_string(i);
        if (!store->put_job(job(id, "t", i)).is_ok()) ++failures;
        if (!store->get_job("t", id).is_ok()) ++failures;
        if (!store->list_jobs("t").is_ok()) ++failures;
      }
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(failures.load(), 0);
  EXPECT_EQ(store->list_jobs("t").value().size(), 200u);
}

// Idempotent creation: the first claim of a request id names the object;
// every later one, however they overlap, gets that name; tenants apart.
TEST_P(StoreTest, ARequestIdNamesOneObjectForEveryClaim) {
  auto store = open();
  ASSERT_EQ(store->claim_request_id("t", "req-1", "job", "job-a").value(), "job-a");
  EXPECT_EQ(store->claim_request_id("t", "req-1", "job", "job-b").value(), "job-a");
  EXPECT_EQ(store->claim_request_id("u", "req-1", "job", "job-c").value(), "job-c") << "request ids are per tenant";
  const auto other_kind = store->claim_request_id("t", "req-1", "dataset", "ds-d");
  ASSERT_EQ(other_kind.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(other_kind.status().message().find("job job-a"), std::string::npos) << other_kind.status().message();
  // A second insert of the id it names is refused: the object is created once.
  ASSERT_TRUE(store->put_job(job("job-a", "t", 1)).is_ok());
  EXPECT_EQ(store->put_job(job("job-a", "t", 2)).code(), StatusCode::kAlreadyExists);
  // Claims at once from several threads (over the pool's connections, on PostgreSQL): one name.
  constexpr int kClaims = 8;
  std::vector<std::string> named(kClaims);
  std::vector<std::thread> threads;
  std::latch go(kClaims);
  for (int i = 0; i < kClaims; ++i) {
    threads.emplace_back([&, i] {
      go.arrive_and_wait();
      auto claimed = store->claim_request_id("t", "req-2", "session", "ses-" + std::to_string(i));
      named[i] = claimed.is_ok() ? claimed.value() : claimed.status().to_string();
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(std::set<std::string>(named.begin(), named.end()).size(), 1u) << named[0];
  EXPECT_EQ(named[0].rfind("ses-", 0), 0u) << named[0];
}

// Looking a request id up stores nothing; old ids are forgotten.
TEST_P(StoreTest, ARequestIdIsFoundWithoutAClaimAndForgottenWhenOld) {
  auto store = open();
  EXPECT_FALSE(store->find_request_id("t", "req-1", "job").value().has_value());
  EXPECT_FALSE(store->find_request_id("t", "req-1", "job").value().has_value()) << "a look-up claimed it";
  ASSERT_EQ(store->claim_request_id("t", "req-1", "job", "job-a").value(), "job-a");
  EXPECT_EQ(store->find_request_id("t", "req-1", "job").value(), std::optional<std::string>("job-a"));
  EXPECT_FALSE(store->find_request_id("u", "req-1", "job").value().has_value()) << "request ids are per tenant";
  EXPECT_EQ(store->find_request_id("t", "req-1", "dataset").status().code(), StatusCode::kInvalidArgument);
  // Claimed "now" on the store's clock: kept by a cut-off in the past, gone by one in the future.
  const std::int64_t now = std::chrono::duration_cast<std::chrono::milliseconds>(
                               std::chrono::system_clock::now().time_since_epoch()).count();
  EXPECT_EQ(store->delete_request_ids(now - 3'600'000).value(), 0);
  EXPECT_EQ(store->delete_request_ids(now + 3'600'000).value(), 1);
  EXPECT_FALSE(store->find_request_id("t", "req-1", "job").value().has_value());
}

TEST_P(StoreTest, TheJobQueueHandsOutEachJobOnceOldestFirst) {
  auto store = open();
  EXPECT_FALSE(store->claim_job("a", 60000).value().has_value());
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(store->put_job(job("job-" + std::to_string(i), "t", 10 - i)).is_ok());
  const auto first = store->claim_job("a", 60000).value();
  ASSERT_TRUE(first.has_value());
  EXPECT_EQ(first->id, "job-2");  // the oldest
  EXPECT_EQ(first->state, JobState::kRunning);
  EXPECT_EQ(first->owner, "a");
  EXPECT_GT(first->started_ms, 0);
  EXPECT_EQ(first->spec, job("x", "t", 0).spec);
  const JobRecord stored = store->get_job("t", "job-2").value();
  EXPECT_EQ(stored.state, JobState::kRunning);
  EXPECT_EQ(stored.owner, "a");
  EXPECT_EQ(store->claim_job("b", 60000).value()->id, "job-1");
  EXPECT_EQ(store->claim_job("b", 60000).value()->id, "job-0");
  EXPECT_FALSE(store->claim_job("c", 60000).value().has_value()) << "every job is held under a live lease";
}

TEST_P(StoreTest, AJobOfAKindThisRiccatidDoesNotKnowIsListedButNeverClaimed) {
  // A newer riccatid sharing the store may queue kinds of jobs this one
  // cannot run: they show as unknown and wait for an instance that can.
  auto store = open();
  JobRecord newer = job("job-newer", "t", 1);
  newer.kind = JobKind::kUnknown;  // stored under a name this build does not know
  ASSERT_TRUE(store->put_job(newer).is_ok());
  ASSERT_TRUE(store->put_job(job("job-known", "t", 2)).is_ok());
  EXPECT_EQ(store->get_job("t", "job-newer").value().kind, JobKind::kUnknown);
  EXPECT_EQ(store->list_jobs("t").value().size(), 2u);
  const auto claimed = store->claim_job("a", 60000).value();
  ASSERT_TRUE(claimed.has_value());
  EXPECT_EQ(claimed->id, "job-known") << "the older job is of an unknown kind and must be skipped";
  EXPECT_FALSE(store->claim_job("a", 60000).value().has_value());
  EXPECT_EQ(store->get_job("t", "job-newer").value().state, JobState::kQueued);
}

TEST_P(StoreTest, ConcurrentClaimsNeverShareAJob) {
  auto store = open();
  constexpr int kJobs = 40;
  for (int i = 0; i < kJobs; ++i) ASSERT_TRUE(store->put_job(job("job-" + std::to_string(i), "t", i)).is_ok());
  std::vector<std::vector<std::string>> claimed(4);
  std::vector<std::thread> threads;
  std::latch go(4);
  for (int w = 0; w < 4; ++w) {
    threads.emplace_back([&, w] {
      go.arrive_and_wait();
      for (;;) {
        auto next = store->claim_job("worker-" + std::to_string(w), 60000);
        if (!next.is_ok() || !next.value().has_value()) break;
        claimed[w].push_back(next.value()->id);
      }
    });
  }
  for (auto& t : threads) t.join();
  std::set<std::string> all;
  std::size_t total = 0;
  for (const auto& ids : claimed) {
    total += ids.size();
    all.insert(ids.begin(), ids.end());
  }
  EXPECT_EQ(total, static_cast<std::size_t>(kJobs)) << "a job was claimed twice, or one was missed";
  EXPECT_EQ(all.size(), static_cast<std::size_t>(kJobs));
}

TEST_P(StoreTest, AnExpiredLeaseIsTakenOverAndOnlyTheHolderEndsTheJob) {
  auto store = open();
  ASSERT_TRUE(store->put_job(job("job-1", "t", 1)).is_ok());
  JobRecord held = store->claim_job("a", 60000).value().value();
  EXPECT_EQ(held.lease_until_ms, clock_->peek() + 60000);
  clock_->advance(59999ms);  // "a" died: its lease runs out
  EXPECT_FALSE(store->claim_job("b", 60000).value().has_value()) << "a's lease holds to its last millisecond";
  clock_->advance(2ms);
  const auto taken = store->claim_job("b", 60000).value();
  ASSERT_TRUE(taken.has_value()) << "an expired lease must be taken over";
  EXPECT_EQ(taken->id, "job-1");
  EXPECT_EQ(taken->started_ms, held.started_ms) << "started_ms is the first claim's";

  held.pass = 4;
  EXPECT_EQ(store->renew_job(held, "a", 60000).status().code(), StatusCode::kAborted);
  JobRecord end_a = held;
  end_a.state = JobState::kSucceeded;
  const std::string result_a = "a's result";
  EXPECT_EQ(store->finish_job(end_a, "a", &result_a).code(), StatusCode::kAborted);
  EXPECT_EQ(store->get_result("t", "job-1").status().code(), StatusCode::kNotFound) << "nothing of a's written";

  JobRecord progress = *taken;
  progress.pass = 2;
  progress.sample = 50;
  progress.theta = {1.0, 2.0};
  EXPECT_FALSE(store->renew_job(progress, "b", 60000).value());
  const JobRecord mid = store->get_job("t", "job-1").value();
  EXPECT_EQ(mid.pass, 2);
  EXPECT_EQ(mid.sample, 50);
  EXPECT_EQ(mid.theta, progress.theta);
  clock_->advance(1000ms);
  EXPECT_FALSE(store->renew_job(progress, "b", 60000).value());
  EXPECT_EQ(store->get_job("t", "job-1").value().lease_until_ms, clock_->peek() + 60000) << "renewed from now";

  JobRecord end_b = progress;
  end_b.state = JobState::kSucceeded;
  end_b.finished_ms = 99;
  const std::string result_b = "b's result";
  ASSERT_TRUE(store->finish_job(end_b, "b", &result_b).is_ok());
  EXPECT_EQ(store->get_result("t", "job-1").value(), result_b);
  EXPECT_EQ(store->get_job("t", "job-1").value().state, JobState::kSucceeded);
  EXPECT_EQ(store->finish_job(end_b, "b", &result_b).code(), StatusCode::kAborted) << "a job ends once";
  EXPECT_FALSE(store->claim_job("c", 60000).value().has_value()) << "an ended job is not claimed again";
}

TEST_P(StoreTest, ReleasedJobsAreQueuedAgainAndCancelsReachTheirOwner) {
  auto store = open();
  for (int i = 0; i < 4; ++i) ASSERT_TRUE(store->put_job(job("job-" + std::to_string(i), "t", i)).is_ok());
  ASSERT_EQ(store->claim_job("a", 60000).value()->id, "job-0");
  ASSERT_EQ(store->claim_job("b", 60000).value()->id, "job-1");
  EXPECT_EQ(store->release_jobs("a", false).value(), 1);
  EXPECT_EQ(store->get_job("t", "job-0").value().state, JobState::kQueued);
  EXPECT_EQ(store->get_job("t", "job-1").value().state, JobState::kRunning) << "b's job is b's";
  EXPECT_EQ(store->claim_job("c", 60000).value()->id, "job-0");
  EXPECT_EQ(store->release_jobs("", false).value(), 2) << "every owner's";

  // Queued: cancelled at once. Running: flagged for its owner's next renewal.
  const JobRecord queued = store->cancel_job("t", "job-3").value();
  EXPECT_EQ(queued.state, JobState::kCancelled);
  EXPECT_EQ(queued.error_code, static_cast<int>(StatusCode::kCancelled));
  EXPECT_GT(queued.finished_ms, 0);
  JobRecord running = store->claim_job("a", 60000).value().value();
  EXPECT_FALSE(store->renew_job(running, "a", 60000).value());
  EXPECT_EQ(store->cancel_job("t", running.id).value().state, JobState::kRunning);
  EXPECT_TRUE(store->renew_job(running, "a", 60000).value()) << "the owner learns of the cancel";
  EXPECT_EQ(store->cancel_job("nobody", running.id).status().code(), StatusCode::kNotFound);
  JobRecord end = running;
  end.state = JobState::kCancelled;
  ASSERT_TRUE(store->finish_job(end, "a", nullptr).is_ok());
  EXPECT_EQ(store->cancel_job("t", running.id).value().state, JobState::kCancelled) << "an ended job stays as it is";
}

// riccatid gives no clock: SQLite then reckons in the system's time,
// PostgreSQL in the database server's (here on the same host).
TEST_P(StoreTest, WithoutAClockGivenLeasesAreReckonedInRealTime) {
  auto opened = place_->open(nullptr);
  ASSERT_TRUE(opened.is_ok()) << opened.status().to_string();
  auto store = std::move(opened).value();
  ASSERT_TRUE(store->put_job(job("job-1", "t", 1)).is_ok());
  const std::int64_t before = SystemStoreClock().now_ms();
  const JobRecord held = store->claim_job("a", 60000).value().value();
  const std::int64_t after = SystemStoreClock().now_ms();
  // Rounding to milliseconds either side (PostgreSQL's extract is exact to microseconds).
  EXPECT_GE(held.lease_until_ms, before + 60000 - 1);
  EXPECT_LE(held.lease_until_ms, after + 60000 + 1);
  EXPECT_FALSE(store->claim_job("b", 60000).value().has_value()) << "a's lease is live";
}

// The retry budget's count: every claim is an attempt, whether the job was
// queued or taken over from a dead owner; a release by a stopping owner
// takes its claim back, one after a death (at start) does not.
TEST_P(StoreTest, EveryClaimOfAJobCountsAsAnAttemptUnlessItsOwnerStoppedIt) {
  auto store = open();
  ASSERT_TRUE(store->put_job(job("job-1", "t", 1)).is_ok());
  EXPECT_EQ(store->get_job("t", "job-1").value().attempts, 0);
  EXPECT_EQ(store->claim_job("a", 60000).value()->attempts, 1);
  clock_->advance(60001ms);  // "a" died: its lease ran out
  EXPECT_EQ(store->claim_job("b", 60000).value()->attempts, 2) << "a takeover is an attempt";
  EXPECT_EQ(store->get_job("t", "job-1").value().attempts, 2);
  EXPECT_EQ(store->release_jobs("b", true).value(), 1);
  EXPECT_EQ(store->get_job("t", "job-1").value().attempts, 1) << "b stopped it: its claim is taken back";
  EXPECT_EQ(store->claim_job("c", 60000).value()->attempts, 2);
  EXPECT_EQ(store->release_jobs("", false).value(), 1);
  EXPECT_EQ(store->get_job("t", "job-1").value().attempts, 2) << "released at a start after a death: it counts";
  JobRecord running = store->claim_job("d", 60000).value().value();
  EXPECT_EQ(running.attempts, 3);
  running.state = JobState::kFailed;
  ASSERT_TRUE(store->finish_job(running, "d", nullptr).is_ok());
  EXPECT_EQ(store->release_jobs("", true).value(), 0);
  EXPECT_EQ(store->get_job("t", "job-1").value().attempts, 3) << "an ended job keeps its count";
  // A job stored with a count keeps it (put_job writes every field).
  JobRecord counted = job("job-2", "t", 2);
  counted.attempts = 5;
  ASSERT_TRUE(store->put_job(counted).is_ok());
  EXPECT_EQ(store->get_job("t", "job-2").value().attempts, 5);
}

TEST_P(StoreTest, ASessionSnapshotIsHeldByOneInstanceUnderALease) {
  auto store = open();
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-1", "a", 60000).status().code(), StatusCode::kNotFound);
  const std::string v1("\x00state 1", 8), v2("\x00state 2", 8);
  ASSERT_TRUE(store->put_session_snapshot("t", "ses-1", "a", 60000, v1).is_ok());
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-1", "a", 60000).value(), v1) << "an owner claims its own";

  const auto refused = store->claim_session_snapshot("t", "ses-1", "b", 60000);
  EXPECT_EQ(refused.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(refused.status().message().find("held by instance a"), std::string::npos) << refused.status().message();
  const Status put_b = store->put_session_snapshot("t", "ses-1", "b", 60000, "b's");
  EXPECT_EQ(put_b.code(), StatusCode::kAborted) << put_b.to_string();
  EXPECT_NE(put_b.message().find("no longer held by b"), std::string::npos) << put_b.message();
  EXPECT_EQ(store->delete_session_snapshot("t", "ses-1", "b").code(), StatusCode::kAborted);

  ASSERT_TRUE(store->put_session_snapshot("t", "ses-1", "a", 60000, v2).is_ok());  // replaces
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-1", "a", 60000).value(), v2);
  ASSERT_TRUE(store->delete_session_snapshot("t", "ses-1", "a").is_ok());
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-1", "a", 60000).status().code(), StatusCode::kNotFound);
  EXPECT_EQ(store->delete_session_snapshot("t", "ses-1", "a").code(), StatusCode::kNotFound);
}

// The snapshots that fall due together are stored in one transaction, each
// judged alone: another instance's session and another tenant's id are
// refused as put_session_snapshot refuses them, and the rest are stored.
TEST_P(StoreTest, SessionSnapshotsAreStoredTogetherEachJudgedAlone) {
  auto store = open();
  ASSERT_TRUE(store->put_session_snapshot("t", "ses-held", "b", 60000, "b's").is_ok());
  ASSERT_TRUE(store->put_session_snapshot("u", "ses-other", "a", 60000, "u's").is_ok());
  ASSERT_TRUE(store->put_session_snapshot("t", "ses-old", "a", 60000, "old").is_ok());
  const std::string binary("\x00new\xff", 5);
  const std::vector<SessionSnapshotWrite> batch = {{"t", "ses-new", binary},
                                                   {"t", "ses-held", "a's"},
                                                   {"t", "ses-other", "t's"},
                                                   {"t", "ses-old", "replaced"}};
  const auto stored = store->put_session_snapshots("a", 60000, batch);
  ASSERT_TRUE(stored.is_ok()) << stored.status().to_string();
  ASSERT_EQ(stored.value().size(), 4u);
  EXPECT_TRUE(stored.value()[0].is_ok()) << stored.value()[0].to_string();
  EXPECT_EQ(stored.value()[1].code(), StatusCode::kAborted) << stored.value()[1].to_string();
  EXPECT_NE(stored.value()[1].message().find("session ses-held is no longer held by a"), std::string::npos);
  EXPECT_EQ(stored.value()[2].code(), StatusCode::kNotFound) << stored.value()[2].to_string();
  EXPECT_EQ(stored.value()[2].message(), "no session ses-other");
  EXPECT_TRUE(stored.value()[3].is_ok()) << stored.value()[3].to_string();

  EXPECT_EQ(store->claim_session_snapshot("t", "ses-new", "a", 60000).value(), binary);
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-old", "a", 60000).value(), "replaced");
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-held", "b", 60000).value(), "b's") << "b's, untouched";
  EXPECT_EQ(store->claim_session_snapshot("u", "ses-other", "a", 60000).value(), "u's") << "u's, untouched";
  const auto none = store->put_session_snapshots("a", 60000, {});
  ASSERT_TRUE(none.is_ok());
  EXPECT_TRUE(none.value().empty());
}

TEST_P(StoreTest, AnExpiredOrReleasedSessionLeaseIsTakenOverAndItsOldOwnerRefused) {
  auto store = open();
  ASSERT_TRUE(store->put_session_snapshot("t", "ses-1", "a", 60000, "a's").is_ok());
  clock_->advance(59999ms);  // "a" died: its lease runs out
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-1", "b", 60000).status().code(), StatusCode::kFailedPrecondition)
      << "a's lease holds to its last millisecond";
  clock_->advance(2ms);
  EXPECT_EQ(store->renew_session_leases("b", 60000).value(), 0) << "b holds nothing yet";
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-1", "b", 60000).value(), "a's");
  EXPECT_EQ(store->put_session_snapshot("t", "ses-1", "a", 60000, "late").code(), StatusCode::kAborted);
  EXPECT_EQ(store->delete_session_snapshot("t", "ses-1", "a").code(), StatusCode::kAborted);
  EXPECT_EQ(store->renew_session_leases("a", 60000).value(), 0) << "a's renewals no longer reach it";
  ASSERT_TRUE(store->put_session_snapshot("t", "ses-1", "b", 60000, "b's").is_ok());
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-1", "c", 60000).status().code(), StatusCode::kFailedPrecondition);

  // Released (a clean shutdown): claimable at once, and renewals leave it so.
  ASSERT_TRUE(store->put_session_snapshot("t", "ses-2", "a", 60000, "two").is_ok());
  const auto holders = [&store] {
    std::vector<std::string> out;
    const auto records = store->list_session_snapshots("t");
    for (const SessionSnapshotRecord& r : records.value()) {
      out.push_back(r.session_id + ":" + r.holder + ":" + r.snapshot);
    }
    return out;
  };
  EXPECT_EQ(holders(), (std::vector<std::string>{"ses-1:b:b's", "ses-2:a:two"}));
  EXPECT_EQ(store->release_sessions("a").value(), 1);
  EXPECT_EQ(holders(), (std::vector<std::string>{"ses-1:b:b's", "ses-2::two"})) << "a released one has no holder";
  EXPECT_EQ(store->renew_session_leases("a", 60000).value(), 0);
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-2", "c", 60000).value(), "two");
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-1", "c", 60000).status().code(), StatusCode::kFailedPrecondition)
      << "b's lease is b's";
  EXPECT_EQ(store->release_sessions("").value(), 2) << "every owner's";
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-1", "c", 60000).value(), "b's");

  // A renewal keeps a lease past its first term.
  ASSERT_TRUE(store->put_session_snapshot("t", "ses-3", "a", 10, "three").is_ok());
  EXPECT_EQ(store->renew_session_leases("a", 60000).value(), 1);
  clock_->advance(30ms);
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-3", "b", 60000).status().code(), StatusCode::kFailedPrecondition);
  clock_->advance(60000ms);
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-3", "b", 60000).value(), "three") << "the renewal ran out";
}

// A renewal is the owner's, not each session's: it covers a session the
// owner stores after it, until the owner stops renewing or releases.
TEST_P(StoreTest, ASessionLeaseLastsAsLongAsItsOwnersRenewal) {
  auto store = open();
  EXPECT_EQ(store->renew_session_leases("a", 100).value(), 0);
  ASSERT_TRUE(store->put_session_snapshot("t", "ses-1", "a", 1, "one").is_ok());  // its own term: 1 ms
  ASSERT_TRUE(store->put_session_snapshot("t", "ses-2", "b", 1, "two").is_ok());  // b has renewed nothing
  clock_->advance(20ms);
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-1", "c", 60000).status().code(), StatusCode::kFailedPrecondition)
      << "a's renewal, 100 ms, holds it";
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-2", "c", 60000).value(), "two") << "b's own 1 ms are over";
  clock_->advance(81ms);
  EXPECT_EQ(store->list_session_snapshots("t").value().front().holder, "") << "a's renewal, 100 ms, is over";
  EXPECT_EQ(store->renew_session_leases("a", 60000).value(), 1);
  clock_->advance(150ms);
  EXPECT_EQ(store->delete_abandoned_session_snapshots(0).value(), 0) << "held by a";
  EXPECT_EQ(store->list_session_snapshots("t").value().front().holder, "a");
  EXPECT_EQ(store->release_sessions("a").value(), 1);
  EXPECT_EQ(store->list_session_snapshots("t").value().front().holder, "") << "released, renewal or not";
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-1", "c", 60000).value(), "one");
}

TEST_P(StoreTest, ConcurrentClaimsOfASessionHaveOneWinner) {
  auto store = open();
  ASSERT_TRUE(store->put_session_snapshot("t", "ses-1", "gone", 0, "snap").is_ok());  // stored released
  std::vector<Result<std::string>> claimed(4, Status{StatusCode::kInternal, "not run"});
  std::vector<std::thread> threads;
  std::latch go(4);
  for (int w = 0; w < 4; ++w) {
    threads.emplace_back([&, w] {
      go.arrive_and_wait();
      claimed[w] = store->claim_session_snapshot("t", "ses-1", "worker-" + std::to_string(w), 60000);
    });
  }
  for (auto& t : threads) t.join();
  int won = 0;
  for (const auto& c : claimed) {
    if (c.is_ok()) {
      ++won;
      EXPECT_EQ(c.value(), "snap");
    } else {
      EXPECT_EQ(c.status().code(), StatusCode::kFailedPrecondition) << c.status().to_string();
    }
  }
  EXPECT_EQ(won, 1);
}

TEST_P(StoreTest, AbandonedSessionSnapshotsAreDeletedAfterTheIdleTime) {
  auto store = open();
  ASSERT_TRUE(store->put_session_snapshot("t", "ses-dead", "a", 1, "dead").is_ok());
  ASSERT_TRUE(store->put_session_snapshot("t", "ses-held", "b", 60000, "held").is_ok());
  clock_->advance(20ms);
  EXPECT_EQ(store->delete_abandoned_session_snapshots(60000).value(), 0) << "stored too recently";
  EXPECT_EQ(store->delete_abandoned_session_snapshots(20).value(), 0) << "stored 20 ms ago, not before";
  EXPECT_EQ(store->delete_abandoned_session_snapshots(19).value(), 1);
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-dead", "c", 60000).status().code(), StatusCode::kNotFound);
  EXPECT_EQ(store->claim_session_snapshot("t", "ses-held", "b", 60000).value(), "held");
}

INSTANTIATE_TEST_SUITE_P(
    Stores, StoreTest,
    ::testing::Values(StoreKind{"sqlite", false, [] { return std::unique_ptr<StorePlace>(new SqlitePlace); }},
                      StoreKind{"postgres", true, [] { return std::unique_ptr<StorePlace>(new PostgresPlace); }}),
    [](const auto& test_info) { return std::string(test_info.param.name); });

TEST(SqliteStore, RefusesANewerSchemaAndAMissingDirectory) {
  TempDir dir;
  const std::string path = (dir.path() / "riccati.db").string();
  ASSERT_TRUE(open_sqlite_store(path).is_ok());
  ASSERT_TRUE(open_sqlite_store(path).is_ok());  // migrations are idempotent
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  ASSERT_EQ(sqlite3_exec(db, "PRAGMA user_version = 999", nullptr, nullptr, nullptr), SQLITE_OK);
  sqlite3_close(db);
  auto newer = open_sqlite_store(path);
  ASSERT_FALSE(newer.is_ok());
  EXPECT_EQ(newer.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(newer.status().message().find("upgrade riccatid"), std::string::npos) << newer.status().message();

  auto missing = open_sqlite_store((dir.path() / "no" / "such" / "dir" / "riccati.db").string());
  ASSERT_FALSE(missing.is_ok());
  EXPECT_NE(missing.status().message().find("no/such/dir"), std::string::npos) << missing.status().message();
}

TEST(PostgresStore, StoresOpeningAtOnceOnAnEmptyDatabaseAllSucceed) {
  RICCATI_SKIP_WITHOUT_POSTGRES();
  PostgresSchema schema;
  // Several instances starting together race to create the schema: the
  // advisory lock makes one migrate and the others find it done.
  constexpr int kStores = 4;
  std::latch start(kStores);
  std::vector<Result<std::unique_ptr<Store>>> opened;
  for (int i = 0; i < kStores; ++i) opened.emplace_back(Status{StatusCode::kInternal, "not run"});
  std::vector<std::thread> threads;
  for (int i = 0; i < kStores; ++i) {
    threads.emplace_back([&, i] {
      start.arrive_and_wait();
      opened[i] = open_postgres_store(schema.url());
    });
  }
  for (auto& t : threads) t.join();
  for (int i = 0; i < kStores; ++i) ASSERT_TRUE(opened[i].is_ok()) << i << ": " << opened[i].status().to_string();
  const pqxx::result versions = schema.exec("SELECT version FROM riccati_schema_migrations ORDER BY version");
  // Each migration applied once, in order.
  ASSERT_EQ(versions.size(), 11u);  // postgres_store.cpp's migrations
  for (int v = 0; v < static_cast<int>(versions.size()); ++v) EXPECT_EQ(versions[v][0].as<int>(), v + 1);
  // And they share one database: what one stores, another reads.
  ASSERT_TRUE(opened[0].value()->put_job_pass("t", "none", 1, "c").code() == StatusCode::kNotFound);
  JobRecord j;
  j.id = "job-1";
  j.tenant = "t";
  j.kind = JobKind::kIdentification;
  ASSERT_TRUE(opened[0].value()->put_job(j).is_ok());
  EXPECT_EQ(opened[kStores - 1].value()->get_job("t", "job-1").value().kind, JobKind::kIdentification);
}

TEST(PostgresStore, RefusesANewerSchemaNamingTheDatabaseWithoutItsPassword) {
  RICCATI_SKIP_WITHOUT_POSTGRES();
  PostgresSchema schema;
  ASSERT_TRUE(open_postgres_store(schema.url()).is_ok());
  ASSERT_TRUE(open_postgres_store(schema.url()).is_ok());  // migrations are idempotent
  schema.exec("INSERT INTO riccati_schema_migrations (version) VALUES (999)");
  auto newer = open_postgres_store(schema.url());
  ASSERT_FALSE(newer.is_ok());
  EXPECT_EQ(newer.status().code(), StatusCode::kFailedPrecondition);
  const std::string& message = newer.status().message();
  EXPECT_NE(message.find("schema version 999"), std::string::npos) << message;
  EXPECT_NE(message.find("upgrade riccatid"), std::string::npos) << message;
  EXPECT_NE(message.find(redact_database_url(schema.url())), std::string::npos) << message;
  // Refused inside the transaction: nothing was changed.
  EXPECT_EQ(schema.exec("SELECT count(*) FROM riccati_schema_migrations WHERE version < 999")[0][0].as<int>(),
            schema.exec("SELECT max(version) FROM riccati_schema_migrations WHERE version < 999")[0][0].as<int>());
  EXPECT_EQ(schema.exec("SELECT count(*) FROM riccati_schema_migrations WHERE version = 999")[0][0].as<int>(), 1);
}

TEST(PostgresStore, AnUnreachableServerIsUnavailableAndNamedWithoutThePassword) {
  // Port 1 on loopback: nothing listens there; no test server needed.
  auto store = open_postgres_store("postgresql://riccati:s3cret@127.0.0.1:1/riccati");
  ASSERT_FALSE(store.is_ok());
  EXPECT_EQ(store.status().code(), StatusCode::kUnavailable);
  const std::string& message = store.status().message();
  EXPECT_NE(message.find("cannot connect to PostgreSQL at postgresql://riccati:***@127.0.0.1:1/riccati"),
            std::string::npos)
      << message;
  EXPECT_EQ(message.find("s3cret"), std::string::npos) << message;
}

TEST(PostgresStore, RedactsPasswordsInUrls) {
  EXPECT_EQ(redact_database_url("postgresql://u:pw@h:5432/db"), "postgresql://u:***@h:5432/db");
  EXPECT_EQ(redact_database_url("postgres://u:p@w@h/db?sslmode=require"), "postgres://u:***@h/db?sslmode=require");
  EXPECT_EQ(redact_database_url("postgresql://u@h/db"), "postgresql://u@h/db");
  EXPECT_EQ(redact_database_url("postgresql://h/db"), "postgresql://h/db");
  EXPECT_EQ(redact_database_url("postgresql://h/db?user=u&password=pw&sslmode=disable"),
            "postgresql://h/db?user=u&password=***&sslmode=disable");
  EXPECT_EQ(redact_database_url("host=h password=pw dbname=d"), "host=h password=*** dbname=d");
  EXPECT_EQ(redact_database_url("host=h sslpassword=x"), "host=h sslpassword=x");
}

TEST(PostgresStore, ReconnectsAfterTheServerDropsItsConnections) {
  RICCATI_SKIP_WITHOUT_POSTGRES();
  PostgresSchema schema;
  // Our own application name, so that only this test's connections are cut.
  auto store = open_postgres_store(schema.url("application_name=" + schema.name())).value();
  JobRecord j;
  j.id = "job-1";
  j.tenant = "t";
  j.kind = JobKind::kIdentification;
  ASSERT_TRUE(store->put_job(j).is_ok());
  const auto cut = [&] {
    return schema.exec("SELECT pg_terminate_backend(pid) FROM pg_stat_activity WHERE application_name = '" +
                       schema.name() + "'")
        .size();
  };
  ASSERT_GE(cut(), 1u);
  // A read is tried again on a new connection: the caller sees nothing.
  auto job = store->get_job("t", "job-1");
  ASSERT_TRUE(job.is_ok()) << job.status().to_string();
  ASSERT_GE(cut(), 1u);
  // A write that cannot safely be repeated fails once as UNAVAILABLE...
  j.id = "job-2";
  const Status lost = store->put_job(j);
  EXPECT_EQ(lost.code(), StatusCode::kUnavailable) << lost.to_string();
  EXPECT_NE(lost.message().find("storing job job-2"), std::string::npos) << lost.message();
  // ...and the next call works on a new connection.
  EXPECT_TRUE(store->put_job(j).is_ok());
  EXPECT_EQ(store->list_jobs("t").value().size(), 2u);
}

}  // namespace
}  // namespace riccati
