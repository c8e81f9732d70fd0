// The SQLite store: one database file, WAL journal, versioned migrations.
#include <spdlog/spdlog.h>
#include <sqlite3.h>

#include <fcntl.h>
#include <sys/resource.h>
#include <sys/statvfs.h>
#include <unistd.h>

#include <cerrno>
#include <filesystem>
#include <chrono>
#include <cstring>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include "store/store.hpp"

namespace riccati {

namespace {

// Migrations, applied in order, each in its own transaction; the database's
// PRAGMA user_version is the number applied. Append only: never edit one
// that has shipped.
const std::vector<const char*> kMigrations = {
    // 1: datasets, their samples, jobs, results, session snapshots.
    R"sql(
    CREATE TABLE datasets (
      id TEXT PRIMARY KEY,
      tenant TEXT NOT NULL,
      name TEXT NOT NULL,
      format TEXT NOT NULL,
      input_names TEXT NOT NULL,
      output_names TEXT NOT NULL,
      samples INTEGER NOT NULL,
      t_start REAL NOT NULL,
      t_end REAL NOT NULL,
      size_bytes INTEGER NOT NULL,
      created_ms INTEGER NOT NULL);
    CREATE INDEX datasets_by_tenant ON datasets (tenant, created_ms);
    CREATE TABLE dataset_samples (
      dataset_id TEXT PRIMARY KEY REFERENCES datasets (id) ON DELETE CASCADE,
      t BLOB NOT NULL,
      u BLOB NOT NULL,
      y BLOB NOT NULL);
    CREATE TABLE jobs (
      id TEXT PRIMARY KEY,
      tenant TEXT NOT NULL,
      kind TEXT NOT NULL,
      state TEXT NOT NULL,
      spec BLOB NOT NULL,
      pass INTEGER NOT NULL,
      passes INTEGER NOT NULL,
      sample INTEGER NOT NULL,
      samples INTEGER NOT NULL,
      theta BLOB NOT NULL,
      error_code INTEGER NOT NULL,
      error_message TEXT NOT NULL,
      created_ms INTEGER NOT NULL,
      started_ms INTEGER NOT NULL,
      finished_ms INTEGER NOT NULL);
    CREATE INDEX jobs_by_tenant ON jobs (tenant, created_ms);
    CREATE INDEX jobs_by_state ON jobs (state);
    CREATE TABLE results (
      job_id TEXT PRIMARY KEY REFERENCES jobs (id) ON DELETE CASCADE,
      tenant TEXT NOT NULL,
      result BLOB NOT NULL);
    CREATE TABLE session_snapshots (
      session_id TEXT PRIMARY KEY,
      tenant TEXT NOT NULL,
      snapshot BLOB NOT NULL,
      updated_ms INTEGER NOT NULL);
    )sql",
    // 2: checkpoints of jobs, a record per completed pass.
    R"sql(
    CREATE TABLE job_passes (
      job_id TEXT NOT NULL REFERENCES jobs (id) ON DELETE CASCADE,
      pass INTEGER NOT NULL,
      tenant TEXT NOT NULL,
      record BLOB NOT NULL,
      PRIMARY KEY (job_id, pass));
    )sql",
    // 3: the job queue: who runs a job, until when, and a cancel request.
    R"sql(
    ALTER TABLE jobs ADD COLUMN owner TEXT NOT NULL DEFAULT '';
    ALTER TABLE jobs ADD COLUMN lease_until_ms INTEGER NOT NULL DEFAULT 0;
    ALTER TABLE jobs ADD COLUMN cancel_requested INTEGER NOT NULL DEFAULT 0;
    )sql",
    // 4: session snapshots held by an instance under a lease, as jobs are.
    R"sql(
    ALTER TABLE session_snapshots ADD COLUMN owner TEXT NOT NULL DEFAULT '';
    ALTER TABLE session_snapshots ADD COLUMN lease_until_ms INTEGER NOT NULL DEFAULT 0;
    CREATE INDEX session_snapshots_by_owner ON session_snapshots (owner);
    )sql",
    // 5: an optimiser's progress (output error, maximum likelihood).
    R"sql(
    ALTER TABLE jobs ADD COLUMN iteration INTEGER NOT NULL DEFAULT 0;
    ALTER TABLE jobs ADD COLUMN cost REAL NOT NULL DEFAULT 0;
    )sql",
    // 6: how many times a job was claimed without ending (the retry budget).
    R"sql(
    ALTER TABLE jobs ADD COLUMN attempts INTEGER NOT NULL DEFAULT 0;
    )sql",
    // 7: clients' request ids, for idempotent creation (claim_request_id).
    R"sql(
    CREATE TABLE request_ids (
      tenant TEXT NOT NULL,
      request_id TEXT NOT NULL,
      kind TEXT NOT NULL,
      object_id TEXT NOT NULL,
      created_ms INTEGER NOT NULL,
      PRIMARY KEY (tenant, request_id));
    )sql",
    // 8: text models uploaded by tenants, every revision.
    R"sql(
    CREATE TABLE models (
      tenant TEXT NOT NULL,
      name TEXT NOT NULL,
      revision INTEGER NOT NULL,
      source BLOB NOT NULL,
      sha256 TEXT NOT NULL,
      created_ms INTEGER NOT NULL,
      deleted INTEGER NOT NULL DEFAULT 0,
      PRIMARY KEY (tenant, name, revision));
    )sql",
    // 9: each dataset's SHA-256 of its file as uploaded, so that a client
    // can reuse an identical upload ('' for datasets stored before).
    R"sql(
    ALTER TABLE datasets ADD COLUMN sha256 TEXT NOT NULL DEFAULT '';
    )sql",
    // 10: the parameters a dataset was made with, when its upload declared
    // them ("name=value" lines; '' for none).
    R"sql(
    ALTER TABLE datasets ADD COLUMN true_parameters TEXT NOT NULL DEFAULT '';
    )sql",
    // 11: one lease row per instance, renewed for all the sessions it
    // holds at once (RICCATI_SQLITE_SESSION_LEASE_UNTIL): renewing each
    // session's row rewrote every snapshot, 10,000 of them every 5 s at
    // 10,000 sessions. The partial index counts an owner's held sessions
    // without their rows.
    R"sql(
    CREATE TABLE session_owner_leases (
      owner TEXT PRIMARY KEY,
      lease_until_ms INTEGER NOT NULL);
    CREATE INDEX session_snapshots_held ON session_snapshots (owner) WHERE lease_until_ms > 0;
    )sql",
    // 12: the model each job's spec names, pinned (name@revision), so that
    // a deleted text model's revisions can be purged once no queued or
    // running job names them. Jobs stored before name none.
    R"sql(
    ALTER TABLE jobs ADD COLUMN model TEXT NOT NULL DEFAULT '';
    )sql",
};

// When a session's lease ends: 0 once released; else its own term (from its
// claim or last put) or its owner's renewed term, whichever is later.
#define RICCATI_SQLITE_SESSION_LEASE_UNTIL                                                              \
  "(CASE WHEN session_snapshots.lease_until_ms > 0 THEN max(session_snapshots.lease_until_ms, coalesce(" \
  "(SELECT o.lease_until_ms FROM session_owner_leases o WHERE o.owner = session_snapshots.owner), 0)) "   \
  "ELSE 0 END)"

// A job that may still run names this revision of a model (its spec's
// pinned name@revision): the revision is kept.
#define RICCATI_MODEL_NAMED_BY_A_JOB                                                          \
  "SELECT 1 FROM jobs WHERE jobs.tenant = models.tenant AND jobs.state IN ('queued', 'running') " \
  "AND jobs.model = models.name || '@' || models.revision"

// Names never contain the ASCII unit separator, so it can join them.
constexpr char kSeparator = '\x1f';

std::string join_names(const std::vector<std::string>& names) {
  std::string out;
  for (std::size_t i = 0; i < names.size(); ++i) {
    if (i > 0) out += kSeparator;
    out += names[i];
  }
  return out;
}

std::vector<std::string> split_names(const std::string& joined) {
  std::vector<std::string> out;
  if (joined.empty()) return out;
  std::size_t start = 0;
  for (std::size_t i = 0; i <= joined.size(); ++i) {
    if (i == joined.size() || joined[i] == kSeparator) {
      out.push_back(joined.substr(start, i - start));
      start = i + 1;
    }
  }
  return out;
}

// Doubles as raw little-endian bytes (x86-64 and ARM64 are both): exact.
std::string to_blob(const double* v, std::size_t n) {
  return std::string(reinterpret_cast<const char*>(v), n * sizeof(double));
}

std::vector<double> from_blob(const void* data, int bytes) {
  std::vector<double> out(static_cast<std::size_t>(bytes) / sizeof(double));
  if (!out.empty()) std::memcpy(out.data(), data, out.size() * sizeof(double));
  return out;
}

struct CloseDb {
  void operator()(sqlite3* db) const { sqlite3_close_v2(db); }
};
struct FinalizeStmt {
  void operator()(sqlite3_stmt* s) const { sqlite3_finalize(s); }
};

// A prepared statement with positional binding (1-based, in call order).
class Statement {
 public:
  Statement(sqlite3* db, const char* sql) {
    sqlite3_stmt* raw = nullptr;
    rc_ = sqlite3_prepare_v2(db, sql, -1, &raw, nullptr);
    stmt_.reset(raw);
  }
  bool prepared() const { return rc_ == SQLITE_OK; }

  // A value SQLite refuses (SQLITE_TOOBIG: over its 1 GB limit) would stay
  // NULL and fail as a NOT NULL constraint; step() returns the refusal instead.
  Statement& text(std::string_view v) {
    bound(sqlite3_bind_text64(stmt_.get(), ++index_, v.data(), v.size(), SQLITE_TRANSIENT, SQLITE_UTF8));
    return *this;
  }
  Statement& blob(std::string_view v) {
    bound(sqlite3_bind_blob64(stmt_.get(), ++index_, v.data(), v.size(), SQLITE_TRANSIENT));
    return *this;
  }
  // n doubles as a blob, read in place (no copy: a dataset's samples can be
  // hundreds of MB): they must outlive the statement's step.
  Statement& doubles(const double* v, std::size_t n) {
    static const double kNone = 0.0;  // an empty blob, not SQL NULL (what a null pointer binds)
    bound(sqlite3_bind_blob64(stmt_.get(), ++index_, n > 0 ? v : &kNone, n * sizeof(double), SQLITE_STATIC));
    return *this;
  }
  Statement& integer(std::int64_t v) {
    sqlite3_bind_int64(stmt_.get(), ++index_, v);
    return *this;
  }
  Statement& real(double v) {
    sqlite3_bind_double(stmt_.get(), ++index_, v);
    return *this;
  }

  // Ready to run again, with new values bound from the first.
  void reset() {
    sqlite3_reset(stmt_.get());
    sqlite3_clear_bindings(stmt_.get());
    index_ = 0;
    bind_rc_ = SQLITE_OK;
  }

  // SQLITE_ROW, SQLITE_DONE or an error code (a failed bind's, unrun).
  int step() { return bind_rc_ != SQLITE_OK ? bind_rc_ : sqlite3_step(stmt_.get()); }
  int bind_error() const { return bind_rc_; }

  std::string column_text(int i) const {
    const auto* p = reinterpret_cast<const char*>(sqlite3_column_text(stmt_.get(), i));
    return p != nullptr ? std::string(p, static_cast<std::size_t>(sqlite3_column_bytes(stmt_.get(), i))) : "";
  }
  std::string column_blob(int i) const {
    const void* p = sqlite3_column_blob(stmt_.get(), i);
    return p != nullptr ? std::string(static_cast<const char*>(p), static_cast<std::size_t>(sqlite3_column_bytes(stmt_.get(), i)))
                        : "";
  }
  std::vector<double> column_doubles(int i) const {
    return from_blob(sqlite3_column_blob(stmt_.get(), i), sqlite3_column_bytes(stmt_.get(), i));
  }
  std::int64_t column_int(int i) const { return sqlite3_column_int64(stmt_.get(), i); }
  double column_double(int i) const { return sqlite3_column_double(stmt_.get(), i); }
  double column_real(int i) const { return sqlite3_column_double(stmt_.get(), i); }

 private:
  void bound(int rc) {
    if (rc != SQLITE_OK && bind_rc_ == SQLITE_OK && rc_ == SQLITE_OK) bind_rc_ = rc;
  }

  std::unique_ptr<sqlite3_stmt, FinalizeStmt> stmt_;
  int rc_ = SQLITE_OK;
  int bind_rc_ = SQLITE_OK;
  int index_ = 0;
};

JobState parse_state(const std::string& s) { return parse_job_state(s).value_or(JobState::kFailed); }

constexpr const char* kJobColumns =
    "id, tenant, kind, state, spec, pass, passes, sample, samples, theta, error_code, error_message, created_ms, "
    "started_ms, finished_ms, owner, lease_until_ms, cancel_requested, iteration, cost, attempts, model";


JobRecord read_job(const Statement& s) {
  JobRecord j;
  j.id = s.column_text(0);
  j.tenant = s.column_text(1);
  j.kind = parse_job_kind(s.column_text(2));
  j.state = parse_state(s.column_text(3));
  j.spec = s.column_blob(4);
  j.pass = static_cast<int>(s.column_int(5));
  j.passes = static_cast<int>(s.column_int(6));
  j.sample = s.column_int(7);
  j.samples = s.column_int(8);
  j.theta = s.column_doubles(9);
  j.error_code = static_cast<int>(s.column_int(10));
  j.error_message = s.column_text(11);
  j.created_ms = s.column_int(12);
  j.started_ms = s.column_int(13);
  j.finished_ms = s.column_int(14);
  j.owner = s.column_text(15);
  j.lease_until_ms = s.column_int(16);
  j.cancel_requested = s.column_int(17) != 0;
  j.iteration = static_cast<int>(s.column_int(18));
  j.cost = s.column_double(19);
  j.attempts = static_cast<int>(s.column_int(20));
  j.model = s.column_text(21);
  return j;
}

constexpr const char* kDatasetColumns =
    "id, tenant, name, format, input_names, output_names, samples, t_start, t_end, size_bytes, created_ms, sha256, "
    "true_parameters";

DatasetRecord read_dataset(const Statement& s) {
  DatasetRecord d;
  d.id = s.column_text(0);
  d.tenant = s.column_text(1);
  d.name = s.column_text(2);
  d.format = s.column_text(3);
  d.input_names = split_names(s.column_text(4));
  d.output_names = split_names(s.column_text(5));
  d.samples = s.column_int(6);
  d.t_start = s.column_real(7);
  d.t_end = s.column_real(8);
  d.size_bytes = s.column_int(9);
  d.created_ms = s.column_int(10);
  d.sha256 = s.column_text(11);
  d.true_parameters = decode_named_values(s.column_text(12));
  return d;
}

class SqliteStore final : public Store {
 public:
  SqliteStore(std::unique_ptr<sqlite3, CloseDb> db, std::string path, std::shared_ptr<StoreClock> clock)
      : db_(std::move(db)), path_(std::move(path)), clock_(std::move(clock)) {}
  // The log is kept (SQLITE_FCNTL_PERSIST_WAL) but emptied as the connection
  // closes: its frames, all copied into the database by then, would
  // otherwise be read again at the next start in place of the database's
  // pages (and hide damage to them from the integrity check).
  ~SqliteStore() override {
    std::lock_guard lock(mu_);
    (void)sqlite3_exec(db_.get(), "PRAGMA journal_size_limit = 0", nullptr, nullptr, nullptr);
  }

  void keep_reserve_at_start() {
    std::lock_guard lock(mu_);
    keep_reserve();
  }

  // PRAGMA quick_check at start: damage anywhere in the file is reported
  // now, refusing to serve, rather than object by object as clients read
  // them. It reads the whole file (about a second per GB).
  Status check_integrity() {
    std::lock_guard lock(mu_);
    const auto started = std::chrono::steady_clock::now();
    Statement q(db_.get(), "PRAGMA quick_check(5)");
    std::string problems;
    int rc = q.prepared() ? SQLITE_ROW : SQLITE_ERROR;
    while (q.prepared() && (rc = q.step()) == SQLITE_ROW) {
      const std::string line = q.column_text(0);
      if (line != "ok") problems += (problems.empty() ? "" : "; ") + line;
    }
    if (rc != SQLITE_DONE || !problems.empty()) {
      if (problems.empty()) problems = sqlite3_errmsg(db_.get());
      return failed_precondition("database " + path_ + " is damaged (" + problems +
                                 "): restore it from a backup; riccatid does not serve a damaged store");
    }
    spdlog::info("store checked database={} check=quick_check ms={}", path_,
                 std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::steady_clock::now() - started).count());
    return Status::ok();
  }

  Status migrate() {
    std::lock_guard lock(mu_);
    RICCATI_RETURN_IF_ERROR(use_incremental_vacuum());
    RICCATI_RETURN_IF_ERROR(exec("PRAGMA journal_mode = WAL"));
    // The write-ahead log and its index stay when riccatid stops, so that a
    // start on a full disk needs no new file (it read and deletes there).
    int persist = 1;
    sqlite3_file_control(db_.get(), "main", SQLITE_FCNTL_PERSIST_WAL, &persist);
    // FULL with WAL: every commit is synced before it is acknowledged, so an
    // accepted upload, job or result survives a kill -9 of the daemon (NORMAL
    // would already) and a power loss (NORMAL may lose the last commits).
    // Commits are few (uploads, state changes, throttled progress, a
    // checkpoint per pass), so the fsync each costs does not matter.
    RICCATI_RETURN_IF_ERROR(exec("PRAGMA synchronous = FULL"));
    RICCATI_RETURN_IF_ERROR(exec("PRAGMA foreign_keys = ON"));
    sqlite3_busy_timeout(db_.get(), 5000);
    Statement version(db_.get(), "PRAGMA user_version");
    if (version.step() != SQLITE_ROW) return error("reading the schema version");
    const auto current = version.column_int(0);
    const auto known = static_cast<std::int64_t>(kMigrations.size());
    if (current > known) {
      return failed_precondition("database " + path_ + " has schema version " + std::to_string(current) +
                                 ", newer than this riccatid (" + std::to_string(known) + "): upgrade riccatid");
    }
    for (auto v = current; v < known; ++v) {
      RICCATI_RETURN_IF_ERROR(exec("BEGIN IMMEDIATE"));
      Status applied = exec(kMigrations[static_cast<std::size_t>(v)]);
      if (applied.is_ok()) applied = exec("PRAGMA user_version = " + std::to_string(v + 1));
      if (!applied.is_ok()) {
        (void)exec("ROLLBACK");
        return applied.with_context("migration " + std::to_string(v + 1));
      }
      RICCATI_RETURN_IF_ERROR(exec("COMMIT"));
    }
    return Status::ok();
  }

  Status put_dataset(const DatasetRecord& r, const Dataset& data) override {
    std::lock_guard lock(mu_);
    RICCATI_RETURN_IF_ERROR(room_for_new_data(
        "storing dataset " + r.id, 8 * (data.t.size() + data.u.size() + data.y.size())));
    return in_transaction("storing dataset " + r.id, [&]() -> Status {
      Statement insert(db_.get(),
                       "INSERT INTO datasets (id, tenant, name, format, input_names, output_names, samples, t_start, "
                       "t_end, size_bytes, created_ms, sha256, true_parameters) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, "
                       "?)");
      insert.text(r.id).text(r.tenant).text(r.name).text(r.format).text(join_names(r.input_names))
          .text(join_names(r.output_names)).integer(r.samples).real(r.t_start).real(r.t_end).integer(r.size_bytes)
          .integer(r.created_ms).text(r.sha256).text(encode_named_values(r.true_parameters));
      RICCATI_RETURN_IF_ERROR(done(insert, "storing dataset " + r.id));
      Statement samples(db_.get(), "INSERT INTO dataset_samples (dataset_id, t, u, y) VALUES (?, ?, ?, ?)");
      samples.text(r.id)
          .doubles(data.t.data(), static_cast<std::size_t>(data.t.size()))
          .doubles(data.u.data(), static_cast<std::size_t>(data.u.size()))
          .doubles(data.y.data(), static_cast<std::size_t>(data.y.size()));
      return done(samples, "storing the samples of dataset " + r.id);
    });
  }

  Result<DatasetRecord> get_dataset(const std::string& tenant, const std::string& id) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(), (std::string("SELECT ") + kDatasetColumns + " FROM datasets WHERE id = ? AND tenant = ?").c_str());
    q.text(id).text(tenant);
    const int rc = q.step();
    if (rc == SQLITE_DONE) return not_found("no dataset " + id);
    if (rc != SQLITE_ROW) return error("reading dataset " + id);
    return read_dataset(q);
  }

  Result<Dataset> load_dataset(const std::string& tenant, const std::string& id) override {
    RICCATI_ASSIGN_OR_RETURN(const DatasetRecord record, get_dataset(tenant, id));
    std::lock_guard lock(mu_);
    Statement q(db_.get(), "SELECT t, u, y FROM dataset_samples WHERE dataset_id = ?");
    q.text(id);
    if (q.step() != SQLITE_ROW) return error("reading the samples of dataset " + id);
    const auto t = q.column_doubles(0), u = q.column_doubles(1), y = q.column_doubles(2);
    const auto n = static_cast<Eigen::Index>(record.samples);
    const auto nu = static_cast<Eigen::Index>(record.input_names.size());
    const auto ny = static_cast<Eigen::Index>(record.output_names.size());
    if (static_cast<Eigen::Index>(t.size()) != n || static_cast<Eigen::Index>(u.size()) != nu * n ||
        static_cast<Eigen::Index>(y.size()) != ny * n) {
      return internal_error("the stored samples of dataset " + id + " do not match its sizes");
    }
    Dataset d;
    d.name = record.name;
    d.input_names = record.input_names;
    d.output_names = record.output_names;
    d.t = Eigen::Map<const Eigen::VectorXd>(t.data(), n);
    d.u = Eigen::Map<const Eigen::MatrixXd>(u.data(), nu, n);
    d.y = Eigen::Map<const Eigen::MatrixXd>(y.data(), ny, n);
    return d;
  }

  Result<std::vector<DatasetRecord>> list_datasets(const std::string& tenant) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(),
                (std::string("SELECT ") + kDatasetColumns + " FROM datasets WHERE tenant = ? ORDER BY created_ms, rowid")
                    .c_str());
    q.text(tenant);
    std::vector<DatasetRecord> out;
    int rc;
    while ((rc = q.step()) == SQLITE_ROW) out.push_back(read_dataset(q));
    if (rc != SQLITE_DONE) return error("listing datasets");
    return out;
  }

  Status delete_dataset(const std::string& tenant, const std::string& id) override {
    std::lock_guard lock(mu_);
    return with_reserve([&]() -> Status {
      Statement q(db_.get(), "DELETE FROM datasets WHERE id = ? AND tenant = ?");
      q.text(id).text(tenant);
      RICCATI_RETURN_IF_ERROR(done(q, "deleting dataset " + id));
      if (sqlite3_changes(db_.get()) == 0) return not_found("no dataset " + id);
      return Status::ok();
    });
  }

  Status put_job(const JobRecord& j) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(), (std::string("INSERT INTO jobs (") + kJobColumns +
                            ") VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)")
                               .c_str());
    q.text(j.id).text(j.tenant).text(job_kind_name(j.kind)).text(job_state_name(j.state)).blob(j.spec).integer(j.pass)
        .integer(j.passes).integer(j.sample).integer(j.samples).blob(to_blob(j.theta.data(), j.theta.size()))
        .integer(j.error_code).text(j.error_message).integer(j.created_ms).integer(j.started_ms)
        .integer(j.finished_ms).text(j.owner).integer(j.lease_until_ms).integer(j.cancel_requested ? 1 : 0)
        .integer(j.iteration).real(j.cost).integer(j.attempts).text(j.model);
    return done(q, "storing job " + j.id);
  }

  Result<std::string> claim_request_id(const std::string& tenant, const std::string& request_id,
                                       const std::string& kind, const std::string& object_id) override {
    std::lock_guard lock(mu_);
    {
      Statement q(db_.get(),
                  "INSERT INTO request_ids (tenant, request_id, kind, object_id, created_ms) VALUES (?, ?, ?, ?, ?) "
                  "ON CONFLICT (tenant, request_id) DO NOTHING");
      q.text(tenant).text(request_id).text(kind).text(object_id).integer(clock_->now_ms());
      RICCATI_RETURN_IF_ERROR(done(q, "storing request id " + request_id));
    }
    Statement q(db_.get(), "SELECT kind, object_id FROM request_ids WHERE tenant = ? AND request_id = ?");
    q.text(tenant).text(request_id);
    if (q.step() != SQLITE_ROW) return error("reading request id " + request_id);
    return named_object(request_id, q.column_text(0), q.column_text(1), kind);
  }

  Result<std::optional<std::string>> find_request_id(const std::string& tenant, const std::string& request_id,
                                                     const std::string& kind) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(), "SELECT kind, object_id FROM request_ids WHERE tenant = ? AND request_id = ?");
    q.text(tenant).text(request_id);
    const int rc = q.step();
    if (rc == SQLITE_DONE) return std::optional<std::string>();
    if (rc != SQLITE_ROW) return error("reading request id " + request_id);
    RICCATI_ASSIGN_OR_RETURN(std::string id, named_object(request_id, q.column_text(0), q.column_text(1), kind));
    return std::optional<std::string>(std::move(id));
  }

  Result<int> delete_request_ids(std::int64_t claimed_before_ms) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(), "DELETE FROM request_ids WHERE created_ms < ?");
    q.integer(claimed_before_ms);
    RICCATI_RETURN_IF_ERROR(done(q, "deleting old request ids"));
    return sqlite3_changes(db_.get());
  }

  Status update_job(const JobRecord& j) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(),
                "UPDATE jobs SET state = ?, pass = ?, passes = ?, sample = ?, samples = ?, theta = ?, error_code = ?, "
                "error_message = ?, started_ms = ?, finished_ms = ?, iteration = ?, cost = ? WHERE id = ? AND tenant = ?");
    q.text(job_state_name(j.state)).integer(j.pass).integer(j.passes).integer(j.sample).integer(j.samples)
        .blob(to_blob(j.theta.data(), j.theta.size())).integer(j.error_code).text(j.error_message)
        .integer(j.started_ms).integer(j.finished_ms).integer(j.iteration).real(j.cost).text(j.id).text(j.tenant);
    RICCATI_RETURN_IF_ERROR(done(q, "updating job " + j.id));
    if (sqlite3_changes(db_.get()) == 0) return not_found("no job " + j.id);
    return Status::ok();
  }

  Result<JobRecord> get_job(const std::string& tenant, const std::string& id) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(), (std::string("SELECT ") + kJobColumns + " FROM jobs WHERE id = ? AND tenant = ?").c_str());
    q.text(id).text(tenant);
    const int rc = q.step();
    if (rc == SQLITE_DONE) return not_found("no job " + id);
    if (rc != SQLITE_ROW) return error("reading job " + id);
    return read_job(q);
  }

  Result<std::vector<JobRecord>> list_jobs(const std::string& tenant) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(),
                (std::string("SELECT ") + kJobColumns + " FROM jobs WHERE tenant = ? ORDER BY created_ms, rowid").c_str());
    q.text(tenant);
    return read_jobs(q, "listing jobs");
  }

  Result<std::vector<JobRecord>> jobs_in_states(const std::vector<JobState>& states) override {
    std::lock_guard lock(mu_);
    std::string sql = std::string("SELECT ") + kJobColumns + " FROM jobs WHERE state IN (";
    for (std::size_t i = 0; i < states.size(); ++i) sql += i == 0 ? "?" : ", ?";
    sql += ") ORDER BY created_ms, rowid";
    Statement q(db_.get(), sql.c_str());
    for (JobState s : states) q.text(job_state_name(s));
    return read_jobs(q, "listing unfinished jobs");
  }

  Result<UnfinishedJobs> count_unfinished_jobs(const std::string& tenant) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(),
                "SELECT COALESCE(SUM(state = 'queued'), 0), COALESCE(SUM(state = 'running'), 0), "
                "COALESCE(SUM(tenant = ?), 0) FROM jobs WHERE state IN ('queued', 'running')");
    q.text(tenant);
    if (q.step() != SQLITE_ROW) return error("counting unfinished jobs");
    return UnfinishedJobs{q.column_int(0), q.column_int(1), q.column_int(2)};
  }

  // One process uses a SQLite store, and it holds mu_ for each of these:
  // the transactions make each one all or nothing.
  Result<std::optional<JobRecord>> claim_job(const std::string& owner, std::int64_t lease_ms) override {
    std::lock_guard lock(mu_);
    return in_transaction("claiming a job", [&]() -> Result<std::optional<JobRecord>> {
      const std::int64_t now = clock_->now_ms();
      Statement q(db_.get(), (std::string("SELECT ") + kJobColumns +
                              " FROM jobs WHERE (state = 'queued' OR (state = 'running' AND lease_until_ms < ?)) "
                              "AND kind IN (" + known_job_kinds_sql() + ") ORDER BY created_ms, rowid LIMIT 1")
                                 .c_str());
      q.integer(now);
      const int rc = q.step();
      if (rc == SQLITE_DONE) return std::optional<JobRecord>();
      if (rc != SQLITE_ROW) return error("claiming a job");
      JobRecord job = read_job(q);
      job.state = JobState::kRunning;
      job.owner = owner;
      job.lease_until_ms = now + lease_ms;
      if (job.started_ms == 0) job.started_ms = now;
      ++job.attempts;
      Statement claim(db_.get(),
                      "UPDATE jobs SET state = 'running', owner = ?, lease_until_ms = ?, started_ms = ?, attempts = ? "
                      "WHERE id = ?");
      claim.text(job.owner).integer(job.lease_until_ms).integer(job.started_ms).integer(job.attempts).text(job.id);
      RICCATI_RETURN_IF_ERROR(done(claim, "claiming job " + job.id));
      return std::optional<JobRecord>(std::move(job));
    });
  }

  Result<bool> renew_job(const JobRecord& p, const std::string& owner, std::int64_t lease_ms) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(),
                "UPDATE jobs SET lease_until_ms = ?, pass = ?, passes = ?, sample = ?, samples = ?, theta = ?, "
                "iteration = ?, cost = ? WHERE id = ? AND owner = ? AND state = 'running' RETURNING cancel_requested");
    q.integer(clock_->now_ms() + lease_ms).integer(p.pass).integer(p.passes).integer(p.sample).integer(p.samples)
        .blob(to_blob(p.theta.data(), p.theta.size())).integer(p.iteration).real(p.cost).text(p.id).text(owner);
    if (!q.prepared()) return error("renewing the lease of job " + p.id);
    const int rc = q.step();
    if (rc == SQLITE_DONE) return job_lease_lost(p.id, owner);
    if (rc != SQLITE_ROW) return error("renewing the lease of job " + p.id);
    const bool cancel = q.column_int(0) != 0;
    if (q.step() != SQLITE_DONE) return error("renewing the lease of job " + p.id);
    return cancel;
  }

  Status finish_job(const JobRecord& j, const std::string& owner, const std::string* result) override {
    std::lock_guard lock(mu_);
    if (result != nullptr) {
      RICCATI_RETURN_IF_ERROR(room_for_new_data("storing the result of job " + j.id, result->size()));
    }
    return in_transaction("ending job " + j.id, [&]() -> Status {
      Statement q(db_.get(),
                  "UPDATE jobs SET state = ?, pass = ?, passes = ?, sample = ?, samples = ?, theta = ?, error_code = ?, "
                  "error_message = ?, finished_ms = ?, lease_until_ms = 0, iteration = ?, cost = ? WHERE id = ? AND "
                  "owner = ? AND state = 'running'");
      q.text(job_state_name(j.state)).integer(j.pass).integer(j.passes).integer(j.sample).integer(j.samples)
          .blob(to_blob(j.theta.data(), j.theta.size())).integer(j.error_code).text(j.error_message)
          .integer(j.finished_ms).integer(j.iteration).real(j.cost).text(j.id).text(owner);
      RICCATI_RETURN_IF_ERROR(done(q, "ending job " + j.id));
      if (sqlite3_changes(db_.get()) == 0) return job_lease_lost(j.id, owner);
      if (result == nullptr) return Status::ok();
      Statement r(db_.get(), "INSERT INTO results (job_id, tenant, result) SELECT id, tenant, ? FROM jobs WHERE id = ?");
      r.blob(*result).text(j.id);
      return done(r, "storing the result of job " + j.id);
    });
  }

  Result<int> release_jobs(const std::string& owner, bool stopped) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(),
                "UPDATE jobs SET state = 'queued', owner = '', lease_until_ms = 0, attempts = CASE WHEN ? THEN "
                "max(attempts - 1, 0) ELSE attempts END WHERE state = 'running' AND (? = '' OR owner = ?)");
    q.integer(stopped ? 1 : 0).text(owner).text(owner);
    RICCATI_RETURN_IF_ERROR(done(q, "releasing the jobs of " + (owner.empty() ? std::string("every instance") : owner)));
    return sqlite3_changes(db_.get());
  }

  Result<JobRecord> cancel_job(const std::string& tenant, const std::string& id) override {
    {
      std::lock_guard lock(mu_);
      Statement q(db_.get(),
                  "UPDATE jobs SET cancel_requested = 1, state = CASE state WHEN 'queued' THEN 'cancelled' ELSE state "
                  "END, error_code = CASE state WHEN 'queued' THEN ? ELSE error_code END, error_message = CASE state "
                  "WHEN 'queued' THEN 'cancelled before it started' ELSE error_message END, finished_ms = CASE state "
                  "WHEN 'queued' THEN ? ELSE finished_ms END WHERE id = ? AND tenant = ? AND state IN ('queued', "
                  "'running')");
      q.integer(static_cast<int>(StatusCode::kCancelled)).integer(clock_->now_ms()).text(id).text(tenant);
      RICCATI_RETURN_IF_ERROR(done(q, "cancelling job " + id));
    }
    return get_job(tenant, id);
  }

  Status delete_job(const std::string& tenant, const std::string& id) override {
    std::lock_guard lock(mu_);
    RICCATI_RETURN_IF_ERROR(with_reserve([&] {
      Statement q(db_.get(), "DELETE FROM jobs WHERE id = ? AND tenant = ? AND state IN " RICCATI_ENDED_STATES_SQL);
      q.text(id).text(tenant);
      return done(q, "deleting job " + id);
    }));
    if (sqlite3_changes(db_.get()) > 0) return Status::ok();
    Statement state(db_.get(), "SELECT state FROM jobs WHERE id = ? AND tenant = ?");
    state.text(id).text(tenant);
    const int rc = state.step();
    if (rc == SQLITE_DONE) return not_found("no job " + id);
    if (rc != SQLITE_ROW) return error("deleting job " + id);
    return job_not_ended(id, state.column_text(0));
  }

  Result<int> delete_ended_jobs(std::int64_t finished_before_ms, std::int64_t keep_per_tenant) override {
    std::lock_guard lock(mu_);
    int deleted = 0;
    const Status stored = with_reserve([&]() -> Status {
      Statement q(db_.get(),
                  "DELETE FROM jobs WHERE state IN " RICCATI_ENDED_STATES_SQL " AND (finished_ms < ? OR id IN (SELECT id "
                  "FROM (SELECT id, ROW_NUMBER() OVER (PARTITION BY tenant ORDER BY finished_ms DESC, id DESC) AS newer "
                  "FROM jobs WHERE state IN " RICCATI_ENDED_STATES_SQL ") WHERE newer > ?))");
      q.integer(finished_before_ms).integer(keep_per_tenant);
      RICCATI_RETURN_IF_ERROR(done(q, "deleting old jobs"));
      deleted = sqlite3_changes(db_.get());
      return Status::ok();
    });
    if (!stored.is_ok()) return stored;
    return deleted;
  }

  Result<std::int64_t> result_size(const std::string& tenant, const std::string& job_id) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(), "SELECT length(result) FROM results WHERE tenant = ? AND job_id = ?");
    q.text(tenant).text(job_id);
    const int rc = q.step();
    if (rc == SQLITE_DONE) return not_found("no result for job " + job_id);
    if (rc != SQLITE_ROW) return error("reading the size of the result of job " + job_id);
    return q.column_int(0);
  }

  Result<std::int64_t> result_bytes(const std::string& tenant) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(), "SELECT COALESCE(SUM(length(result)), 0) FROM results WHERE tenant = ?");
    q.text(tenant);
    if (q.step() != SQLITE_ROW) return error("reading the size of the results");
    return q.column_int(0);
  }

  Result<StoreUsage> usage() override {
    std::lock_guard lock(mu_);
    StoreUsage usage;
    Statement q(db_.get(),
                "SELECT (SELECT page_count FROM pragma_page_count()) * (SELECT page_size FROM pragma_page_size()), "
                "(SELECT COALESCE(SUM(size_bytes), 0) FROM datasets), "
                "(SELECT COALESCE(SUM(length(result)), 0) FROM results)");
    if (q.step() != SQLITE_ROW) return error("reading the store's size");
    usage.database_bytes = q.column_int(0);
    usage.dataset_bytes = q.column_int(1);
    usage.result_bytes = q.column_int(2);
    return usage;
  }

  Status put_result(const std::string& tenant, const std::string& job_id, const std::string& result) override {
    std::lock_guard lock(mu_);
    RICCATI_RETURN_IF_ERROR(room_for_new_data("storing the result of job " + job_id, result.size()));
    // Through the job's row, so that a result belongs to its job's tenant.
    Statement q(db_.get(),
                "INSERT INTO results (job_id, tenant, result) SELECT id, tenant, ? FROM jobs WHERE id = ? AND tenant = ?");
    q.blob(result).text(job_id).text(tenant);
    RICCATI_RETURN_IF_ERROR(done(q, "storing the result of job " + job_id));
    if (sqlite3_changes(db_.get()) == 0) return not_found("no job " + job_id);
    return Status::ok();
  }

  Result<std::string> get_result(const std::string& tenant, const std::string& job_id) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(), "SELECT result FROM results WHERE job_id = ? AND tenant = ?");
    q.text(job_id).text(tenant);
    const int rc = q.step();
    if (rc == SQLITE_DONE) return not_found("no result for job " + job_id);
    if (rc != SQLITE_ROW) return error("reading the result of job " + job_id);
    return q.column_blob(0);
  }

  Status put_job_pass(const std::string& tenant, const std::string& job_id, int pass,
                      const std::string& record) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(),
                "INSERT INTO job_passes (job_id, pass, tenant, record) SELECT id, ?, tenant, ? FROM jobs WHERE id = ? "
                "AND tenant = ? ON CONFLICT (job_id, pass) DO UPDATE SET record = excluded.record");
    q.integer(pass).blob(record).text(job_id).text(tenant);
    RICCATI_RETURN_IF_ERROR(done(q, "storing pass " + std::to_string(pass) + " of job " + job_id));
    if (sqlite3_changes(db_.get()) == 0) return not_found("no job " + job_id);
    return Status::ok();
  }

  Result<std::vector<std::string>> list_job_passes(const std::string& tenant, const std::string& job_id) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(), "SELECT record FROM job_passes WHERE job_id = ? AND tenant = ? ORDER BY pass");
    q.text(job_id).text(tenant);
    std::vector<std::string> records;
    int rc;
    while ((rc = q.step()) == SQLITE_ROW) records.push_back(q.column_blob(0));
    if (rc != SQLITE_DONE) return error("reading the passes of job " + job_id);
    return records;
  }

  // Sessions: as for jobs, one process uses a SQLite store and holds mu_
  // for each call; the transactions make each one all or nothing.
  Result<std::vector<Status>> put_session_snapshots(const std::string& owner, std::int64_t lease_ms,
                                                    const std::vector<SessionSnapshotWrite>& batch) override {
    std::lock_guard lock(mu_);
    const std::string doing = batch.size() == 1 ? "storing the snapshot of session " + std::string(batch[0].session_id)
                                                : "storing " + std::to_string(batch.size()) + " session snapshots";
    return in_transaction(doing, [&]() -> Result<std::vector<Status>> {
      const std::int64_t now = clock_->now_ms();
      Statement q(db_.get(), "SELECT tenant, owner, " RICCATI_SQLITE_SESSION_LEASE_UNTIL
                             " FROM session_snapshots WHERE session_id = ?");
      Statement w(db_.get(),
                  "INSERT INTO session_snapshots (session_id, tenant, snapshot, updated_ms, owner, lease_until_ms) "
                  "VALUES (?, ?, ?, ?, ?, ?) ON CONFLICT (session_id) DO UPDATE SET snapshot = excluded.snapshot, "
                  "updated_ms = excluded.updated_ms, owner = excluded.owner, lease_until_ms = excluded.lease_until_ms");
      std::vector<Status> stored;
      stored.reserve(batch.size());
      for (const SessionSnapshotWrite& s : batch) {
        const std::string id(s.session_id);
        const std::string storing = "storing the snapshot of session " + id;
        q.reset();
        q.text(s.session_id);
        const int rc = q.step();
        if (rc == SQLITE_ROW) {
          if (q.column_text(0) != s.tenant) {  // another tenant's id
            stored.push_back(not_found("no session " + id));
            continue;
          }
          if (q.column_text(1) != owner && q.column_int(2) > now) {
            stored.push_back(session_lease_lost(id, owner));
            continue;
          }
        } else if (rc != SQLITE_DONE) {
          return error(storing);
        }
        w.reset();
        w.text(s.session_id).text(s.tenant).blob(s.snapshot).integer(now).text(owner).integer(now + lease_ms);
        RICCATI_RETURN_IF_ERROR(done(w, storing));
        stored.push_back(Status::ok());
      }
      return stored;
    });
  }

  Result<std::string> claim_session_snapshot(const std::string& tenant, const std::string& session_id,
                                             const std::string& owner, std::int64_t lease_ms) override {
    std::lock_guard lock(mu_);
    const std::string doing = "claiming session " + session_id;
    return in_transaction(doing, [&]() -> Result<std::string> {
      const std::int64_t now = clock_->now_ms();
      Statement q(db_.get(), "SELECT owner, " RICCATI_SQLITE_SESSION_LEASE_UNTIL
                             ", snapshot FROM session_snapshots WHERE session_id = ? AND tenant = ?");
      q.text(session_id).text(tenant);
      const int rc = q.step();
      if (rc == SQLITE_DONE) return not_found("no session " + session_id);
      if (rc != SQLITE_ROW) return error(doing);
      const std::string holder = q.column_text(0);
      const std::int64_t until = q.column_int(1);
      if (holder != owner && until > now) return session_held_elsewhere(session_id, holder, until - now);
      std::string snapshot = q.column_blob(2);
      Statement w(db_.get(), "UPDATE session_snapshots SET owner = ?, lease_until_ms = ? WHERE session_id = ?");
      w.text(owner).integer(now + lease_ms).text(session_id);
      RICCATI_RETURN_IF_ERROR(done(w, doing));
      return snapshot;
    });
  }

  Result<int> renew_session_leases(const std::string& owner, std::int64_t lease_ms) override {
    std::lock_guard lock(mu_);
    const std::string doing = "renewing the session leases of " + owner;
    return in_transaction(doing, [&]() -> Result<int> {
      Statement w(db_.get(),
                  "INSERT INTO session_owner_leases (owner, lease_until_ms) VALUES (?, ?) ON CONFLICT (owner) DO "
                  "UPDATE SET lease_until_ms = excluded.lease_until_ms");
      w.text(owner).integer(clock_->now_ms() + lease_ms);
      RICCATI_RETURN_IF_ERROR(done(w, doing));
      Statement q(db_.get(), "SELECT count(*) FROM session_snapshots WHERE owner = ? AND lease_until_ms > 0");
      q.text(owner);
      if (q.step() != SQLITE_ROW) return error(doing);
      return static_cast<int>(q.column_int(0));
    });
  }

  Result<int> release_sessions(const std::string& owner) override {
    std::lock_guard lock(mu_);
    const std::string doing =
        "releasing the sessions of " + (owner.empty() ? std::string("every instance") : owner);
    return in_transaction(doing, [&]() -> Result<int> {
      Statement q(db_.get(),
                  "UPDATE session_snapshots SET lease_until_ms = 0 WHERE lease_until_ms > 0 AND (? = '' OR owner = ?)");
      q.text(owner).text(owner);
      RICCATI_RETURN_IF_ERROR(done(q, doing));
      const int released = sqlite3_changes(db_.get());
      Statement d(db_.get(), "DELETE FROM session_owner_leases WHERE ? = '' OR owner = ?");
      d.text(owner).text(owner);
      RICCATI_RETURN_IF_ERROR(done(d, doing));
      return released;
    });
  }

  Status delete_session_snapshot(const std::string& tenant, const std::string& session_id,
                                 const std::string& owner) override {
    std::lock_guard lock(mu_);
    const std::string doing = "deleting the snapshot of session " + session_id;
    return in_transaction(doing, [&]() -> Status {
      Statement q(db_.get(), "SELECT owner, " RICCATI_SQLITE_SESSION_LEASE_UNTIL
                             " FROM session_snapshots WHERE session_id = ? AND tenant = ?");
      q.text(session_id).text(tenant);
      const int rc = q.step();
      if (rc == SQLITE_DONE) return not_found("no snapshot of session " + session_id);
      if (rc != SQLITE_ROW) return error(doing);
      if (q.column_text(0) != owner && q.column_int(1) > clock_->now_ms()) return session_lease_lost(session_id, owner);
      Statement d(db_.get(), "DELETE FROM session_snapshots WHERE session_id = ?");
      d.text(session_id);
      return done(d, doing);
    });
  }

  Result<std::vector<SessionSnapshotRecord>> list_session_snapshots(const std::string& tenant) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(),
                "SELECT session_id, CASE WHEN " RICCATI_SQLITE_SESSION_LEASE_UNTIL " > ? THEN owner ELSE '' END, snapshot "
                "FROM session_snapshots WHERE tenant = ? ORDER BY session_id");
    q.integer(clock_->now_ms()).text(tenant);
    std::vector<SessionSnapshotRecord> records;
    int rc;
    while ((rc = q.step()) == SQLITE_ROW) records.push_back({q.column_text(0), q.column_text(1), q.column_blob(2)});
    if (rc != SQLITE_DONE) return error("listing the session snapshots of " + tenant);
    return records;
  }

  Result<int> delete_abandoned_session_snapshots(std::int64_t idle_ms) override {
    std::lock_guard lock(mu_);
    const std::int64_t now = clock_->now_ms();
    Statement q(db_.get(), "DELETE FROM session_snapshots WHERE " RICCATI_SQLITE_SESSION_LEASE_UNTIL
                           " <= ? AND updated_ms < ?");
    q.integer(now).integer(now - idle_ms);
    RICCATI_RETURN_IF_ERROR(done(q, "deleting abandoned session snapshots"));
    return sqlite3_changes(db_.get());
  }

  Result<ModelRecord> put_model(const ModelRecord& record) override {
    std::lock_guard lock(mu_);
    RICCATI_RETURN_IF_ERROR(room_for_new_data("storing model " + record.name, record.source.size()));
    // One statement, under the store's lock: the next revision cannot be taken twice.
    Statement q(db_.get(),
                "INSERT INTO models (tenant, name, revision, source, sha256, created_ms, deleted) SELECT ?, ?, "
                "coalesce(max(revision), 0) + 1, ?, ?, ?, 0 FROM models WHERE tenant = ? AND name = ? RETURNING revision");
    q.text(record.tenant).text(record.name).blob(record.source).text(record.sha256).integer(record.created_ms)
        .text(record.tenant).text(record.name);
    if (q.step() != SQLITE_ROW) return error("storing model " + record.name);
    ModelRecord out = record;
    out.revision = q.column_int(0);
    out.deleted = false;
    RICCATI_RETURN_IF_ERROR(done(q, "storing model " + record.name));
    return out;
  }

  Result<ModelRecord> get_model(const std::string& tenant, const std::string& name, std::int64_t revision) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(), revision > 0
                               ? "SELECT revision, source, sha256, created_ms, deleted FROM models WHERE tenant = ? AND "
                                 "name = ? AND revision = ?"
                               : "SELECT revision, source, sha256, created_ms, deleted FROM models WHERE tenant = ? AND "
                                 "name = ? AND deleted = 0 ORDER BY revision DESC LIMIT 1");
    q.text(tenant).text(name);
    if (revision > 0) q.integer(revision);
    const int rc = q.step();
    const std::string which = revision > 0 ? name + "@" + std::to_string(revision) : name;
    if (rc == SQLITE_DONE) return not_found("no model \"" + which + "\"");
    if (rc != SQLITE_ROW) return error("reading model " + which);
    ModelRecord r;
    r.tenant = tenant;
    r.name = name;
    r.revision = q.column_int(0);
    r.source = q.column_blob(1);
    r.sha256 = q.column_text(2);
    r.created_ms = q.column_int(3);
    r.deleted = q.column_int(4) != 0;
    return r;
  }

  Result<std::vector<ModelRecord>> list_models(const std::string& tenant) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(),
                "SELECT name, revision, source, sha256, created_ms FROM models m WHERE tenant = ? AND deleted = 0 AND "
                "revision = (SELECT max(revision) FROM models WHERE tenant = m.tenant AND name = m.name) ORDER BY name");
    q.text(tenant);
    std::vector<ModelRecord> out;
    int rc;
    while ((rc = q.step()) == SQLITE_ROW) {
      ModelRecord r;
      r.tenant = tenant;
      r.name = q.column_text(0);
      r.revision = q.column_int(1);
      r.source = q.column_blob(2);
      r.sha256 = q.column_text(3);
      r.created_ms = q.column_int(4);
      out.push_back(std::move(r));
    }
    if (rc != SQLITE_DONE) return error("listing models");
    return out;
  }

  Status delete_model(const std::string& tenant, const std::string& name) override {
    std::lock_guard lock(mu_);
    return with_reserve([&]() -> Status {
      Statement q(db_.get(), "UPDATE models SET deleted = 1 WHERE tenant = ? AND name = ? AND deleted = 0");
      q.text(tenant).text(name);
      RICCATI_RETURN_IF_ERROR(done(q, "deleting model " + name));
      if (sqlite3_changes(db_.get()) == 0) return not_found("no model \"" + name + "\"");
      return Status::ok();
    });
  }

  Result<int> purge_unused_models() override {
    std::lock_guard lock(mu_);
    int purged = 0;
    const Status stored = with_reserve([&]() -> Status {
      // The newest revision of a name stays, its source emptied, so that
      // the name's next upload takes the next number (name@3 is one source).
      Statement q(db_.get(), "DELETE FROM models WHERE deleted = 1 AND NOT EXISTS (" RICCATI_MODEL_NAMED_BY_A_JOB
                             ") AND revision < (SELECT max(m.revision) FROM models m WHERE m.tenant = models.tenant "
                             "AND m.name = models.name)");
      RICCATI_RETURN_IF_ERROR(done(q, "purging deleted models"));
      purged = sqlite3_changes(db_.get());
      Statement empty(db_.get(), "UPDATE models SET source = x'' WHERE deleted = 1 AND length(source) > 0 AND NOT "
                                 "EXISTS (" RICCATI_MODEL_NAMED_BY_A_JOB ")");
      RICCATI_RETURN_IF_ERROR(done(empty, "purging deleted models"));
      purged += sqlite3_changes(db_.get());
      return Status::ok();
    });
    if (!stored.is_ok()) return stored;
    return purged;
  }

  Result<std::vector<ModelRevision>> list_model_revisions(const std::string& tenant) override {
    std::lock_guard lock(mu_);
    Statement q(db_.get(),
                "SELECT name, revision, length(source) FROM models WHERE tenant = ? AND deleted = 0 "
                "ORDER BY name, revision");
    q.text(tenant);
    std::vector<ModelRevision> out;
    int rc;
    while ((rc = q.step()) == SQLITE_ROW) out.push_back({q.column_text(0), q.column_int(1), q.column_int(2)});
    if (rc != SQLITE_DONE) return error("listing model revisions");
    return out;
  }

 private:
  // Runs `body` in a write transaction (mu_ held by the caller): committed if
  // it returns ok, rolled back otherwise.
  template <typename F>
  auto in_transaction(const std::string& doing, F&& body) -> std::invoke_result_t<F&> {
    if (sqlite3_exec(db_.get(), "BEGIN IMMEDIATE", nullptr, nullptr, nullptr) != SQLITE_OK) return error(doing);
    auto out = body();
    Status ended = Status::ok();
    if (out.is_ok() && sqlite3_exec(db_.get(), "COMMIT", nullptr, nullptr, nullptr) != SQLITE_OK) ended = error(doing);
    if (!out.is_ok() || !ended.is_ok()) {
      // A failed COMMIT may leave the transaction open: end it either way.
      if (sqlite3_get_autocommit(db_.get()) == 0) (void)sqlite3_exec(db_.get(), "ROLLBACK", nullptr, nullptr, nullptr);
      make_room();
    }
    if (!ended.is_ok()) return ended;
    return out;
  }


  Status exec(const std::string& sql) {
    char* message = nullptr;
    if (sqlite3_exec(db_.get(), sql.c_str(), nullptr, nullptr, &message) != SQLITE_OK) {
      const std::string what = message != nullptr ? message : sqlite3_errmsg(db_.get());
      sqlite3_free(message);
      return failure("running " + sql.substr(0, sql.find_first_of(" \n")), what);
    }
    return Status::ok();
  }

  Status error(const std::string& doing) { return failure(doing, sqlite3_errmsg(db_.get())); }
  // A value refused when bound: its own code and message, not the
  // connection's (which a later bind may have reset).
  Status bind_failure(int rc, const std::string& doing) { return failure(doing, sqlite3_errstr(rc), rc); }

  // What a failed call means to the caller. A store that cannot grow (a full
  // disk or quota, or a file at the daemon's file size limit) is
  // RESOURCE_EXHAUSTED: the client can free room (delete datasets or jobs)
  // and try again. A value over SQLite's size limit (SQLITE_TOOBIG) is
  // RESOURCE_EXHAUSTED too, saying so. Anything else is INTERNAL. Either way
  // the database's path stays in the daemon's log and out of what clients see.
  // `code`: SQLite's (extended) code; -1: the connection's last.
  Status failure(const std::string& doing, const std::string& what, int code = -1) {
    if (code < 0) code = sqlite3_extended_errcode(db_.get());
    const int primary = code & 0xff;
    std::string cause;
    if (primary == SQLITE_FULL || primary == SQLITE_IOERR) cause = no_room_cause();
    if (primary == SQLITE_FULL && cause.empty()) cause = "database or disk is full";
    spdlog::error("store failed database={} doing=\"{}\" error=\"{}\" sqlite_code={}{}", path_, doing, what, code,
                  cause.empty() ? "" : " cause=\"" + cause + "\"");
    if (primary == SQLITE_TOOBIG) {
      return {StatusCode::kResourceExhausted, "the store failed " + doing + ": " + what + " (SQLite stores at most " +
                                                  std::to_string(sqlite3_limit(db_.get(), SQLITE_LIMIT_LENGTH, -1)) +
                                                  " bytes in one value)"};
    }
    if (cause.empty()) {
      return internal_error("the store failed " + doing + ": " + what + " (the daemon's log has the details)");
    }
    room_needed_ = true;
    make_room();
    return {StatusCode::kResourceExhausted,
            "the store is full (" + cause + ") " + doing + ": delete datasets or jobs, or give the data directory room"};
  }

  // Why a write failed, when it can be told (SQLite keeps no errno for a
  // failed write): the file system has no room left, or a database file is at
  // the process's file size limit. Empty when neither.
  std::string no_room_cause() const {
    constexpr std::uintmax_t kSlack = 1 << 20;  // a transaction's pages, a frame written in part
    const std::filesystem::path db(path_);
    struct statvfs fs {};
    if (statvfs(db.parent_path().c_str(), &fs) == 0 && std::uintmax_t(fs.f_bavail) * fs.f_frsize < kSlack) {
      return "no space left on the device";
    }
    rlimit limit{};
    if (getrlimit(RLIMIT_FSIZE, &limit) == 0 && limit.rlim_cur != RLIM_INFINITY) {
      for (const char* suffix : {"", "-wal", "-journal"}) {
        std::error_code ec;
        const std::uintmax_t size = std::filesystem::file_size(path_ + suffix, ec);
        if (!ec && size + kSlack >= limit.rlim_cur) {
          return std::string(*suffix == '\0' ? "the database" : "its write-ahead log") +
                 " reached the daemon's file size limit, " + std::to_string(limit.rlim_cur) + " bytes";
        }
      }
    }
    return {};
  }

  // After a write that found no room, and once no transaction is open: the
  // write-ahead log is copied into the database and truncated. The log only
  // grows until a checkpoint, which SQLite runs after a commit that takes it
  // past 1000 pages, so a log stopped short of that by a full disk or a size
  // limit would otherwise stay full and refuse even the deletions that make
  // room.
  // Room kept on the data directory's file system for the writes that make
  // room: on a disk that is really full, SQLite cannot even delete (the
  // deletion's pages go to the write-ahead log first, which cannot grow,
  // and copying the log into the database may need to grow that too). A
  // file of kReserveBytes beside the database holds that room; a deletion
  // that finds no room removes it, checkpoints and tries again, and the
  // reserve is made again once the file system has room for it and more.
  static constexpr std::uintmax_t kReserveBytes = 4 << 20;

  std::string reserve_path() const { return path_ + "-reserve"; }

  // Makes the reserve if it is missing and there is room for it and a
  // margin (so that making it does not itself fill the disk: what is left
  // takes new data, which waits for the reserve, room_for_new_data).
  static constexpr std::uintmax_t kReserveMargin = 1 << 20;
  void keep_reserve() {
    if (reserve_present()) {
      reserve_made_ = true;
      return;
    }
    std::error_code ec;
    struct statvfs fs {};
    if (statvfs(std::filesystem::path(path_).parent_path().c_str(), &fs) != 0 ||
        std::uintmax_t(fs.f_bavail) * fs.f_frsize < kReserveBytes + kReserveMargin) {
      return;
    }
    const int fd = ::open(reserve_path().c_str(), O_WRONLY | O_CREAT | O_CLOEXEC, 0600);
    if (fd < 0) return;
    const int rc = posix_fallocate(fd, 0, static_cast<off_t>(kReserveBytes));
    ::close(fd);
    if (rc != 0) {
      std::filesystem::remove(reserve_path(), ec);
      return;
    }
    reserve_made_ = true;
    spdlog::info("store reserve in place file={} bytes={}", reserve_path(), kReserveBytes);
  }

  // Runs `op` (a write that makes room, mu_ held); if it finds no room, gives
  // the reserve back to the file system and runs it once more.
  template <typename Op>
  Status with_reserve(Op&& op) {
    Status first = op();
    if (first.code() != StatusCode::kResourceExhausted) {
      if (first.is_ok()) reclaim();
      return first;
    }
    std::error_code ec;
    if (!std::filesystem::remove(reserve_path(), ec)) return first;  // no reserve left
    spdlog::warn("store reserve given back to delete on a full disk file={} bytes={}", reserve_path(), kReserveBytes);
    room_needed_ = true;
    make_room();
    Status second = op();
    if (second.is_ok()) reclaim();
    return second;
  }

  void make_room() {
    if (!room_needed_ || sqlite3_get_autocommit(db_.get()) == 0) return;
    room_needed_ = false;
    const int rc = sqlite3_wal_checkpoint_v2(db_.get(), nullptr, SQLITE_CHECKPOINT_TRUNCATE, nullptr, nullptr);
    if (rc == SQLITE_OK) {
      spdlog::info("store log checkpointed and truncated after a failed write database={}", path_);
    } else {
      spdlog::warn("store log checkpoint failed database={} error=\"{}\"", path_, sqlite3_errmsg(db_.get()));
    }
  }

  // Deleted rows' pages given back to the file system, not only to SQLite's
  // free list (auto_vacuum = INCREMENTAL, and PRAGMA incremental_vacuum after
  // each deletion): on a full disk, the room a deletion frees is room for the
  // reserve again, and under a file size limit the database shrinks below it,
  // so that the log's commits can be copied into it. Set before the first
  // table of a new database; an older one is rebuilt (VACUUM) at start when
  // the disk has room for a copy of it, else it stays as it was, logged.
  Status use_incremental_vacuum() {
    Statement mode(db_.get(), "PRAGMA auto_vacuum");
    if (mode.step() != SQLITE_ROW) return error("reading auto_vacuum");
    if (mode.column_int(0) == 2) return Status::ok();
    Statement tables(db_.get(), "SELECT count(*) FROM sqlite_master");
    if (tables.step() != SQLITE_ROW) return error("reading the schema");
    if (tables.column_int(0) == 0) return exec("PRAGMA auto_vacuum = INCREMENTAL");
    std::error_code ec;
    const std::uintmax_t size = std::filesystem::file_size(path_, ec);
    struct statvfs fs {};
    if (ec || statvfs(std::filesystem::path(path_).parent_path().c_str(), &fs) != 0 ||
        std::uintmax_t(fs.f_bavail) * fs.f_frsize < 2 * size + 2 * kReserveBytes) {
      spdlog::warn("store not rebuilt for incremental vacuum (no room for a copy of it) database={}: deletions on a "
                   "full disk free room inside the database, not on the disk",
                   path_);
      return Status::ok();
    }
    const auto started = std::chrono::steady_clock::now();
    RICCATI_RETURN_IF_ERROR(exec("PRAGMA auto_vacuum = INCREMENTAL"));
    RICCATI_RETURN_IF_ERROR(exec("VACUUM"));
    spdlog::info("store rebuilt for incremental vacuum database={} bytes={} ms={}", path_, size,
                 std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::steady_clock::now() - started).count());
    return Status::ok();
  }

  // After a deletion: its free pages given back to the file system (the log
  // then checkpointed and truncated, which is when the database file
  // shrinks), and the reserve made again if it was used. Best effort: a
  // deletion that was stored stays stored.
  void reclaim() {
    if (sqlite3_exec(db_.get(), "PRAGMA incremental_vacuum", nullptr, nullptr, nullptr) != SQLITE_OK) {
      spdlog::warn("store incremental vacuum failed database={} error=\"{}\"", path_, sqlite3_errmsg(db_.get()));
    }
    if (reserve_made_ && !reserve_present()) {
      room_needed_ = true;
      make_room();
      keep_reserve();
    }
  }

  bool reserve_present() const {
    std::error_code ec;
    return std::filesystem::file_size(reserve_path(), ec) >= kReserveBytes && !ec;
  }

  // Before a write that stores new data (a dataset, a result, a model) of
  // about `bytes`: once the reserve has been used, no new data is stored
  // until it is made again, so that the room deletions free goes to the
  // reserve first; and, with a reserve in place, the disk must have room for
  // the data twice (its copy in the write-ahead log, then in the database
  // when the log is copied into it) beside a margin. Otherwise the log fills
  // the disk with commits that can never be copied into the database, and
  // the reserve is too small for a deletion to get past them.
  Status room_for_new_data(const std::string& doing, std::uintmax_t bytes) {
    if (!reserve_made_) return Status::ok();  // a disk never had room for one; or a file size limit
    if (!reserve_present()) keep_reserve();
    std::string missing;
    if (!reserve_present()) {
      missing = "but the " + std::to_string(kReserveBytes >> 20) + " MiB it keeps for deletions";
    } else {
      struct statvfs fs {};
      if (statvfs(std::filesystem::path(path_).parent_path().c_str(), &fs) == 0 &&
          std::uintmax_t(fs.f_bavail) * fs.f_frsize < 2 * bytes + kReserveMargin) {
        missing = "for " + std::to_string(bytes) + " bytes and their copy in the write-ahead log";
      }
    }
    if (missing.empty()) return Status::ok();
    spdlog::warn("store refused new data database={} doing=\"{}\" cause=\"no space left on the device {}\"", path_,
                 doing, missing);
    return {StatusCode::kResourceExhausted, "the store is full (no space left on the device " + missing + ") " +
                                                doing + ": delete datasets or jobs, or give the data directory room"};
  }

  // Runs a statement that returns no rows.
  Status done(Statement& s, const std::string& doing) {
    if (!s.prepared()) return error(doing);
    if (s.bind_error() != SQLITE_OK) return bind_failure(s.bind_error(), doing);
    const int rc = s.step();
    if (rc == SQLITE_DONE) return Status::ok();
    if (rc == SQLITE_CONSTRAINT) {
      return {StatusCode::kAlreadyExists, doing + ": " + sqlite3_errmsg(db_.get())};
    }
    return error(doing);
  }

  Result<std::vector<JobRecord>> read_jobs(Statement& q, const std::string& doing) {
    if (!q.prepared()) return error(doing);
    std::vector<JobRecord> out;
    int rc;
    while ((rc = q.step()) == SQLITE_ROW) out.push_back(read_job(q));
    if (rc != SQLITE_DONE) return error(doing);
    return out;
  }

  std::mutex mu_;  // one connection, one statement at a time
  std::unique_ptr<sqlite3, CloseDb> db_;
  const std::string path_;
  const std::shared_ptr<StoreClock> clock_;  // leases and stored times
  bool room_needed_ = false;  // a write found no room: make_room() once no transaction is open
  bool reserve_made_ = false;  // the reserve was in place once: new data waits for it when it is gone
};

}  // namespace

Result<std::unique_ptr<Store>> open_sqlite_store(const std::string& path, std::shared_ptr<StoreClock> clock) {
  // An empty file is what a truncated database looks like: starting a new
  // store over it would hide the loss, so the operator decides.
  std::error_code ec;
  if (std::filesystem::is_regular_file(path, ec) && std::filesystem::file_size(path, ec) == 0 && !ec) {
    return failed_precondition("database " + path +
                               " is an empty file (0 bytes), as a truncated one would be: restore it from a backup, or "
                               "remove it to start a new, empty store");
  }
  sqlite3* raw = nullptr;
  const int rc = sqlite3_open_v2(path.c_str(), &raw, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_FULLMUTEX,
                                 nullptr);
  std::unique_ptr<sqlite3, CloseDb> db(raw);
  if (rc != SQLITE_OK) {
    return failed_precondition("cannot open database " + path + ": " +
                               (raw != nullptr ? sqlite3_errmsg(raw) : sqlite3_errstr(rc)));
  }
  if (clock == nullptr) clock = std::make_shared<SystemStoreClock>();
  auto store = std::make_unique<SqliteStore>(std::move(db), path, std::move(clock));
  RICCATI_RETURN_IF_ERROR(store->check_integrity());
  RICCATI_RETURN_IF_ERROR(store->migrate());
  store->keep_reserve_at_start();
  return std::unique_ptr<Store>(std::move(store));
}

}  // namespace riccati
