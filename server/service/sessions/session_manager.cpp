#include "service/sessions/session_manager.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <set>

#include "service/convert.hpp"
#include "service/ids.hpp"
#include "service/run_settings.hpp"

namespace riccati::service {
namespace {

// What ListSessions shows of a session that another instance serves, or
// that waits to be resumed: its last snapshot, and who holds it.
v1::SessionInfo stored_info(const std::string& id, const internal::SessionSnapshot& s, const std::string& holder) {
  v1::SessionInfo info;
  info.set_id(id);
  info.set_model(s.request().model());
  info.set_filter(s.request().filter().kind());
  info.set_state(s.has_diverged()                     ? v1::SESSION_STATE_DIVERGED
                 : (s.streaming() && !holder.empty()) ? v1::SESSION_STATE_STREAMING
                                                      : v1::SESSION_STATE_IDLE);
  info.set_measurements(s.accepted());
  if (s.started()) {
    info.set_t(s.t());
    *info.mutable_state_estimate() = s.z();
  }
  set_timestamp(s.created_ms(), info.mutable_created());
  set_timestamp(s.last_active_ms(), info.mutable_last_active());
  if (s.has_diverged()) *info.mutable_error() = s.diverged();
  info.set_instance(holder);
  return info;
}

}  // namespace

SessionManager::SessionManager(const ModelCatalog& models, std::chrono::seconds idle_timeout, Limits limits,
                               Store* store, SessionStoreOptions options)
    : models_(models), idle_timeout_(idle_timeout), limits_(limits), store_(store), options_(std::move(options)) {
  reaper_ = std::thread([this] {
    std::unique_lock lock(mu_);
    const auto period = std::max<std::chrono::milliseconds>(std::chrono::milliseconds(200),
                                                            std::chrono::milliseconds(idle_timeout_) / 4);
    while (!stop_cv_.wait_for(lock, period, [this] { return stopping_; })) {
      lock.unlock();
      expire_idle();
      lock.lock();
    }
  });
}

SessionManager::~SessionManager() {
  {
    std::lock_guard lock(mu_);
    stopping_ = true;
  }
  stop_cv_.notify_all();
  reaper_.join();
  shutdown();
}

Status SessionManager::start() {
  if (store_ == nullptr) return Status::ok();
  // This instance's earlier run held these: nobody serves them now, so any
  // instance (this one too) may resume them at once.
  // On a full store (a full disk) the release cannot be written: riccatid
  // starts anyway, to read and delete (their leases expire instead).
  const Result<int> released = store_->release_sessions(options_.exclusive_store ? "" : options_.instance_id);
  if (!released.is_ok() && released.status().code() != StatusCode::kResourceExhausted) return released.status();
  if (!released.is_ok()) {
    spdlog::warn("sessions of an earlier run not released error=\"{}\"", released.status().message());
  } else if (released.value() > 0) {
    spdlog::info("sessions released count={} (held by an earlier run)", released.value());
  }
  spdlog::info("sessions stored instance={} lease_ms={} snapshot_ms={}", options_.instance_id,
               options_.lease.count(), options_.snapshot_interval.count());
  writer_ = std::thread([this] { writer_loop(); });
  return Status::ok();
}

void SessionManager::shutdown() {
  if (!writer_.joinable()) return;
  {
    std::lock_guard lock(writer_mu_);
    writer_stopping_ = true;
  }
  writer_cv_.notify_all();
  writer_.join();
  std::map<std::string, Pending> last;
  {
    std::lock_guard lock(writer_mu_);
    last.swap(pending_);
  }
  write(last);
  auto released = store_->release_sessions(options_.instance_id);
  if (released.is_ok()) {
    spdlog::info("sessions released count={}: any instance resumes them", released.value());
  } else {
    spdlog::warn("sessions not released error=\"{}\"", released.status().message());
  }
}

Result<std::shared_ptr<Session>> SessionManager::build(std::string id, const std::string& tenant,
                                                       const v1::CreateSessionRequest& request,
                                                       std::int64_t created_ms) {
  // A stored text model is pinned to the revision it has now (name@revision):
  // the session, and its snapshot resumed elsewhere, keep that revision
  // whatever is uploaded later.
  RICCATI_ASSIGN_OR_RETURN(const ResolvedModel resolved, models_.resolve(tenant, request.model()));
  const ModelPtr& model = resolved.model;
  v1::CreateSessionRequest pinned = request;
  pinned.set_model(resolved.reference);
  RICCATI_ASSIGN_OR_RETURN(OnlineRunner runner, online_runner_from_proto(model, request));
  runner.set_max_time_step(static_cast<double>(limits_.max_time_step_s));
  return std::make_shared<Session>(std::move(id), tenant, pinned, created_ms, std::move(runner));
}

Status SessionManager::check_limits(const std::string& tenant) const {
  if (static_cast<std::int64_t>(sessions_.size()) >= limits_.max_sessions) {
    return limit_reached("max_sessions", limits_.max_sessions, "riccatid has that many sessions open");
  }
  const auto own = std::count_if(sessions_.begin(), sessions_.end(),
                                 [&](const auto& entry) { return entry.second->tenant() == tenant; });
  if (own >= limits_.max_tenant_sessions) {
    return limit_reached("max_tenant_sessions", limits_.max_tenant_sessions,
                         "this tenant has that many sessions open; close one (CloseSession) first");
  }
  return Status::ok();
}

Result<std::shared_ptr<Session>> SessionManager::create(const std::string& tenant,
                                                        const v1::CreateSessionRequest& request) {
  RICCATI_RETURN_IF_ERROR(check_client_string("request_id", request.request_id(), kMaxRequestIdBytes));
  if (static_cast<std::int64_t>(request.ByteSizeLong()) > limits_.max_stored_request_bytes) {
    return limit_reached("max_stored_request_bytes", limits_.max_stored_request_bytes,
                         "the session's request is " + std::to_string(request.ByteSizeLong()) + " bytes encoded");
  }
  std::string id = new_id("ses");
  const bool idempotent = !request.request_id().empty() && store_ != nullptr;
  std::optional<std::string> earlier;
  if (idempotent) {
    // A retry of a request that made a session gets that session (here, or
    // resumed from its snapshot).
    RICCATI_ASSIGN_OR_RETURN(earlier, store_->find_request_id(tenant, request.request_id(), "session"));
    if (earlier) {
      id = *earlier;
      if (Result<std::shared_ptr<Session>> made = get(tenant, id);
          made.is_ok() || made.status().code() != StatusCode::kNotFound) {
        return made;
      }
    }
  }
  RICCATI_ASSIGN_OR_RETURN(std::shared_ptr<Session> session, build(id, tenant, request, now_ms()));
  if (idempotent && !earlier) {
    // Claimed only once the session is within the limits: a refused
    // request stores nothing.
    {
      std::lock_guard lock(mu_);
      RICCATI_RETURN_IF_ERROR(check_limits(tenant));
    }
    RICCATI_ASSIGN_OR_RETURN(const std::string claimed,
                             store_->claim_request_id(tenant, request.request_id(), "session", id));
    if (claimed != id) {
      // Another call with the same request_id claimed it first.
      if (Result<std::shared_ptr<Session>> made = get(tenant, claimed);
          made.is_ok() || made.status().code() != StatusCode::kNotFound) {
        return made;
      }
      RICCATI_ASSIGN_OR_RETURN(session, build(claimed, tenant, request, now_ms()));
      id = claimed;
    }
  }
  {
    std::lock_guard lock(mu_);
    if (auto made = sessions_.find(id); made != sessions_.end() && made->second->tenant() == tenant) {
      return made->second;  // a retry of the same request made it meanwhile
    }
    RICCATI_RETURN_IF_ERROR(check_limits(tenant));
    sessions_[session->id()] = session;
  }
  if (store_ != nullptr) {
    // Stored before the client hears of it, so any session it knows of can
    // be resumed elsewhere.
    const Status stored = store_->put_session_snapshot(tenant, session->id(), options_.instance_id,
                                                       options_.lease.count(), session->snapshot(options_.instance_id));
    counted(stored);
    if (!stored.is_ok()) {
      std::lock_guard lock(mu_);
      sessions_.erase(session->id());
      return stored;
    }
  }
  spdlog::info("session created id={} model={} tenant={}", session->id(), request.model(), tenant);
  return session;
}

Result<std::shared_ptr<Session>> SessionManager::get(const std::string& tenant, const std::string& id) {
  {
    std::lock_guard lock(mu_);
    auto it = sessions_.find(id);
    if (it != sessions_.end()) {
      if (it->second->tenant() != tenant) return not_found("no session " + id);
      return it->second;
    }
  }
  if (store_ == nullptr) return not_found("no session " + id);
  return resume(tenant, id);
}

Result<std::shared_ptr<Session>> SessionManager::resume(const std::string& tenant, const std::string& id) {
  {
    std::lock_guard lock(mu_);
    RICCATI_RETURN_IF_ERROR(check_limits(tenant));
  }
  RICCATI_ASSIGN_OR_RETURN(const std::string bytes,
                           store_->claim_session_snapshot(tenant, id, options_.instance_id, options_.lease.count()));
  internal::SessionSnapshot snapshot;
  Result<std::shared_ptr<Session>> rebuilt = [&]() -> Result<std::shared_ptr<Session>> {
    if (!snapshot.ParseFromString(bytes) || snapshot.tenant() != tenant) {
      return internal_error("its stored snapshot is unreadable");
    }
    RICCATI_ASSIGN_OR_RETURN(std::shared_ptr<Session> session,
                             build(id, tenant, snapshot.request(), snapshot.created_ms()));
    RICCATI_RETURN_IF_ERROR(session->restore(snapshot));
    return session;
  }();
  const auto give_back = [&] {
    // Released, for an instance that can (its lease was taken for nothing).
    std::lock_guard io(io_mu_);
    (void)store_->put_session_snapshot(tenant, id, options_.instance_id, 0, bytes);
  };
  if (!rebuilt.is_ok()) {
    give_back();
    spdlog::warn("session not resumed id={} error=\"{}\"", id, rebuilt.status().message());
    return failed_precondition("session " + id + " cannot be resumed on this instance: " +
                               rebuilt.status().message());
  }
  std::shared_ptr<Session> session = std::move(rebuilt).value();
  {
    std::lock_guard lock(mu_);
    auto it = sessions_.find(id);
    if (it != sessions_.end()) return it->second;  // resumed by a call at the same time
    const Status room = check_limits(tenant);
    if (!room.is_ok()) {
      give_back();
      return room;
    }
    sessions_[id] = session;
  }
  const v1::SessionInfo info = session->info();
  spdlog::info("session resumed id={} from_instance={} t={} measurements={} tenant={}", id, snapshot.instance(),
               info.t(), info.measurements(), tenant);
  if (options_.metrics != nullptr) options_.metrics->session_resumed();
  return session;
}

Result<std::vector<v1::SessionInfo>> SessionManager::list(const std::string& tenant) {
  std::vector<v1::SessionInfo> out;
  std::set<std::string> here;
  {
    std::lock_guard lock(mu_);
    for (const auto& [id, s] : sessions_) {
      if (s->tenant() != tenant) continue;
      out.push_back(s->info());
      out.back().set_instance(options_.instance_id);
      here.insert(id);
    }
  }
  if (store_ == nullptr) return out;
  // The others: served by other instances, or waiting to be resumed.
  RICCATI_ASSIGN_OR_RETURN(const std::vector<SessionSnapshotRecord> stored, store_->list_session_snapshots(tenant));
  for (const SessionSnapshotRecord& record : stored) {
    internal::SessionSnapshot snapshot;
    if (here.contains(record.session_id) || !snapshot.ParseFromString(record.snapshot) || snapshot.tenant() != tenant) {
      continue;  // an unreadable one: get() says why when the client asks for it
    }
    out.push_back(stored_info(record.session_id, snapshot, record.holder));
  }
  std::sort(out.begin(), out.end(), [](const v1::SessionInfo& a, const v1::SessionInfo& b) { return a.id() < b.id(); });
  return out;
}

Status SessionManager::close(const std::string& tenant, const std::string& id) {
  // Through get(): a session stored by a stopped instance is closed too.
  RICCATI_ASSIGN_OR_RETURN(std::shared_ptr<Session> session, get(tenant, id));
  {
    std::lock_guard lock(mu_);
    auto it = sessions_.find(id);
    if (it == sessions_.end() || it->second != session) return not_found("no session " + id);
    sessions_.erase(it);
  }
  forget(*session);
  spdlog::info("session closed id={}", id);
  return Status::ok();
}

std::size_t SessionManager::size() {
  std::lock_guard lock(mu_);
  return sessions_.size();
}

void SessionManager::after_batch(Session& session) {
  if (store_ == nullptr) return;
  if (session.snapshot_due(std::chrono::steady_clock::now(), options_.snapshot_interval)) save(session);
}

void SessionManager::save(Session& session) {
  if (store_ == nullptr) return;
  const bool handed = session.save(options_.instance_id, [&](std::string bytes) {
    std::lock_guard lock(writer_mu_);
    pending_[session.id()] = Pending{session.tenant(), std::move(bytes)};
  });
  if (handed) writer_cv_.notify_one();
}

void SessionManager::forget(Session& session) {
  session.close();  // no snapshot of it is handed over after this
  if (store_ == nullptr) return;
  {
    std::lock_guard lock(writer_mu_);
    pending_.erase(session.id());
  }
  std::lock_guard io(io_mu_);
  const Status deleted = store_->delete_session_snapshot(session.tenant(), session.id(), options_.instance_id);
  if (!deleted.is_ok() && deleted.code() != StatusCode::kNotFound) {
    spdlog::warn("session snapshot not deleted id={} error=\"{}\"", session.id(), deleted.message());
  }
}

void SessionManager::writer_loop() {
  const auto renew_every = std::max<std::chrono::milliseconds>(options_.lease / 3, std::chrono::milliseconds(100));
  // At most one transaction in a quarter of the snapshot interval: the
  // snapshots falling due meanwhile gather, so that the commits a second
  // do not grow with the number of sessions.
  const auto gather = options_.snapshot_interval / 4;
  auto next_renewal = std::chrono::steady_clock::now() + renew_every;
  auto next_write = std::chrono::steady_clock::now();
  std::unique_lock lock(writer_mu_);
  for (;;) {
    writer_cv_.wait_until(lock, next_renewal, [&] { return writer_stopping_ || !pending_.empty(); });
    if (!pending_.empty()) writer_cv_.wait_until(lock, next_write, [&] { return writer_stopping_; });
    if (writer_stopping_) return;  // shutdown() stores what is pending
    std::map<std::string, Pending> batch;
    batch.swap(pending_);
    lock.unlock();
    if (!batch.empty()) next_write = std::chrono::steady_clock::now() + gather;
    const bool stored = write(batch);
    if (std::chrono::steady_clock::now() >= next_renewal) {
      auto renewed = store_->renew_session_leases(options_.instance_id, options_.lease.count());
      if (!renewed.is_ok()) spdlog::warn("session leases not renewed error=\"{}\"", renewed.status().message());
      next_renewal = std::chrono::steady_clock::now() + renew_every;
    }
    lock.lock();
    // The store failed: try again a little later, not at once.
    if (!stored) writer_cv_.wait_for(lock, renew_every, [&] { return writer_stopping_; });
  }
}

void SessionManager::counted(const Status& stored) const {
  if (options_.metrics != nullptr) options_.metrics->session_snapshot(stored.is_ok());
}

bool SessionManager::write(std::map<std::string, Pending>& batch) {
  if (batch.empty()) return true;
  // One transaction for all (see writer_loop), in the ids' order (the
  // map's): two instances' batches lock shared rows in the same order.
  std::vector<SessionSnapshotWrite> writes;
  writes.reserve(batch.size());
  for (const auto& [id, snapshot] : batch) writes.push_back({snapshot.tenant, id, snapshot.bytes});
  Result<std::vector<Status>> stored = [&] {
    std::lock_guard io(io_mu_);
    return store_->put_session_snapshots(options_.instance_id, options_.lease.count(), writes);
  }();
  if (!stored.is_ok()) {
    spdlog::warn("session snapshots not stored count={} error=\"{}\"", batch.size(), stored.status().message());
    std::lock_guard lock(writer_mu_);
    for (auto& [id, snapshot] : batch) {
      counted(stored.status());
      pending_.try_emplace(id, std::move(snapshot));  // unless a newer one came meanwhile
    }
    return false;
  }
  auto outcome = stored.value().begin();
  for (const auto& [id, snapshot] : batch) {
    const Status& one = *outcome++;
    counted(one);
    if (one.code() == StatusCode::kAborted) lost(id, one);
    if (one.code() == StatusCode::kNotFound) {  // another tenant's id: never ours to store
      spdlog::warn("session snapshot not stored id={} error=\"{}\"", id, one.message());
    }
  }
  return true;
}

void SessionManager::lost(const std::string& id, const Status& why) {
  std::shared_ptr<Session> session;
  {
    std::lock_guard lock(mu_);
    auto it = sessions_.find(id);
    if (it == sessions_.end()) return;
    session = it->second;
    sessions_.erase(it);
  }
  session->lose(why);
  spdlog::warn("session lease lost id={} instance={}: another instance resumed it", id, options_.instance_id);
}

std::size_t SessionManager::expire_idle() {
  const auto cutoff = std::chrono::steady_clock::now() - idle_timeout_;
  std::vector<std::shared_ptr<Session>> expired;
  {
    std::lock_guard lock(mu_);
    for (auto it = sessions_.begin(); it != sessions_.end();) {
      if (it->second->idle_since(cutoff)) {
        expired.push_back(it->second);
        it = sessions_.erase(it);
      } else {
        ++it;
      }
    }
  }
  for (const auto& session : expired) {
    spdlog::info("session expired id={}", session->id());
    forget(*session);
  }
  if (store_ != nullptr) {
    // Sessions of instances that stopped or died, which nobody resumed: they
    // expire as they would have there.
    auto abandoned = store_->delete_abandoned_session_snapshots(
        std::chrono::duration_cast<std::chrono::milliseconds>(idle_timeout_).count());
    if (abandoned.is_ok() && abandoned.value() > 0) {
      spdlog::info("session snapshots expired count={} (of stopped instances)", abandoned.value());
    }
  }
  return expired.size();
}

}  // namespace riccati::service
