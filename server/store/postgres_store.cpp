// The PostgreSQL store: a small pool of connections, versioned migrations
// under an advisory lock, samples as exact BYTEA.
#include "store/postgres_store.hpp"

#include <spdlog/spdlog.h>

#include <condition_variable>
#include <cstring>
#include <memory>
#include <mutex>
#include <pqxx/pqxx>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

namespace riccati {

namespace {

// Migrations, applied in order at start; riccati_schema_migrations lists
// those applied. Append only: never edit one that has shipped.
const std::vector<const char*> kMigrations = {
    // 1: the SQLite store's tables (its migrations 1 and 2), plus what
    // several riccatid sharing a database will need to claim jobs.
    R"sql(
    CREATE TABLE datasets (
      id TEXT PRIMARY KEY,
      tenant TEXT NOT NULL,
      name TEXT NOT NULL,
      format TEXT NOT NULL,
      input_names TEXT[] NOT NULL,
      output_names TEXT[] NOT NULL,
      samples BIGINT NOT NULL,
      t_start DOUBLE PRECISION NOT NULL,
      t_end DOUBLE PRECISION NOT NULL,
      size_bytes BIGINT NOT NULL,
      created_ms BIGINT NOT NULL,
      seq BIGINT GENERATED ALWAYS AS IDENTITY);  -- insertion order, among equal created_ms
    CREATE INDEX datasets_by_tenant ON datasets (tenant, created_ms, seq);
    CREATE TABLE dataset_samples (
      dataset_id TEXT PRIMARY KEY REFERENCES datasets (id) ON DELETE CASCADE,
      t BYTEA NOT NULL,
      u BYTEA NOT NULL,
      y BYTEA NOT NULL);
    -- Doubles hardly compress: keep them out of line without trying.
    ALTER TABLE dataset_samples ALTER COLUMN t SET STORAGE EXTERNAL, ALTER COLUMN u SET STORAGE EXTERNAL,
      ALTER COLUMN y SET STORAGE EXTERNAL;
    CREATE TABLE jobs (
      id TEXT PRIMARY KEY,
      tenant TEXT NOT NULL,
      kind TEXT NOT NULL,
      state TEXT NOT NULL CHECK (state IN ('queued', 'running', 'succeeded', 'failed', 'cancelled')),
      spec BYTEA NOT NULL,
      pass INTEGER NOT NULL,
      passes INTEGER NOT NULL,
      sample BIGINT NOT NULL,
      samples BIGINT NOT NULL,
      theta BYTEA NOT NULL,
      error_code INTEGER NOT NULL,
      error_message TEXT NOT NULL,
      created_ms BIGINT NOT NULL,
      started_ms BIGINT NOT NULL,
      finished_ms BIGINT NOT NULL,
      -- Not used yet: the instance running the job and until when its claim
      -- holds unless renewed, for several riccatid sharing the database.
      owner TEXT,
      lease_until_ms BIGINT,
      seq BIGINT GENERATED ALWAYS AS IDENTITY);
    CREATE INDEX jobs_by_tenant ON jobs (tenant, created_ms, seq);
    CREATE INDEX jobs_by_state ON jobs (state, created_ms, seq);
    CREATE TABLE results (
      job_id TEXT PRIMARY KEY REFERENCES jobs (id) ON DELETE CASCADE,
      tenant TEXT NOT NULL,
      result BYTEA NOT NULL);
    CREATE TABLE job_passes (
      job_id TEXT NOT NULL REFERENCES jobs (id) ON DELETE CASCADE,
      pass INTEGER NOT NULL,
      tenant TEXT NOT NULL,
      record BYTEA NOT NULL,
      PRIMARY KEY (job_id, pass));
    CREATE TABLE session_snapshots (
      session_id TEXT PRIMARY KEY,
      tenant TEXT NOT NULL,
      snapshot BYTEA NOT NULL,
      updated_ms BIGINT NOT NULL);
    )sql",
    // 2: the job queue: owner and lease in use, a cancel request, and an
    // index for the claim query (queued jobs, and running ones to take over).
    R"sql(
    UPDATE jobs SET owner = '' WHERE owner IS NULL;
    UPDATE jobs SET lease_until_ms = 0 WHERE lease_until_ms IS NULL;
    ALTER TABLE jobs ALTER COLUMN owner SET DEFAULT '', ALTER COLUMN owner SET NOT NULL,
      ALTER COLUMN lease_until_ms SET DEFAULT 0, ALTER COLUMN lease_until_ms SET NOT NULL,
      ADD COLUMN cancel_requested BOOLEAN NOT NULL DEFAULT false;
    CREATE INDEX jobs_claimable ON jobs (created_ms, seq) WHERE state IN ('queued', 'running');
    )sql",
    // 3: session snapshots held by an instance under a lease, as jobs are.
    R"sql(
    ALTER TABLE session_snapshots ADD COLUMN owner TEXT NOT NULL DEFAULT '',
      ADD COLUMN lease_until_ms BIGINT NOT NULL DEFAULT 0;
    CREATE INDEX session_snapshots_by_owner ON session_snapshots (owner);
    )sql",
    // 4: an optimiser's progress (output error, maximum likelihood).
    R"sql(
    ALTER TABLE jobs ADD COLUMN iteration INTEGER NOT NULL DEFAULT 0,
      ADD COLUMN cost DOUBLE PRECISION NOT NULL DEFAULT 0;
    )sql",
    // 5: how many times a job was claimed without ending (the retry budget).
    R"sql(
    ALTER TABLE jobs ADD COLUMN attempts INTEGER NOT NULL DEFAULT 0;
    )sql",
    // 6: clients' request ids, for idempotent creation (claim_request_id).
    R"sql(
    CREATE TABLE request_ids (
      tenant TEXT NOT NULL,
      request_id TEXT NOT NULL,
      kind TEXT NOT NULL,
      object_id TEXT NOT NULL,
      created_ms BIGINT NOT NULL,
      PRIMARY KEY (tenant, request_id));
    )sql",
    // 7: text models uploaded by tenants, every revision.
    R"sql(
    CREATE TABLE models (
      tenant TEXT NOT NULL,
      name TEXT NOT NULL,
      revision BIGINT NOT NULL,
      source BYTEA NOT NULL,
      sha256 TEXT NOT NULL,
      created_ms BIGINT NOT NULL,
      deleted BOOLEAN NOT NULL DEFAULT false,
      PRIMARY KEY (tenant, name, revision));
    )sql",
    // 8: each dataset's SHA-256 of its file as uploaded, so that a client
    // can reuse an identical upload ('' for datasets stored before).
    R"sql(
    ALTER TABLE datasets ADD COLUMN sha256 TEXT NOT NULL DEFAULT '';
    )sql",
    // 9: the parameters a dataset was made with, when its upload declared
    // them ("name=value" lines; '' for none).
    R"sql(
    ALTER TABLE datasets ADD COLUMN true_parameters TEXT NOT NULL DEFAULT '';
    )sql",
    // 10: one lease row per instance, renewed for all the sessions it holds
    // at once (RICCATI_PG_SESSION_LEASE_UNTIL): renewing each session's row
    // rewrote every snapshot's row. The partial index counts an owner's
    // held sessions.
    R"sql(
    CREATE TABLE session_owner_leases (
      owner TEXT PRIMARY KEY,
      lease_until_ms BIGINT NOT NULL);
    CREATE INDEX session_snapshots_held ON session_snapshots (owner) WHERE lease_until_ms > 0;
    )sql",
    // 11: the model each job's spec names, pinned (name@revision), so that
    // a deleted text model's revisions can be purged once no queued or
    // running job names them. Jobs stored before name none.
    R"sql(
    ALTER TABLE jobs ADD COLUMN model TEXT NOT NULL DEFAULT '';
    )sql",
};

// Leases are read against the database's clock, so that instances on hosts
// whose clocks disagree still agree on when a lease has expired; unless a
// clock was given at open (tests), whose time each operation sets on its
// connection first (riccati.now_ms, read here; unset, current_setting gives
// NULL, or '' once a session has had it reset).
#define RICCATI_PG_NOW_MS                                              \
  "coalesce(nullif(current_setting('riccati.now_ms', true), '')::bigint, " \
  "(extract(epoch FROM clock_timestamp()) * 1000)::bigint)"
// When a session's lease ends: 0 once released; else its own term (from its
// claim or last put) or its owner's renewed term, whichever is later.
#define RICCATI_PG_SESSION_LEASE_UNTIL                                                                  \
  "(CASE WHEN session_snapshots.lease_until_ms > 0 THEN GREATEST(session_snapshots.lease_until_ms, "  \
  "coalesce((SELECT o.lease_until_ms FROM session_owner_leases o WHERE o.owner = session_snapshots.owner), 0)) " \
  "ELSE 0 END)"

// The advisory lock every riccatid takes while it migrates, so that
// instances starting at once apply the migrations one after the other (the
// second then finds nothing to do). Any fixed key: "riccati" in ASCII.
constexpr std::int64_t kMigrationLock = 0x72696363617469;

// Connections open at once, at most. Store calls are short (a statement or
// two) but each is a network round trip, so a few connections let RPC
// threads and job workers overlap without loading the server.
constexpr std::size_t kPoolSize = 4;

// The first line of a libpq/libpqxx message, without "ERROR:  ".
std::string first_line(const char* what) {
  std::string s(what);
  s = s.substr(0, s.find('\n'));
  for (const char* prefix : {"ERROR:  ", "FATAL:  "}) {
    if (s.rfind(prefix, 0) == 0) s.erase(0, std::strlen(prefix));
  }
  while (!s.empty() && (s.back() == ' ' || s.back() == '\r')) s.pop_back();
  return s;
}

// Defaults that the URL may override: a name the server shows for our
// connections, and a bound on connecting to a host that does not answer
// (libpq would wait for the operating system's TCP timeout).
std::string with_default_params(const std::string& url) {
  const bool uri = url.rfind("postgresql://", 0) == 0 || url.rfind("postgres://", 0) == 0;
  std::string out = url;
  auto add = [&](const std::string& key, const std::string& value) {
    if (url.find(key + "=") != std::string::npos) return;
    if (uri) {
      out += out.find('?') == std::string::npos ? '?' : '&';
    } else if (!out.empty()) {
      out += ' ';
    }
    out += key + "=" + value;
  };
  add("fallback_application_name", "riccatid");
  add("connect_timeout", "10");
  return out;
}

// Doubles as raw little-endian bytes (x86-64 and ARM64 are both): exact.
pqxx::binarystring to_bytea(const double* v, std::size_t n) { return pqxx::binarystring(v, n * sizeof(double)); }

std::vector<double> doubles_of(const pqxx::field& f) {
  const pqxx::binarystring b(f);
  std::vector<double> out(b.size() / sizeof(double));
  if (!out.empty()) std::memcpy(out.data(), b.data(), out.size() * sizeof(double));
  return out;
}

std::string bytes_of(const pqxx::field& f) { return pqxx::binarystring(f).str(); }

// A TEXT[] literal: every element quoted, quotes and backslashes escaped.
std::string text_array(const std::vector<std::string>& items) {
  std::string out = "{";
  for (std::size_t i = 0; i < items.size(); ++i) {
    if (i > 0) out += ',';
    out += '"';
    for (char c : items[i]) {
      if (c == '"' || c == '\\') out += '\\';
      out += c;
    }
    out += '"';
  }
  return out + "}";
}

// A one-dimensional TEXT[] as PostgreSQL writes it: {a,"b c","q\"d",""}.
// Parsed here because libpqxx 6's array_parser also takes single quotes
// for quoting, which PostgreSQL never does, and so mangles 'x'.
std::vector<std::string> strings_of(const pqxx::field& f) {
  const std::string s = f.as<std::string>();
  std::vector<std::string> out;
  std::size_t i = s.find('{');
  if (i == std::string::npos) throw std::runtime_error("expected a text array, got " + s);
  if (++i < s.size() && s[i] == '}') return out;
  while (i < s.size()) {
    std::string item;
    if (s[i] == '"') {
      for (++i; i < s.size() && s[i] != '"'; ++i) {
        if (s[i] == '\\' && i + 1 < s.size()) ++i;
        item += s[i];
      }
      ++i;  // the closing quote
    } else {
      while (i < s.size() && s[i] != ',' && s[i] != '}') item += s[i++];
    }
    out.push_back(std::move(item));
    if (i >= s.size() || s[i] == '}') break;
    ++i;  // the comma
  }
  return out;
}

constexpr const char* kJobColumns =
    "id, tenant, kind, state, spec, pass, passes, sample, samples, theta, error_code, error_message, created_ms, "
    "started_ms, finished_ms, owner, lease_until_ms, cancel_requested, iteration, cost, attempts, model";

JobRecord read_job(const pqxx::row& r) {
  JobRecord j;
  j.id = r[0].as<std::string>();
  j.tenant = r[1].as<std::string>();
  j.kind = parse_job_kind(r[2].as<std::string>());
  j.state = parse_job_state(r[3].as<std::string>()).value_or(JobState::kFailed);
  j.spec = bytes_of(r[4]);
  j.pass = r[5].as<int>();
  j.passes = r[6].as<int>();
  j.sample = r[7].as<std::int64_t>();
  j.samples = r[8].as<std::int64_t>();
  j.theta = doubles_of(r[9]);
  j.error_code = r[10].as<int>();
  j.error_message = r[11].as<std::string>();
  j.created_ms = r[12].as<std::int64_t>();
  j.started_ms = r[13].as<std::int64_t>();
  j.finished_ms = r[14].as<std::int64_t>();
  j.owner = r[15].as<std::string>();
  j.lease_until_ms = r[16].as<std::int64_t>();
  j.cancel_requested = r[17].as<bool>();
  j.iteration = r[18].as<int>();
  j.cost = r[19].as<double>();
  j.attempts = r[20].as<int>();
  j.model = r[21].as<std::string>();
  return j;
}

constexpr const char* kDatasetColumns =
    "id, tenant, name, format, input_names, output_names, samples, t_start, t_end, size_bytes, created_ms, sha256, "
    "true_parameters";

DatasetRecord read_dataset(const pqxx::row& r) {
  DatasetRecord d;
  d.id = r[0].as<std::string>();
  d.tenant = r[1].as<std::string>();
  d.name = r[2].as<std::string>();
  d.format = r[3].as<std::string>();
  d.input_names = strings_of(r[4]);
  d.output_names = strings_of(r[5]);
  d.samples = r[6].as<std::int64_t>();
  d.t_start = r[7].as<double>();
  d.t_end = r[8].as<double>();
  d.size_bytes = r[9].as<std::int64_t>();
  d.created_ms = r[10].as<std::int64_t>();
  d.sha256 = r[11].as<std::string>();
  d.true_parameters = decode_named_values(r[12].as<std::string>());
  return d;
}

// A connection with the server's notices and warnings sent to our log
// (libpq would print them on stderr).
struct Connection {
  explicit Connection(const std::string& conninfo) : conn(conninfo), notices(conn) {}

  struct NoticeLogger final : pqxx::errorhandler {
    explicit NoticeLogger(pqxx::connection_base& c) : pqxx::errorhandler(c) {}
    bool operator()(const char message[]) noexcept override {
      spdlog::warn("postgresql says: {}", first_line(message));
      return false;  // handled: no other handler
    }
  };

  pqxx::connection conn;
  NoticeLogger notices;  // after conn: unregistered before conn closes
};

// At most `size` connections, opened when needed and kept for reuse. A
// broken one is dropped and replaced by a new one at the next take().
class ConnectionPool {
 public:
  ConnectionPool(std::string conninfo, std::string shown, std::size_t size)
      : conninfo_(std::move(conninfo)), shown_(std::move(shown)), size_(size) {}

  Result<std::unique_ptr<Connection>> take() {
    std::unique_lock lock(mu_);
    cv_.wait(lock, [&] { return !idle_.empty() || open_ < size_; });
    if (!idle_.empty()) {
      std::unique_ptr<Connection> c = std::move(idle_.back());
      idle_.pop_back();
      return c;
    }
    ++open_;
    lock.unlock();
    try {
      auto c = std::make_unique<Connection>(conninfo_);
      // Doubles in query results exactly (the server's shortest exact form,
      // whatever its configuration says); notices only from warnings up.
      pqxx::nontransaction(c->conn).exec("SET extra_float_digits = 3; SET client_min_messages = warning");
      return c;
    } catch (const std::exception& e) {
      give_back(nullptr);
      return Status{StatusCode::kUnavailable, "cannot connect to PostgreSQL at " + shown_ + ": " + first_line(e.what())};
    }
  }

  // Returns a connection taken; nullptr (a broken one) frees its place.
  void give_back(std::unique_ptr<Connection> c) {
    std::lock_guard lock(mu_);
    if (c != nullptr) {
      idle_.push_back(std::move(c));
    } else {
      --open_;
    }
    cv_.notify_one();
  }

  // After a connection broke, the idle ones most likely did too (the server
  // restarted, the network went): close them rather than fail on each.
  void drop_idle() {
    std::vector<std::unique_ptr<Connection>> dropped;
    std::lock_guard lock(mu_);
    dropped.swap(idle_);
    open_ -= dropped.size();
    cv_.notify_all();
  }

 private:
  const std::string conninfo_;
  const std::string shown_;
  const std::size_t size_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::vector<std::unique_ptr<Connection>> idle_;
  std::size_t open_ = 0;
};

// One connection for one operation, given back when the lease ends.
class Lease {
 public:
  explicit Lease(ConnectionPool& pool) : pool_(pool) {
    auto c = pool.take();
    if (c.is_ok()) {
      conn_ = std::move(c).value();
    } else {
      status_ = c.status();
    }
  }
  ~Lease() {
    if (conn_ == nullptr) return;
    pool_.give_back(broken_ || !conn_->conn.is_open() ? nullptr : std::move(conn_));
  }
  Lease(const Lease&) = delete;
  Lease& operator=(const Lease&) = delete;

  bool ok() const { return conn_ != nullptr; }
  const Status& status() const { return status_; }
  pqxx::connection& connection() { return conn_->conn; }
  void mark_broken() { broken_ = true; }

 private:
  ConnectionPool& pool_;
  std::unique_ptr<Connection> conn_;
  Status status_;
  bool broken_ = false;
};

class PostgresStore final : public Store {
 public:
  PostgresStore(const std::string& conninfo, std::string shown, std::shared_ptr<StoreClock> clock)
      : shown_(std::move(shown)), pool_(conninfo, shown_, kPoolSize), clock_(std::move(clock)) {}

  Status migrate() {
    const int known = static_cast<int>(kMigrations.size());
    int from = 0;
    std::string doing = "applying schema migrations";  // named more precisely below, for errors
    Status s = run<pqxx::work>(doing, false, [&](pqxx::work& tx) -> Status {
      tx.exec_params("SELECT pg_advisory_xact_lock($1)", kMigrationLock);
      tx.exec(
          "CREATE TABLE IF NOT EXISTS riccati_schema_migrations (version INTEGER PRIMARY KEY, applied_at "
          "TIMESTAMPTZ NOT NULL DEFAULT now())");
      from = tx.exec1("SELECT coalesce(max(version), 0) FROM riccati_schema_migrations")[0].as<int>();
      if (from > known) {
        return failed_precondition("database " + shown_ + " has schema version " + std::to_string(from) +
                                   ", newer than this riccatid (" + std::to_string(known) + "): upgrade riccatid");
      }
      for (int v = from; v < known; ++v) {
        doing = "applying schema migration " + std::to_string(v + 1);
        tx.exec(kMigrations[static_cast<std::size_t>(v)]);
        tx.exec_params("INSERT INTO riccati_schema_migrations (version) VALUES ($1)", v + 1);
      }
      return Status::ok();
    });
    if (s.is_ok() && from < known) {
      spdlog::info("store schema migrated kind=postgresql database={} from_version={} to_version={}", shown_, from,
                   known);
    }
    return s;
  }

  Status put_dataset(const DatasetRecord& r, const Dataset& data) override {
    return run<pqxx::work>("storing dataset " + r.id, false, [&](pqxx::work& tx) -> Status {
      tx.exec_params(
          "INSERT INTO datasets (id, tenant, name, format, input_names, output_names, samples, t_start, t_end, "
          "size_bytes, created_ms, sha256, true_parameters) VALUES ($1, $2, $3, $4, $5::text[], $6::text[], $7, $8, $9, "
          "$10, $11, $12, $13)",
          r.id, r.tenant, r.name, r.format, text_array(r.input_names), text_array(r.output_names), r.samples,
          r.t_start, r.t_end, r.size_bytes, r.created_ms, r.sha256, encode_named_values(r.true_parameters));
      tx.exec_params("INSERT INTO dataset_samples (dataset_id, t, u, y) VALUES ($1, $2::bytea, $3::bytea, $4::bytea)",
                     r.id, to_bytea(data.t.data(), static_cast<std::size_t>(data.t.size())),
                     to_bytea(data.u.data(), static_cast<std::size_t>(data.u.size())),
                     to_bytea(data.y.data(), static_cast<std::size_t>(data.y.size())));
      return Status::ok();
    });
  }

  Result<DatasetRecord> get_dataset(const std::string& tenant, const std::string& id) override {
    return run<pqxx::nontransaction>("reading dataset " + id, true, [&](auto& tx) -> Result<DatasetRecord> {
      const pqxx::result r = tx.exec_params(
          std::string("SELECT ") + kDatasetColumns + " FROM datasets WHERE id = $1 AND tenant = $2", id, tenant);
      if (r.empty()) return not_found("no dataset " + id);
      return read_dataset(r[0]);
    });
  }

  Result<Dataset> load_dataset(const std::string& tenant, const std::string& id) override {
    return run<pqxx::nontransaction>("reading the samples of dataset " + id, true, [&](auto& tx) -> Result<Dataset> {
      const pqxx::result r = tx.exec_params(
          "SELECT d.name, d.input_names, d.output_names, d.samples, s.t, s.u, s.y FROM datasets d JOIN "
          "dataset_samples s ON s.dataset_id = d.id WHERE d.id = $1 AND d.tenant = $2",
          id, tenant);
      if (r.empty()) return not_found("no dataset " + id);
      Dataset d;
      d.name = r[0][0].as<std::string>();
      d.input_names = strings_of(r[0][1]);
      d.output_names = strings_of(r[0][2]);
      const auto n = static_cast<Eigen::Index>(r[0][3].as<std::int64_t>());
      const auto t = doubles_of(r[0][4]), u = doubles_of(r[0][5]), y = doubles_of(r[0][6]);
      const auto nu = static_cast<Eigen::Index>(d.input_names.size());
      const auto ny = static_cast<Eigen::Index>(d.output_names.size());
      if (static_cast<Eigen::Index>(t.size()) != n || static_cast<Eigen::Index>(u.size()) != nu * n ||
          static_cast<Eigen::Index>(y.size()) != ny * n) {
        return internal_error("database " + shown_ + ": the stored samples of dataset " + id +
                              " do not match its sizes");
      }
      d.t = Eigen::Map<const Eigen::VectorXd>(t.data(), n);
      d.u = Eigen::Map<const Eigen::MatrixXd>(u.data(), nu, n);
      d.y = Eigen::Map<const Eigen::MatrixXd>(y.data(), ny, n);
      return d;
    });
  }

  Result<std::vector<DatasetRecord>> list_datasets(const std::string& tenant) override {
    return run<pqxx::nontransaction>("listing datasets", true, [&](auto& tx) -> Result<std::vector<DatasetRecord>> {
      const pqxx::result r = tx.exec_params(
          std::string("SELECT ") + kDatasetColumns + " FROM datasets WHERE tenant = $1 ORDER BY created_ms, seq",
          tenant);
      std::vector<DatasetRecord> out;
      for (const auto& row : r) out.push_back(read_dataset(row));
      return out;
    });
  }

  Status delete_dataset(const std::string& tenant, const std::string& id) override {
    return run<pqxx::nontransaction>("deleting dataset " + id, false, [&](auto& tx) -> Status {
      const pqxx::result r = tx.exec_params("DELETE FROM datasets WHERE id = $1 AND tenant = $2", id, tenant);
      if (r.affected_rows() == 0) return not_found("no dataset " + id);
      return Status::ok();
    });
  }

  Status put_job(const JobRecord& j) override {
    return run<pqxx::nontransaction>("storing job " + j.id, false, [&](auto& tx) -> Status {
      tx.exec_params(std::string("INSERT INTO jobs (") + kJobColumns +
                         ") VALUES ($1, $2, $3, $4, $5::bytea, $6, $7, $8, $9, $10::bytea, $11, $12, $13, $14, $15, "
                         "$16, $17, $18, $19, $20, $21, $22)",
                     j.id, j.tenant, job_kind_name(j.kind), job_state_name(j.state), pqxx::binarystring(j.spec), j.pass, j.passes,
                     j.sample, j.samples, to_bytea(j.theta.data(), j.theta.size()), j.error_code, j.error_message,
                     j.created_ms, j.started_ms, j.finished_ms, j.owner, j.lease_until_ms, j.cancel_requested,
                     j.iteration, j.cost, j.attempts, j.model);
      return Status::ok();
    });
  }

  Status update_job(const JobRecord& j) override {
    // Idempotent (it sets values), so safe to send again on a new connection.
    return run<pqxx::nontransaction>("updating job " + j.id, true, [&](auto& tx) -> Status {
      const pqxx::result r = tx.exec_params(
          "UPDATE jobs SET state = $1, pass = $2, passes = $3, sample = $4, samples = $5, theta = $6::bytea, "
          "error_code = $7, error_message = $8, started_ms = $9, finished_ms = $10, iteration = $11, cost = $12 WHERE "
          "id = $13 AND tenant = $14",
          job_state_name(j.state), j.pass, j.passes, j.sample, j.samples, to_bytea(j.theta.data(), j.theta.size()),
          j.error_code, j.error_message, j.started_ms, j.finished_ms, j.iteration, j.cost, j.id, j.tenant);
      if (r.affected_rows() == 0) return not_found("no job " + j.id);
      return Status::ok();
    });
  }

  Result<JobRecord> get_job(const std::string& tenant, const std::string& id) override {
    return run<pqxx::nontransaction>("reading job " + id, true, [&](auto& tx) -> Result<JobRecord> {
      const pqxx::result r = tx.exec_params(
          std::string("SELECT ") + kJobColumns + " FROM jobs WHERE id = $1 AND tenant = $2", id, tenant);
      if (r.empty()) return not_found("no job " + id);
      return read_job(r[0]);
    });
  }

  Result<std::vector<JobRecord>> list_jobs(const std::string& tenant) override {
    return run<pqxx::nontransaction>("listing jobs", true, [&](auto& tx) -> Result<std::vector<JobRecord>> {
      return read_jobs(tx.exec_params(
          std::string("SELECT ") + kJobColumns + " FROM jobs WHERE tenant = $1 ORDER BY created_ms, seq", tenant));
    });
  }

  Result<std::vector<JobRecord>> jobs_in_states(const std::vector<JobState>& states) override {
    std::vector<std::string> names;
    for (JobState s : states) names.emplace_back(job_state_name(s));
    return run<pqxx::nontransaction>("listing unfinished jobs", true,
                                     [&](auto& tx) -> Result<std::vector<JobRecord>> {
                                       return read_jobs(tx.exec_params(
                                           std::string("SELECT ") + kJobColumns +
                                               " FROM jobs WHERE state = ANY ($1::text[]) ORDER BY created_ms, seq",
                                           text_array(names)));
                                     });
  }

  Result<std::optional<JobRecord>> claim_job(const std::string& owner, std::int64_t lease_ms) override {
    // SKIP LOCKED: instances claiming at once each take a different job
    // instead of queueing behind one another's row lock. Not retried on a
    // lost connection: a claim that did commit would be taken twice by us,
    // and its lease simply expires.
    return run<pqxx::nontransaction>("claiming a job", false, [&](auto& tx) -> Result<std::optional<JobRecord>> {
      const pqxx::result r = tx.exec_params(
          std::string("UPDATE jobs SET state = 'running', owner = $1, lease_until_ms = " RICCATI_PG_NOW_MS
                      " + $2, started_ms = CASE WHEN started_ms = 0 THEN " RICCATI_PG_NOW_MS
                      " ELSE started_ms END, attempts = attempts + 1 WHERE id = (SELECT id FROM jobs WHERE (state = 'queued' OR "
                      "(state = 'running' AND lease_until_ms < " RICCATI_PG_NOW_MS
                      ")) AND kind IN (") + known_job_kinds_sql() +
              ") ORDER BY created_ms, seq LIMIT 1 FOR UPDATE SKIP LOCKED) RETURNING " +
              kJobColumns,
          owner, lease_ms);
      if (r.empty()) return std::optional<JobRecord>();
      return std::optional<JobRecord>(read_job(r[0]));
    });
  }

  Result<bool> renew_job(const JobRecord& p, const std::string& owner, std::int64_t lease_ms) override {
    return run<pqxx::nontransaction>("renewing the lease of job " + p.id, true, [&](auto& tx) -> Result<bool> {
      const pqxx::result r = tx.exec_params(
          "UPDATE jobs SET lease_until_ms = " RICCATI_PG_NOW_MS
          " + $1, pass = $2, passes = $3, sample = $4, samples = $5, theta = $6::bytea, iteration = $7, cost = $8 "
          "WHERE id = $9 AND owner = $10 AND state = 'running' RETURNING cancel_requested",
          lease_ms, p.pass, p.passes, p.sample, p.samples, to_bytea(p.theta.data(), p.theta.size()), p.iteration,
          p.cost, p.id, owner);
      if (r.empty()) return job_lease_lost(p.id, owner);
      return r[0][0].as<bool>();
    });
  }

  Status finish_job(const JobRecord& j, const std::string& owner, const std::string* result) override {
    // One transaction: the state and the result are written together, and
    // only by the job's owner.
    return run<pqxx::work>("ending job " + j.id, true, [&](auto& tx) -> Status {
      const pqxx::result r = tx.exec_params(
          "UPDATE jobs SET state = $1, pass = $2, passes = $3, sample = $4, samples = $5, theta = $6::bytea, "
          "error_code = $7, error_message = $8, finished_ms = $9, lease_until_ms = 0, iteration = $10, cost = $11 WHERE "
          "id = $12 AND owner = $13 AND state = 'running'",
          job_state_name(j.state), j.pass, j.passes, j.sample, j.samples, to_bytea(j.theta.data(), j.theta.size()),
          j.error_code, j.error_message, j.finished_ms, j.iteration, j.cost, j.id, owner);
      if (r.affected_rows() == 0) return job_lease_lost(j.id, owner);
      if (result != nullptr) {
        tx.exec_params("INSERT INTO results (job_id, tenant, result) SELECT id, tenant, $1::bytea FROM jobs WHERE id = $2",
                       pqxx::binarystring(*result), j.id);
      }
      return Status::ok();
    });
  }

  Result<int> release_jobs(const std::string& owner, bool stopped) override {
    return run<pqxx::nontransaction>("releasing the jobs of " + (owner.empty() ? std::string("every instance") : owner),
                                     true, [&](auto& tx) -> Result<int> {
                                       const pqxx::result r = tx.exec_params(
                                           "UPDATE jobs SET state = 'queued', owner = '', lease_until_ms = 0, "
                                           "attempts = CASE WHEN $2 THEN greatest(attempts - 1, 0) ELSE attempts "
                                           "END WHERE state = 'running' AND ($1 = '' OR owner = $1)",
                                           owner, stopped);
                                       return static_cast<int>(r.affected_rows());
                                     });
  }

  Result<JobRecord> cancel_job(const std::string& tenant, const std::string& id) override {
    RICCATI_RETURN_IF_ERROR(run<pqxx::nontransaction>("cancelling job " + id, true, [&](auto& tx) -> Status {
      tx.exec_params(
          "UPDATE jobs SET cancel_requested = true, state = CASE state WHEN 'queued' THEN 'cancelled' ELSE state END, "
          "error_code = CASE state WHEN 'queued' THEN $1 ELSE error_code END, error_message = CASE state WHEN "
          "'queued' THEN 'cancelled before it started' ELSE error_message END, finished_ms = CASE state WHEN "
          "'queued' THEN " RICCATI_PG_NOW_MS " ELSE finished_ms END WHERE id = $2 AND tenant = $3 AND state IN "
          "('queued', 'running')",
          static_cast<int>(StatusCode::kCancelled), id, tenant);
      return Status::ok();
    }));
    return get_job(tenant, id);
  }

  Status delete_job(const std::string& tenant, const std::string& id) override {
    return run<pqxx::nontransaction>("deleting job " + id, false, [&](auto& tx) -> Status {
      const pqxx::result r = tx.exec_params(
          "DELETE FROM jobs WHERE id = $1 AND tenant = $2 AND state IN " RICCATI_ENDED_STATES_SQL, id, tenant);
      if (r.affected_rows() > 0) return Status::ok();
      const pqxx::result state = tx.exec_params("SELECT state FROM jobs WHERE id = $1 AND tenant = $2", id, tenant);
      if (state.empty()) return not_found("no job " + id);
      return job_not_ended(id, state[0][0].as<std::string>());
    });
  }

  Result<int> delete_ended_jobs(std::int64_t finished_before_ms, std::int64_t keep_per_tenant) override {
    return run<pqxx::nontransaction>("deleting old jobs", true, [&](auto& tx) -> Result<int> {
      const pqxx::result r = tx.exec_params(
          "DELETE FROM jobs WHERE state IN " RICCATI_ENDED_STATES_SQL " AND (finished_ms < $1 OR id IN (SELECT id "
          "FROM (SELECT id, ROW_NUMBER() OVER (PARTITION BY tenant ORDER BY finished_ms DESC, id DESC) AS newer FROM "
          "jobs WHERE state IN " RICCATI_ENDED_STATES_SQL ") AS ranked WHERE newer > $2))",
          finished_before_ms, keep_per_tenant);
      return static_cast<int>(r.affected_rows());
    });
  }

  Result<std::int64_t> result_size(const std::string& tenant, const std::string& job_id) override {
    return run<pqxx::nontransaction>("reading the size of the result of job " + job_id, true,
                                     [&](auto& tx) -> Result<std::int64_t> {
                                       const pqxx::result r = tx.exec_params(
                                           "SELECT octet_length(result) FROM results WHERE tenant = $1 AND "
                                           "job_id = $2",
                                           tenant, job_id);
                                       if (r.empty()) return not_found("no result for job " + job_id);
                                       return r[0][0].as<std::int64_t>();
                                     });
  }

  Result<std::int64_t> result_bytes(const std::string& tenant) override {
    return run<pqxx::nontransaction>("reading the size of the results", true, [&](auto& tx) -> Result<std::int64_t> {
      const pqxx::result r =
          tx.exec_params("SELECT COALESCE(SUM(octet_length(result)), 0) FROM results WHERE tenant = $1", tenant);
      return r[0][0].as<std::int64_t>();
    });
  }

  Result<StoreUsage> usage() override {
    return run<pqxx::nontransaction>("reading the store's size", true, [&](auto& tx) -> Result<StoreUsage> {
      const pqxx::result r = tx.exec(
          "SELECT pg_database_size(current_database()), (SELECT COALESCE(SUM(size_bytes), 0) FROM datasets), "
          "(SELECT COALESCE(SUM(octet_length(result)), 0) FROM results)");
      StoreUsage usage;
      usage.database_bytes = r[0][0].as<std::int64_t>();
      usage.dataset_bytes = r[0][1].as<std::int64_t>();
      usage.result_bytes = r[0][2].as<std::int64_t>();
      return usage;
    });
  }

  Status put_result(const std::string& tenant, const std::string& job_id, const std::string& result) override {
    // Through the job's row, so that a result belongs to its job's tenant.
    return run<pqxx::nontransaction>("storing the result of job " + job_id, false, [&](auto& tx) -> Status {
      const pqxx::result r = tx.exec_params(
          "INSERT INTO results (job_id, tenant, result) SELECT id, tenant, $1::bytea FROM jobs WHERE id = $2 AND "
          "tenant = $3",
          pqxx::binarystring(result), job_id, tenant);
      if (r.affected_rows() == 0) return not_found("no job " + job_id);
      return Status::ok();
    });
  }

  Result<std::string> claim_request_id(const std::string& tenant, const std::string& request_id,
                                       const std::string& kind, const std::string& object_id) override {
    // The insert's row, or the row that was there. A row another instance
    // committed while this statement ran is not in the statement's snapshot
    // (ON CONFLICT waited for it): then a second statement reads it.
    return run<pqxx::nontransaction>("storing request id " + request_id, true, [&](auto& tx) -> Result<std::string> {
      pqxx::result r = tx.exec_params(
          "WITH inserted AS (INSERT INTO request_ids (tenant, request_id, kind, object_id, created_ms) VALUES ($1, $2, "
          "$3, $4, " RICCATI_PG_NOW_MS ") ON CONFLICT (tenant, request_id) DO NOTHING RETURNING kind, object_id) "
          "SELECT kind, object_id FROM inserted UNION ALL SELECT kind, object_id FROM request_ids WHERE tenant = $1 "
          "AND request_id = $2",
          tenant, request_id, kind, object_id);
      if (r.empty()) {
        r = tx.exec_params("SELECT kind, object_id FROM request_ids WHERE tenant = $1 AND request_id = $2", tenant,
                           request_id);
      }
      if (r.empty()) return internal_error("request id " + request_id + " was neither stored nor found");
      return named_object(request_id, r[0][0].as<std::string>(), r[0][1].as<std::string>(), kind);
    });
  }

  Result<std::optional<std::string>> find_request_id(const std::string& tenant, const std::string& request_id,
                                                     const std::string& kind) override {
    return run<pqxx::nontransaction>("reading request id " + request_id, true,
                                     [&](auto& tx) -> Result<std::optional<std::string>> {
                                       const pqxx::result r = tx.exec_params(
                                           "SELECT kind, object_id FROM request_ids WHERE tenant = $1 AND "
                                           "request_id = $2",
                                           tenant, request_id);
                                       if (r.empty()) return std::optional<std::string>();
                                       RICCATI_ASSIGN_OR_RETURN(
                                           std::string id, named_object(request_id, r[0][0].as<std::string>(),
                                                                        r[0][1].as<std::string>(), kind));
                                       return std::optional<std::string>(std::move(id));
                                     });
  }

  Result<int> delete_request_ids(std::int64_t claimed_before_ms) override {
    return run<pqxx::nontransaction>("deleting old request ids", true, [&](auto& tx) -> Result<int> {
      const pqxx::result r = tx.exec_params("DELETE FROM request_ids WHERE created_ms < $1", claimed_before_ms);
      return static_cast<int>(r.affected_rows());
    });
  }

  Result<UnfinishedJobs> count_unfinished_jobs(const std::string& tenant) override {
    return run<pqxx::nontransaction>("counting unfinished jobs", true, [&](auto& tx) -> Result<UnfinishedJobs> {
      const pqxx::result r = tx.exec_params(
          "SELECT COUNT(*) FILTER (WHERE state = 'queued'), COUNT(*) FILTER (WHERE state = 'running'), "
          "COUNT(*) FILTER (WHERE tenant = $1) FROM jobs WHERE state IN ('queued', 'running')",
          tenant);
      return UnfinishedJobs{r[0][0].as<std::int64_t>(), r[0][1].as<std::int64_t>(), r[0][2].as<std::int64_t>()};
    });
  }

  Result<std::string> get_result(const std::string& tenant, const std::string& job_id) override {
    return run<pqxx::nontransaction>("reading the result of job " + job_id, true, [&](auto& tx) -> Result<std::string> {
      const pqxx::result r =
          tx.exec_params("SELECT result FROM results WHERE job_id = $1 AND tenant = $2", job_id, tenant);
      if (r.empty()) return not_found("no result for job " + job_id);
      return bytes_of(r[0][0]);
    });
  }

  Status put_job_pass(const std::string& tenant, const std::string& job_id, int pass,
                      const std::string& record) override {
    const std::string what = "storing pass " + std::to_string(pass) + " of job " + job_id;
    return run<pqxx::nontransaction>(what, true, [&](auto& tx) -> Status {
      const pqxx::result r = tx.exec_params(
          "INSERT INTO job_passes (job_id, pass, tenant, record) SELECT id, $1, tenant, $2::bytea FROM jobs WHERE id "
          "= $3 AND tenant = $4 ON CONFLICT (job_id, pass) DO UPDATE SET record = excluded.record",
          pass, pqxx::binarystring(record), job_id, tenant);
      if (r.affected_rows() == 0) return not_found("no job " + job_id);
      return Status::ok();
    });
  }

  Result<std::vector<std::string>> list_job_passes(const std::string& tenant, const std::string& job_id) override {
    return run<pqxx::nontransaction>("reading the passes of job " + job_id, true,
                                     [&](auto& tx) -> Result<std::vector<std::string>> {
                                       const pqxx::result r = tx.exec_params(
                                           "SELECT record FROM job_passes WHERE job_id = $1 AND tenant = $2 "
                                           "ORDER BY pass",
                                           job_id, tenant);
                                       std::vector<std::string> out;
                                       for (const auto& row : r) out.push_back(bytes_of(row[0]));
                                       return out;
                                     });
  }

  Result<std::vector<Status>> put_session_snapshots(const std::string& owner, std::int64_t lease_ms,
                                                    const std::vector<SessionSnapshotWrite>& batch) override {
    const std::string doing = batch.size() == 1 ? "storing the snapshot of session " + std::string(batch[0].session_id)
                                                : "storing " + std::to_string(batch.size()) + " session snapshots";
    // Upserts that set values, in one transaction: safe to send again on a
    // new connection.
    return run<pqxx::work>(doing, true, [&](auto& tx) -> Result<std::vector<Status>> {
      std::vector<Status> stored;
      stored.reserve(batch.size());
      for (const SessionSnapshotWrite& s : batch) {
        const std::string id(s.session_id), tenant(s.tenant);
        const pqxx::result r = tx.exec_params(
            "INSERT INTO session_snapshots (session_id, tenant, snapshot, updated_ms, owner, lease_until_ms) VALUES "
            "($1, $2, $3::bytea, " RICCATI_PG_NOW_MS ", $4, " RICCATI_PG_NOW_MS " + $5) ON CONFLICT (session_id) DO "
            "UPDATE SET snapshot = excluded.snapshot, updated_ms = excluded.updated_ms, owner = excluded.owner, "
            "lease_until_ms = excluded.lease_until_ms WHERE session_snapshots.tenant = excluded.tenant AND "
            "(session_snapshots.owner = excluded.owner OR " RICCATI_PG_SESSION_LEASE_UNTIL " <= excluded.updated_ms)",
            id, tenant, pqxx::binarystring(s.snapshot.data(), s.snapshot.size()), owner, lease_ms);
        if (r.affected_rows() > 0) {
          stored.push_back(Status::ok());
          continue;
        }
        // Why not: another tenant's id (reads as missing), or another owner's.
        const pqxx::result held = tx.exec_params("SELECT tenant FROM session_snapshots WHERE session_id = $1", id);
        stored.push_back(held.empty() || held[0][0].as<std::string>() != tenant ? not_found("no session " + id)
                                                                                : session_lease_lost(id, owner));
      }
      return stored;
    });
  }

  Result<std::string> claim_session_snapshot(const std::string& tenant, const std::string& session_id,
                                             const std::string& owner, std::int64_t lease_ms) override {
    // The row lock orders concurrent claims: the second sees the first's
    // lease and is refused. Claiming again is harmless (the same owner may).
    return run<pqxx::nontransaction>("claiming session " + session_id, true, [&](auto& tx) -> Result<std::string> {
      for (int attempt = 0;; ++attempt) {
        const pqxx::result r = tx.exec_params(
            "UPDATE session_snapshots SET owner = $3, lease_until_ms = " RICCATI_PG_NOW_MS
            " + $4 WHERE session_id = $1 AND tenant = $2 AND (owner = $3 OR " RICCATI_PG_SESSION_LEASE_UNTIL
            " <= " RICCATI_PG_NOW_MS ") RETURNING snapshot",
            session_id, tenant, owner, lease_ms);
        if (!r.empty()) return bytes_of(r[0][0]);
        const pqxx::result held = tx.exec_params(
            "SELECT owner, " RICCATI_PG_SESSION_LEASE_UNTIL " - " RICCATI_PG_NOW_MS
            " FROM session_snapshots WHERE session_id = $1 AND tenant = $2",
            session_id, tenant);
        if (held.empty()) return not_found("no session " + session_id);
        const auto remaining = held[0][1].as<std::int64_t>();
        // The lease ended between the two statements: claim again.
        if (remaining > 0 || attempt > 0) {
          return session_held_elsewhere(session_id, held[0][0].as<std::string>(), remaining);
        }
      }
    });
  }

  Result<int> renew_session_leases(const std::string& owner, std::int64_t lease_ms) override {
    // One row for all the owner's sessions; then how many it holds.
    return run<pqxx::nontransaction>("renewing the session leases of " + owner, true, [&](auto& tx) -> Result<int> {
      tx.exec_params("INSERT INTO session_owner_leases (owner, lease_until_ms) VALUES ($1, " RICCATI_PG_NOW_MS
                     " + $2) ON CONFLICT (owner) DO UPDATE SET lease_until_ms = excluded.lease_until_ms",
                     owner, lease_ms);
      const pqxx::result r = tx.exec_params(
          "SELECT count(*) FROM session_snapshots WHERE owner = $1 AND lease_until_ms > 0", owner);
      return r[0][0].as<int>();
    });
  }

  Result<int> release_sessions(const std::string& owner) override {
    return run<pqxx::work>(
        "releasing the sessions of " + (owner.empty() ? std::string("every instance") : owner), true,
        [&](auto& tx) -> Result<int> {
          const pqxx::result r = tx.exec_params(
              "UPDATE session_snapshots SET lease_until_ms = 0 WHERE lease_until_ms > 0 AND ($1 = '' OR owner = $1)",
              owner);
          tx.exec_params("DELETE FROM session_owner_leases WHERE $1 = '' OR owner = $1", owner);
          return static_cast<int>(r.affected_rows());
        });
  }

  Status delete_session_snapshot(const std::string& tenant, const std::string& session_id,
                                 const std::string& owner) override {
    return run<pqxx::nontransaction>("deleting the snapshot of session " + session_id, false, [&](auto& tx) -> Status {
      const pqxx::result r = tx.exec_params(
          "DELETE FROM session_snapshots WHERE session_id = $1 AND tenant = $2 AND (owner = $3 OR "
          RICCATI_PG_SESSION_LEASE_UNTIL " <= " RICCATI_PG_NOW_MS ")",
          session_id, tenant, owner);
      if (r.affected_rows() > 0) return Status::ok();
      const pqxx::result held = tx.exec_params(
          "SELECT 1 FROM session_snapshots WHERE session_id = $1 AND tenant = $2", session_id, tenant);
      if (held.empty()) return not_found("no snapshot of session " + session_id);
      return session_lease_lost(session_id, owner);
    });
  }

  Result<std::vector<SessionSnapshotRecord>> list_session_snapshots(const std::string& tenant) override {
    return run<pqxx::nontransaction>(
        "listing the session snapshots of " + tenant, true, [&](auto& tx) -> Result<std::vector<SessionSnapshotRecord>> {
          const pqxx::result r = tx.exec_params(
              "SELECT session_id, CASE WHEN " RICCATI_PG_SESSION_LEASE_UNTIL " > " RICCATI_PG_NOW_MS
              " THEN owner ELSE '' END, snapshot FROM session_snapshots WHERE tenant = $1 ORDER BY session_id",
              tenant);
          std::vector<SessionSnapshotRecord> records;
          for (const auto& row : r) records.push_back({row[0].as<std::string>(), row[1].as<std::string>(), bytes_of(row[2])});
          return records;
        });
  }

  Result<int> delete_abandoned_session_snapshots(std::int64_t idle_ms) override {
    return run<pqxx::nontransaction>("deleting abandoned session snapshots", true, [&](auto& tx) -> Result<int> {
      const pqxx::result r = tx.exec_params(
          "DELETE FROM session_snapshots WHERE " RICCATI_PG_SESSION_LEASE_UNTIL " <= " RICCATI_PG_NOW_MS
          " AND updated_ms < " RICCATI_PG_NOW_MS " - $1",
          idle_ms);
      return static_cast<int>(r.affected_rows());
    });
  }

  Result<ModelRecord> put_model(const ModelRecord& record) override {
    // Two instances storing the same name at once collide on the primary
    // key; the loser is told to try again (not idempotent: no retry here).
    return run<pqxx::nontransaction>("storing model " + record.name, false, [&](auto& tx) -> Result<ModelRecord> {
      const pqxx::result r = tx.exec_params(
          "INSERT INTO models (tenant, name, revision, source, sha256, created_ms, deleted) SELECT $1, $2, "
          "coalesce(max(revision), 0) + 1, $3::bytea, $4, $5, false FROM models WHERE tenant = $1 AND name = $2 "
          "RETURNING revision",
          record.tenant, record.name, pqxx::binarystring(record.source), record.sha256, record.created_ms);
      ModelRecord out = record;
      out.revision = r[0][0].as<std::int64_t>();
      out.deleted = false;
      return out;
    });
  }

  Result<ModelRecord> get_model(const std::string& tenant, const std::string& name, std::int64_t revision) override {
    const std::string which = revision > 0 ? name + "@" + std::to_string(revision) : name;
    return run<pqxx::nontransaction>("reading model " + which, true, [&](auto& tx) -> Result<ModelRecord> {
      const pqxx::result r =
          revision > 0 ? tx.exec_params("SELECT revision, source, sha256, created_ms, deleted FROM models WHERE tenant = "
                                        "$1 AND name = $2 AND revision = $3",
                                        tenant, name, revision)
                       : tx.exec_params("SELECT revision, source, sha256, created_ms, deleted FROM models WHERE tenant = "
                                        "$1 AND name = $2 AND NOT deleted ORDER BY revision DESC LIMIT 1",
                                        tenant, name);
      if (r.empty()) return not_found("no model \"" + which + "\"");
      ModelRecord m;
      m.tenant = tenant;
      m.name = name;
      m.revision = r[0][0].as<std::int64_t>();
      m.source = bytes_of(r[0][1]);
      m.sha256 = r[0][2].as<std::string>();
      m.created_ms = r[0][3].as<std::int64_t>();
      m.deleted = r[0][4].as<bool>();
      return m;
    });
  }

  Result<std::vector<ModelRecord>> list_models(const std::string& tenant) override {
    return run<pqxx::nontransaction>("listing models", true, [&](auto& tx) -> Result<std::vector<ModelRecord>> {
      const pqxx::result r = tx.exec_params(
          "SELECT DISTINCT ON (name) name, revision, source, sha256, created_ms, deleted FROM models WHERE tenant = $1 "
          "ORDER BY name, revision DESC",
          tenant);
      std::vector<ModelRecord> out;
      for (const auto& row : r) {
        if (row[5].as<bool>()) continue;  // the latest revision is deleted: the name is
        ModelRecord m;
        m.tenant = tenant;
        m.name = row[0].as<std::string>();
        m.revision = row[1].as<std::int64_t>();
        m.source = bytes_of(row[2]);
        m.sha256 = row[3].as<std::string>();
        m.created_ms = row[4].as<std::int64_t>();
        out.push_back(std::move(m));
      }
      return out;
    });
  }

  Status delete_model(const std::string& tenant, const std::string& name) override {
    return run<pqxx::nontransaction>("deleting model " + name, true, [&](auto& tx) -> Status {
      const pqxx::result r = tx.exec_params(
          "UPDATE models SET deleted = true WHERE tenant = $1 AND name = $2 AND NOT deleted", tenant, name);
      if (r.affected_rows() == 0) return not_found("no model \"" + name + "\"");
      return Status::ok();
    });
  }

  Result<int> purge_unused_models() override {
    return run<pqxx::nontransaction>("purging deleted models", true, [&](auto& tx) -> Result<int> {
      // The newest revision of a name stays, its source emptied, so that
      // the name's next upload takes the next number (name@3 is one source).
      constexpr const char* kNamedByAJob =
          "SELECT 1 FROM jobs WHERE jobs.tenant = models.tenant AND jobs.state IN ('queued', 'running') AND "
          "jobs.model = models.name || '@' || models.revision";
      const pqxx::result deleted = tx.exec(
          std::string("DELETE FROM models WHERE deleted AND NOT EXISTS (") + kNamedByAJob +
          ") AND revision < (SELECT max(m.revision) FROM models m WHERE m.tenant = models.tenant AND m.name = "
          "models.name)");
      const pqxx::result emptied = tx.exec(std::string("UPDATE models SET source = ''::bytea WHERE deleted AND "
                                                       "octet_length(source) > 0 AND NOT EXISTS (") +
                                           kNamedByAJob + ")");
      return static_cast<int>(deleted.affected_rows() + emptied.affected_rows());
    });
  }

  Result<std::vector<ModelRevision>> list_model_revisions(const std::string& tenant) override {
    return run<pqxx::nontransaction>("listing model revisions", true,
                                     [&](auto& tx) -> Result<std::vector<ModelRevision>> {
      const pqxx::result r = tx.exec_params(
          "SELECT name, revision, octet_length(source) FROM models WHERE tenant = $1 AND NOT deleted "
          "ORDER BY name, revision",
          tenant);
      std::vector<ModelRevision> out;
      for (const auto& row : r) {
        out.push_back({row[0].as<std::string>(), row[1].as<std::int64_t>(), row[2].as<std::int64_t>()});
      }
      return out;
    });
  }

 private:
  // Runs `body` in a transaction of type Tx (pqxx::work for several
  // statements that go together, pqxx::nontransaction for one: a round trip
  // less) on a pooled connection, committing if it returns ok, and turns
  // database errors into a Status naming the database and what was being
  // done. A broken connection is found only by using it, so a call that is
  // safe to repeat (`idempotent`) is tried once more on a new connection.
  template <typename Tx, typename F>
  auto run(const std::string& doing, bool idempotent, F&& body) -> std::invoke_result_t<F&, Tx&> {
    using R = std::invoke_result_t<F&, Tx&>;
    for (int attempt = 1;; ++attempt) {
      Lease lease(pool_);
      if (!lease.ok()) return lease.status();
      try {
        Tx tx(lease.connection());
        if (clock_ != nullptr) {
          // Session-wide (not local to a transaction: a nontransaction has
          // none), and set again by every operation on this connection.
          tx.exec_params("SELECT set_config('riccati.now_ms', $1, false)", std::to_string(clock_->now_ms()));
        }
        R out = body(tx);
        if (out.is_ok()) tx.commit();  // else tx rolls back as it goes
        return out;
      } catch (const pqxx::broken_connection& e) {
        lease.mark_broken();
        pool_.drop_idle();
        if (idempotent && attempt == 1) {
          spdlog::warn("database connection lost, retrying database={} doing=\"{}\" error=\"{}\"", shown_, doing,
                       first_line(e.what()));
          continue;
        }
        return Status{StatusCode::kUnavailable, where(doing) + "connection lost: " + first_line(e.what())};
      } catch (const pqxx::in_doubt_error& e) {
        lease.mark_broken();
        pool_.drop_idle();
        return Status{StatusCode::kUnavailable, where(doing) +
                                                    "connection lost while committing, the change may or may not "
                                                    "have been stored: " + first_line(e.what())};
      } catch (const pqxx::unique_violation& e) {
        return Status{StatusCode::kAlreadyExists, doing + ": " + first_line(e.what())};
      } catch (const std::exception& e) {
        return internal_error(where(doing) + first_line(e.what()));
      }
    }
  }


  std::string where(const std::string& doing) const { return "database " + shown_ + ", " + doing + ": "; }

  static Result<std::vector<JobRecord>> read_jobs(const pqxx::result& r) {
    std::vector<JobRecord> out;
    for (const auto& row : r) out.push_back(read_job(row));
    return out;
  }

  const std::string shown_;  // the URL without its password
  ConnectionPool pool_;
  const std::shared_ptr<StoreClock> clock_;  // none: the database server's
};

}  // namespace

std::string redact_database_url(const std::string& url) {
  std::string out = url;
  // URI user info: scheme://user:password@host...
  const auto scheme = out.find("://");
  if (scheme != std::string::npos) {
    const auto start = scheme + 3;
    const auto query = out.find('?', start);
    const auto at = out.rfind('@', query == std::string::npos ? std::string::npos : query);
    if (at != std::string::npos && at >= start) {
      const auto colon = out.find(':', start);
      if (colon != std::string::npos && colon < at) out.replace(colon + 1, at - colon - 1, "***");
    }
  }
  // password=... as a URI parameter or a key=value pair.
  for (auto pos = out.find("password="); pos != std::string::npos; pos = out.find("password=", pos + 1)) {
    const bool starts_key = pos == 0 || out[pos - 1] == '?' || out[pos - 1] == '&' || out[pos - 1] == ' ';
    if (!starts_key) continue;
    const auto value = pos + std::strlen("password=");
    auto end = out.find_first_of("& ", value);
    if (end == std::string::npos) end = out.size();
    out.replace(value, end - value, "***");
  }
  return out;
}

Result<std::unique_ptr<Store>> open_postgres_store(const std::string& url, std::shared_ptr<StoreClock> clock) {
  auto store = std::make_unique<PostgresStore>(with_default_params(url), redact_database_url(url), std::move(clock));
  RICCATI_RETURN_IF_ERROR(store->migrate());
  return std::unique_ptr<Store>(std::move(store));
}

}  // namespace riccati
