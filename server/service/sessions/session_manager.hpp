// SessionManager: the filter sessions (session.hpp) of this instance.
//
// A session is created with a model, filter settings and an initial
// estimate; its filter starts at the first measurement it receives. One
// stream at a time may be attached; a client that disconnects can attach a
// new stream until the session has been idle for longer than the idle
// timeout, when it expires.
//
// With a store (the daemon), a session survives its instance: its snapshot
// (the request, the filter's state, the counters) is stored at creation,
// when a stream detaches, at most every snapshot interval while streaming,
// and when it diverges, held by this instance under a lease that is renewed
// while the instance lives (Store::put_session_snapshot). get() of a session
// that is not here claims its snapshot and resumes it, bit for bit, so a
// client whose instance died asks any other (GetSession: t and measurements
// say where the session stands), re-sends its measurements after t and
// streams on. A live instance keeps its sessions: another refuses them with
// FAILED_PRECONDITION naming it. Streams never wait on the database: they
// hand the encoded snapshot to a writer thread, which keeps only the latest
// per session and stores what gathered in one transaction, at most one in a
// quarter of the snapshot interval (a commit syncs the disk: a commit a
// snapshot would cost more than the sessions' filters).
#pragma once

#include "service/limits.hpp"
#include "service/metrics.hpp"

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "engine/models/plugin_loader.hpp"
#include "service/models/model_catalog.hpp"
#include "riccati/internal/session_snapshot.pb.h"
#include "riccati/v1/sessions.pb.h"
#include "service/sessions/session.hpp"
#include "store/store.hpp"

namespace riccati::service {

// How this instance keeps its sessions in a store shared with others.
struct SessionStoreOptions {
  std::string instance_id;                  // the owner of the snapshots stored here (the job queue's)
  std::chrono::milliseconds lease{15000};   // the job queue's: renewed every third of it
  std::chrono::milliseconds snapshot_interval{1000};  // at most this often while streaming
  // The store is this instance's alone (SQLite): at start every lease is
  // released, whoever held it (an earlier run under another id).
  bool exclusive_store = true;
  Metrics* metrics = nullptr;  // counts snapshots stored or failed and sessions resumed; may be null
};

class SessionManager {
 public:
  // Without a store, sessions live in memory only.
  SessionManager(const ModelCatalog& models, std::chrono::seconds idle_timeout, Limits limits = {},
                 Store* store = nullptr, SessionStoreOptions options = {});
  ~SessionManager();
  SessionManager(const SessionManager&) = delete;
  SessionManager& operator=(const SessionManager&) = delete;

  // Releases the leases of this instance's earlier run (every lease, with an
  // exclusive store) and starts the snapshot writer.
  Status start();
  // Stores the pending snapshots, then releases this instance's leases, so
  // any instance resumes its sessions at once. After the streams ended.
  void shutdown();

  Result<std::shared_ptr<Session>> create(const std::string& tenant, const v1::CreateSessionRequest& request);
  // A session here, or one resumed from its snapshot in the store.
  Result<std::shared_ptr<Session>> get(const std::string& tenant, const std::string& id);
  // This instance's id: the SessionInfo.instance of the sessions it serves.
  const std::string& instance_id() const { return options_.instance_id; }
  // The tenant's sessions, by id: those here, and those that the store
  // holds for other instances or for none (ListSessions).
  Result<std::vector<v1::SessionInfo>> list(const std::string& tenant);
  Status close(const std::string& tenant, const std::string& id);
  std::size_t size();

  // After each batch a stream processed: a snapshot if one is due.
  void after_batch(Session& session);
  // A snapshot now (a stream detached), stored in the background.
  void save(Session& session);

  // Removes sessions idle for longer than the timeout; returns how many.
  std::size_t expire_idle();

 private:
  struct Pending {
    std::string tenant;
    std::string bytes;
  };

  // A session of `request`, checked as CreateSession checks it, not registered.
  Result<std::shared_ptr<Session>> build(std::string id, const std::string& tenant,
                                         const v1::CreateSessionRequest& request, std::int64_t created_ms);
  // max_sessions and max_tenant_sessions, with mu_ held.
  Status check_limits(const std::string& tenant) const;
  Result<std::shared_ptr<Session>> resume(const std::string& tenant, const std::string& id);
  // Deletes the session's snapshot (closed or expired), after any write of it in flight.
  void forget(Session& session);
  void writer_loop();
  // Stores `batch`; returns false if the store failed (those wait for the next round).
  bool write(std::map<std::string, Pending>& batch);
  // Another instance resumed `id`: drop it here.
  void lost(const std::string& id, const Status& why);
  // Counts a snapshot put, stored or failed (metrics).
  void counted(const Status& stored) const;

  const ModelCatalog& models_;
  const std::chrono::seconds idle_timeout_;
  const Limits limits_;  // max_sessions, max_tenant_sessions
  Store* const store_;
  const SessionStoreOptions options_;
  mutable std::mutex mu_;
  std::map<std::string, std::shared_ptr<Session>> sessions_;
  std::condition_variable stop_cv_;
  bool stopping_ = false;
  std::thread reaper_;

  // The snapshot writer. Lock order: io_mu_, mu_, a session's, writer_mu_.
  std::mutex writer_mu_;
  std::condition_variable writer_cv_;
  std::map<std::string, Pending> pending_;  // the latest snapshot of each session, not yet stored
  bool writer_stopping_ = false;
  std::thread writer_;
  std::mutex io_mu_;  // held while writing or deleting snapshots: a delete follows a write in flight
};

}  // namespace riccati::service
