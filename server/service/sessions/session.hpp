// Session: a filter run that a rig streams measurements into, one stream at a
// time (engine/estimation/online_runner.hpp runs the filter). A measurement
// with the wrong sizes, non-finite values or a time not after the previous
// one is refused on its own (the session goes on); a filter that diverges
// closes the session to further measurements and says why. A session is
// saved as a snapshot (riccati.internal.SessionSnapshot) and restored from one
// bit for bit; session_manager.hpp decides when and where they are stored.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>

#include "engine/estimation/online_runner.hpp"
#include "riccati/internal/session_snapshot.pb.h"
#include "riccati/v1/sessions.pb.h"

namespace riccati::service {

class Session {
 public:
  Session(std::string id, std::string tenant, v1::CreateSessionRequest request, std::int64_t created_ms,
          OnlineRunner runner);

  const std::string& id() const { return id_; }
  const std::string& tenant() const { return tenant_; }

  // Attaches a stream; FAILED_PRECONDITION if one is attached already or the
  // session diverged.
  Status attach();
  void detach();

  // Processes one measurement into `out` (an estimate or an error for it).
  // Returns non-ok only when the filter diverged, or another instance
  // resumed the session: the stream must end with that status.
  Status process(const v1::Measurement& m, bool full_covariance, v1::MeasurementResult* out);

  // At most the bytes of one measurement's answer (with or without the
  // full covariance): what bounds a batch's answer before it is computed.
  std::int64_t result_bytes(bool full_covariance) const;
  // Retunings kept in the history (SessionInfo.retunings): the newest.
  static constexpr int kRetuningsKept = 32;

  v1::SessionInfo info() const;
  // The filter's estimate now, for watchers (the web workbench's event
  // stream), and the measurements accepted so far; no estimate (false)
  // before the first.
  bool latest(v1::Estimate* out, std::uint64_t* accepted) const;
  // Live retuning: new noise weights between two measurements, kept in the
  // session's request (what a snapshot rebuilds it from) and its history.
  Status retune(const v1::RetuneSessionRequest& request);
  bool idle_since(std::chrono::steady_clock::time_point t) const;

  // The session as a snapshot (SessionSnapshot, encoded), stored by `instance`.
  std::string snapshot(const std::string& instance) const;
  // Hands a snapshot to `sink` unless the session was closed: under the
  // session's lock, so that none is handed over after close(). Returns
  // whether it did.
  bool save(const std::string& instance, const std::function<void(std::string)>& sink);
  // Measurements came since the last snapshot and `interval` has passed
  // since it, or the filter diverged.
  bool snapshot_due(std::chrono::steady_clock::time_point now, std::chrono::milliseconds interval) const;
  // Puts back the state of a snapshot of this session.
  Status restore(const internal::SessionSnapshot& snapshot);
  // No more snapshots: the session was closed or expired here. A measurement
  // being processed stops first (its integration polls closing()), so that
  // close() waits for no more than that.
  void close();
  bool closing() const { return closing_.load(std::memory_order_relaxed); }
  // Another instance holds the session now: no more snapshots, and a stream
  // attached here ends with `why`.
  void lose(const Status& why);

 private:
  void fill_estimate(double t, bool full_covariance, v1::Estimate* e) const;  // mu_ held
  std::string encode(const std::string& instance) const;                    // mu_ held

  const std::string id_;
  const std::string tenant_;
  // As given, its filter's weights as retuned: what a snapshot rebuilds the session from (mu_).
  v1::CreateSessionRequest request_;
  const std::int64_t created_ms_;

  mutable std::mutex mu_;
  OnlineRunner runner_;
  bool streaming_ = false;
  bool closed_ = false;
  std::atomic<bool> closing_{false};  // close() has begun (read without mu_)
  Status diverged_;             // the runner's divergence, as the session reports it
  Status lost_;                 // another instance resumed it
  google::protobuf::RepeatedPtrField<v1::Retuning> retunings_;
  std::uint64_t received_ = 0;  // every measurement, accepted or not
  std::uint64_t accepted_ = 0;
  std::uint64_t received_at_snapshot_ = 0;
  std::chrono::steady_clock::time_point last_snapshot_;
  std::int64_t last_active_ms_;
  std::chrono::steady_clock::time_point last_active_;
};

}  // namespace riccati::service
