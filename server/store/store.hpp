// Store: what the daemon keeps across restarts.
//
// Datasets (their samples), jobs (spec, state, progress), job results and
// session snapshots. SQLite (a file in the data directory) is the embedded
// default; PostgreSQL (postgres_store.hpp) implements the same interface, so
// nothing here may depend on either: records are plain values, ids are strings chosen by
// the caller, times are Unix milliseconds, and what the store does not need
// to look into (a job's spec, a result, a snapshot) is an opaque byte string
// that the service layer encodes (protobuf).
//
// Every record belongs to a tenant. Lookups take the tenant and never return
// another tenant's records (NOT_FOUND), so tenancy cannot be forgotten at a
// call site. Until authentication exists every caller is tenant "default".
//
// Implementations are thread-safe: the daemon calls them from RPC threads and
// workers at once.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "engine/data/dataset.hpp"
#include "engine/status.hpp"
#include "store/clock.hpp"

namespace riccati {

struct DatasetRecord {
  std::string id;
  std::string tenant;
  std::string name;    // as uploaded (usually the file name)
  std::string format;  // "csv" or "mat"
  std::vector<std::string> input_names;
  std::vector<std::string> output_names;
  std::int64_t samples = 0;
  double t_start = 0.0;
  double t_end = 0.0;
  std::int64_t size_bytes = 0;  // of the uploaded file
  std::int64_t created_ms = 0;
  std::string sha256;  // of the uploaded file, 64 hex digits ('' if stored before riccatid kept it)
  std::map<std::string, double> true_parameters;  // declared at upload; empty: none
};

// Named values as one text column ("name=value" lines, values written to
// round-trip exactly); names hold no '=' or newline (the service checks).
std::string encode_named_values(const std::map<std::string, double>& values);
std::map<std::string, double> decode_named_values(const std::string& text);

enum class JobState { kQueued, kRunning, kSucceeded, kFailed, kCancelled };

// What a job does. kUnknown is only ever read: a kind that a newer riccatid
// sharing the store wrote; this one lists such jobs but never claims them.
enum class JobKind { kIdentification, kValidation, kSmoothing, kUnknown };

const char* job_kind_name(JobKind kind);  // "identification", "validation", "smoothing"
JobKind parse_job_kind(const std::string& name);  // kUnknown for any other name
// The kinds this riccatid runs, as an SQL list: 'identification', 'validation', ...
std::string known_job_kinds_sql();

const char* job_state_name(JobState state);  // "queued", "running", ...
// The state named so by job_state_name; nullopt for any other name.
std::optional<JobState> parse_job_state(const std::string& name);
bool is_terminal(JobState state);
// ABORTED: `owner` no longer holds job `id` (what renew_job and finish_job return then).
Status job_lease_lost(const std::string& id, const std::string& owner);
// FAILED_PRECONDITION: job `id` cannot be deleted in state `state` (queued, running).
Status job_not_ended(const std::string& id, const std::string& state);
// The ended states as an SQL list, for both stores' queries.
#define RICCATI_ENDED_STATES_SQL "('succeeded', 'failed', 'cancelled')"
// ABORTED: `owner` no longer holds session `id` (put_session_snapshot,
// delete_session_snapshot).
Status session_lease_lost(const std::string& id, const std::string& owner);
// FAILED_PRECONDITION: session `id` is held by instance `holder` for
// `remaining_ms` more (claim_session_snapshot).
Status session_held_elsewhere(const std::string& id, const std::string& holder, std::int64_t remaining_ms);

// A snapshot to store, as put_session_snapshots takes it: views of the
// caller's strings, which outlive the call.
struct SessionSnapshotWrite {
  std::string_view tenant;
  std::string_view session_id;
  std::string_view snapshot;
};

// A stored session snapshot, as list_session_snapshots gives it.
struct SessionSnapshotRecord {
  std::string session_id;
  std::string holder;  // the instance whose lease is live; empty when none holds it
  std::string snapshot;
};

struct JobRecord {
  std::string id;
  std::string tenant;
  JobKind kind = JobKind::kIdentification;
  JobState state = JobState::kQueued;
  std::string spec;  // opaque: encoded by the service layer
  // The model the spec names, pinned ("name@revision" for a tenant's text
  // model): what keeps a deleted model's revision stored while the job may
  // still run (purge_unused_models).
  std::string model;
  // Progress (identification): pass and sample are 1-based; 0 = not started.
  int pass = 0;
  int passes = 0;
  std::int64_t sample = 0;
  std::int64_t samples = 0;
  std::vector<double> theta;  // current estimate
  // An optimiser's progress (output error, maximum likelihood): iterations so far, the criterion.
  int iteration = 0;
  double cost = 0.0;
  // Failure or cancellation.
  int error_code = 0;  // StatusCode
  std::string error_message;
  std::int64_t created_ms = 0;
  std::int64_t started_ms = 0;   // 0 = not started
  std::int64_t finished_ms = 0;  // 0 = not finished
  // The job queue (claim_job): the instance running the job, until when its
  // claim holds unless renewed (the store's clock), and whether a client
  // asked to cancel it while it ran (its owner stops it at its next renewal).
  std::string owner;  // empty: not claimed
  std::int64_t lease_until_ms = 0;
  bool cancel_requested = false;
  // Claims so far, the current one included (claim_job counts them; a
  // release by a stopping owner takes its claim back): what bounds a job
  // that kills its instance, or whose end cannot be stored, to a few tries.
  int attempts = 0;
};

// A text model uploaded by a tenant (CreateModel): every revision is kept,
// so that a job that names one (name@revision) runs on what it was submitted
// with even after the name is given new equations or deleted.
struct ModelRecord {
  std::string tenant;
  std::string name;
  std::int64_t revision = 0;  // 1, 2, ... per (tenant, name), set by put_model
  std::string source;         // the YAML text, as uploaded
  std::string sha256;         // of source, 64 hex digits
  std::int64_t created_ms = 0;
  bool deleted = false;  // DeleteModel: hidden from the name, kept for the jobs that use it
};

// One stored revision of a text model, without its source: what ListModels
// shows of a name's revisions and what the tenant's model quota counts.
struct ModelRevision {
  std::string name;
  std::int64_t revision = 0;
  std::int64_t source_bytes = 0;
};

// How much a store holds (the metric riccati_store_bytes).
struct StoreUsage {
  std::int64_t database_bytes = 0;  // on disk: SQLite's file, PostgreSQL's pg_database_size
  std::int64_t dataset_bytes = 0;   // uploaded files, as uploaded, every tenant's
  std::int64_t result_bytes = 0;    // job results, every tenant's
};

// Queued and running jobs, counted (Store::count_unfinished_jobs).
struct UnfinishedJobs {
  std::int64_t queued = 0;
  std::int64_t running = 0;
  std::int64_t of_tenant = 0;  // queued or running, of the tenant asked about
};

// claim_request_id's answer from what is stored for `request_id`: the
// object id, or INVALID_ARGUMENT when it names another kind than `kind`.
Result<std::string> named_object(const std::string& request_id, const std::string& stored_kind,
                                 const std::string& object_id, const std::string& kind);

class Store {
 public:
  virtual ~Store() = default;

  // Datasets. put_dataset stores the record and the samples together (all or
  // nothing); ALREADY_EXISTS if the id is taken.
  virtual Status put_dataset(const DatasetRecord& record, const Dataset& data) = 0;
  virtual Result<DatasetRecord> get_dataset(const std::string& tenant, const std::string& id) = 0;
  virtual Result<Dataset> load_dataset(const std::string& tenant, const std::string& id) = 0;
  // Oldest first.
  virtual Result<std::vector<DatasetRecord>> list_datasets(const std::string& tenant) = 0;
  virtual Status delete_dataset(const std::string& tenant, const std::string& id) = 0;

  // Jobs. put_job inserts (ALREADY_EXISTS if the id is taken); update_job
  // replaces state, progress, error and times of an existing job (NOT_FOUND),
  // whoever holds it (the job queue below is what workers use).
  virtual Status put_job(const JobRecord& job) = 0;

  // Idempotent creation. A client's `request_id` (per tenant) names, from
  // the first call on, the object of `kind` ("job", "dataset", "session")
  // whose id that call gave (`object_id`): returns the id the request_id
  // names, object_id for the first call and the first call's for every
  // later one. The caller then creates the object under that id, unless it
  // exists (put_job and put_dataset refuse an id twice with ALREADY_EXISTS),
  // so one object comes of a request however often it is retried, however
  // the retries overlap. A request_id that names another kind of object is
  // INVALID_ARGUMENT.
  virtual Result<std::string> claim_request_id(const std::string& tenant, const std::string& request_id,
                                               const std::string& kind, const std::string& object_id) = 0;
  // The id an earlier call's claim of `request_id` names (nullopt: none);
  // INVALID_ARGUMENT when it names another kind. Read only: a manager looks
  // first, checks the request (limits, quotas), and claims only then, so a
  // refused request stores nothing.
  virtual Result<std::optional<std::string>> find_request_id(const std::string& tenant, const std::string& request_id,
                                                             const std::string& kind) = 0;
  // Forgets the request ids claimed before `claimed_before_ms` (the store's
  // clock for PostgreSQL, as claims are): a retry is answered for as long as
  // its id is kept (docs/operations.md). Returns how many.
  virtual Result<int> delete_request_ids(std::int64_t claimed_before_ms) = 0;
  virtual Status update_job(const JobRecord& job) = 0;
  virtual Result<JobRecord> get_job(const std::string& tenant, const std::string& id) = 0;
  // Oldest first.
  virtual Result<std::vector<JobRecord>> list_jobs(const std::string& tenant) = 0;
  // Every tenant's jobs in one of these states, oldest first: what a daemon
  // starting up must run again.
  virtual Result<std::vector<JobRecord>> jobs_in_states(const std::vector<JobState>& states) = 0;
  // How many jobs are queued and running, every tenant's, and how many of
  // them are `tenant`'s: what a submit and a metrics scrape need, without
  // reading any job's spec.
  virtual Result<UnfinishedJobs> count_unfinished_jobs(const std::string& tenant) = 0;

  // The job queue. Several riccatid may share one store (PostgreSQL); each
  // job runs on one of them at a time, under a lease that its owner renews.
  //
  // claim_job: the oldest job of a kind this riccatid knows that is queued,
  // or running under an expired lease (its instance died), becomes running, owned by `owner` for
  // `lease_ms` from now; started_ms is set at its first claim, and attempts
  // counts the claim. Two callers never get the same job. nullopt: nothing to run.
  virtual Result<std::optional<JobRecord>> claim_job(const std::string& owner, std::int64_t lease_ms) = 0;
  // The owner renews its lease and publishes progress (pass, passes, sample,
  // samples, theta, iteration, cost of `progress`). ABORTED if `owner` no longer holds the job
  // (it ended, or its lease expired and another instance took it). Returns
  // whether a cancel was requested meanwhile.
  virtual Result<bool> renew_job(const JobRecord& progress, const std::string& owner, std::int64_t lease_ms) = 0;
  // The owner ends the job: state, progress, error and finished_ms of
  // `final`, and the result when there is one, together (all or nothing).
  // ABORTED, and nothing written, if `owner` no longer holds the job: so a
  // job's result is written once even if two instances ran it.
  virtual Status finish_job(const JobRecord& final, const std::string& owner, const std::string* result) = 0;
  // Puts the running jobs of `owner` (every owner's when empty: a store that
  // one instance uses alone, at its start) back in the queue; returns how many.
  // `stopped`: their owner stopped them itself (a shutdown), which is no
  // fault of theirs, so their last claim is not counted in attempts.
  virtual Result<int> release_jobs(const std::string& owner, bool stopped) = 0;
  // Cancels a job: a queued one at once (state cancelled), a running one by
  // flagging it for its owner; an ended one is left as it is. Returns the job.
  virtual Result<JobRecord> cancel_job(const std::string& tenant, const std::string& id) = 0;

  // Deletes an ended job with its result and pass records. NOT_FOUND if the
  // tenant has no such job; FAILED_PRECONDITION naming its state if it is
  // queued or running (it must be cancelled first).
  virtual Status delete_job(const std::string& tenant, const std::string& id) = 0;
  // Retention: deletes every tenant's ended jobs (with their results) that
  // finished before `finished_before_ms` (0: none by age), and all but the
  // newest `keep_per_tenant` ended jobs of each tenant. Returns how many.
  virtual Result<int> delete_ended_jobs(std::int64_t finished_before_ms, std::int64_t keep_per_tenant) = 0;

  // Results: at most one per job, written once (ALREADY_EXISTS after);
  // NOT_FOUND if the tenant has no such job.
  virtual Status put_result(const std::string& tenant, const std::string& job_id, const std::string& result) = 0;
  virtual Result<std::string> get_result(const std::string& tenant, const std::string& job_id) = 0;
  // The bytes of a job's stored result, without reading it: NOT_FOUND if
  // there is none (what a read is held to before it begins).
  virtual Result<std::int64_t> result_size(const std::string& tenant, const std::string& job_id) = 0;
  // The bytes of the tenant's stored results (its quota, max_tenant_result_bytes).
  virtual Result<std::int64_t> result_bytes(const std::string& tenant) = 0;
  virtual Result<StoreUsage> usage() = 0;

  // Job checkpoints: one record (opaque) per completed pass of an
  // identification job, so that a job restarted after a crash resumes after
  // its last completed pass instead of from zero. One record per pass keeps
  // what is written linear in the number of passes. Putting a pass again
  // replaces it; NOT_FOUND if the job does not exist (for this tenant).
  virtual Status put_job_pass(const std::string& tenant, const std::string& job_id, int pass,
                              const std::string& record) = 0;
  // The job's pass records, in pass order (none: empty).
  virtual Result<std::vector<std::string>> list_job_passes(const std::string& tenant, const std::string& job_id) = 0;

  // Session snapshots: the latest state of each filter session (opaque
  // bytes), so that another instance, or this one after a restart, resumes
  // it. A session is served by one instance at a time: its snapshot is held
  // by that instance (`owner`) under a lease the owner renews, as jobs are;
  // lease times are the store's clock. A lease runs until lease_until_ms;
  // after that (or once released) any instance may claim the session.
  //
  // put_session_snapshot: stores (inserts or replaces) the snapshot, held by
  // `owner` for `lease_ms` from now. ABORTED (session_lease_lost) if another
  // owner holds it under a live lease; NOT_FOUND if the id is another
  // tenant's. A lease_ms of 0 stores it released.
  Status put_session_snapshot(const std::string& tenant, const std::string& session_id, const std::string& owner,
                              std::int64_t lease_ms, const std::string& snapshot);
  // Stores each snapshot as put_session_snapshot does, all in one
  // transaction: one commit (one sync to disk) for the many sessions whose
  // snapshots fell due together. One status a snapshot, in order: ok,
  // ABORTED or NOT_FOUND as above for that one alone, the others stored; an
  // error, and nothing stored, if the transaction failed.
  virtual Result<std::vector<Status>> put_session_snapshots(const std::string& owner, std::int64_t lease_ms,
                                                            const std::vector<SessionSnapshotWrite>& batch) = 0;
  // Takes the session over: `owner` holds it for `lease_ms` from now and
  // gets its snapshot. NOT_FOUND if there is none (or it is another
  // tenant's); FAILED_PRECONDITION naming the holder if another owner's
  // lease is live. An owner may always claim its own (a restart with the
  // same instance id).
  virtual Result<std::string> claim_session_snapshot(const std::string& tenant, const std::string& session_id,
                                                     const std::string& owner, std::int64_t lease_ms) = 0;
  // Extends by `lease_ms` from now the leases `owner` holds and has not
  // released (a released one is taken again by a claim or a put), and those
  // it takes until then: one lease row for the owner, whatever the number of
  // its sessions, so that a renewal does not rewrite every snapshot. Returns
  // how many sessions it holds.
  virtual Result<int> renew_session_leases(const std::string& owner, std::int64_t lease_ms) = 0;
  // Ends the leases of `owner` now (every owner's when empty: a store that
  // one instance uses alone, at its start), so that any instance may claim
  // those sessions at once; returns how many.
  virtual Result<int> release_sessions(const std::string& owner) = 0;
  // Deletes the snapshot (the session was closed or expired). NOT_FOUND if
  // there is none for this tenant; ABORTED, and nothing deleted, if another
  // owner holds it under a live lease (it was resumed there).
  virtual Status delete_session_snapshot(const std::string& tenant, const std::string& session_id,
                                         const std::string& owner) = 0;
  // The tenant's snapshots, by session id: ListSessions shows with them the
  // sessions that other instances serve or that wait to be resumed.
  virtual Result<std::vector<SessionSnapshotRecord>> list_session_snapshots(const std::string& tenant) = 0;
  // Deletes the snapshots that nobody holds (their leases ended) and that
  // were last stored more than `idle_ms` ago: sessions of instances that
  // died, which nobody resumed within the idle timeout. Returns how many.
  virtual Result<int> delete_abandoned_session_snapshots(std::int64_t idle_ms) = 0;

  // Text models. put_model stores `record` as the next revision of
  // (tenant, name) and returns it with its revision set (a name deleted
  // before continues its count). get_model with revision 0 gives the latest
  // revision unless the name is deleted; with a revision, that one, deleted
  // or not; NOT_FOUND otherwise. list_models: the latest revision of each
  // name not deleted, by name. delete_model marks every revision of the name
  // deleted; NOT_FOUND if it has none live.
  virtual Result<ModelRecord> put_model(const ModelRecord& record) = 0;
  virtual Result<ModelRecord> get_model(const std::string& tenant, const std::string& name, std::int64_t revision) = 0;
  virtual Result<std::vector<ModelRecord>> list_models(const std::string& tenant) = 0;
  virtual Status delete_model(const std::string& tenant, const std::string& name) = 0;
  // Every revision of the tenant's models that is not deleted, by name then
  // revision.
  // Deletes the revisions of deleted text models (every tenant's) that no
  // queued or running job names (JobRecord::model): an ended job keeps its
  // result, not its model. A name's newest revision stays with its source
  // emptied, so that revision numbers are never given twice. Returns how
  // many revisions were deleted or emptied.
  virtual Result<int> purge_unused_models() = 0;
  virtual Result<std::vector<ModelRevision>> list_model_revisions(const std::string& tenant) = 0;
};

// Opens (creating if needed) the SQLite store in `path` and brings its schema
// up to date (versioned migrations, applied in one transaction each). An
// empty file (a truncated database) and a damaged one (PRAGMA quick_check)
// are refused: FAILED_PRECONDITION naming the file and what to do. Leases
// and stored times are read from `clock` (none: the system's, clock.hpp).
Result<std::unique_ptr<Store>> open_sqlite_store(const std::string& path,
                                                 std::shared_ptr<StoreClock> clock = nullptr);

}  // namespace riccati
