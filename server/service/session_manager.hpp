// Filter sessions: a filter that a rig streams measurements into.
//
// A session is created with a model, filter settings and an initial
// estimate; its filter starts at the first measurement it receives. One
// stream at a time may be attached; a client that disconnects can attach a
// new stream until the session has been idle for longer than the idle
// timeout, when it expires. A measurement with the wrong sizes, non-finite
// values or a time not after the previous one is refused on its own (the
// session goes on); a filter that diverges closes the session to further
// measurements and reports why.
#pragma once

#include "service/limits.hpp"

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "engine/filter.hpp"
#include "engine/identification.hpp"
#include "engine/plugin_loader.hpp"
#include "riccati/v1/sessions.pb.h"

namespace riccati::service {

class Session {
 public:
  Session(std::string id, std::string tenant, ModelPtr model, std::unique_ptr<Filter> filter,
          InitialState initial_state, Eigen::VectorXd x0, Eigen::VectorXd theta0, Eigen::MatrixXd P0);

  const std::string& id() const { return id_; }
  const std::string& tenant() const { return tenant_; }

  // Attaches a stream; FAILED_PRECONDITION if one is attached already or the
  // session diverged.
  Status attach();
  void detach();

  // Processes one measurement into `out` (an estimate or an error for it).
  // Returns non-ok only when the filter diverged: the stream must end with
  // that status.
  Status process(const v1::Measurement& m, bool full_covariance, v1::MeasurementResult* out);

  v1::SessionInfo info() const;
  bool idle_since(std::chrono::steady_clock::time_point t) const;

 private:
  Status check(const v1::Measurement& m) const;
  Status step(const v1::Measurement& m);

  const std::string id_;
  const std::string tenant_;
  const ModelPtr model_;
  const InitialState initial_state_;
  const Eigen::VectorXd x0_, theta0_;
  const Eigen::MatrixXd P0_;
  const std::int64_t created_ms_;

  mutable std::mutex mu_;
  std::unique_ptr<Filter> filter_;
  bool started_ = false;
  bool streaming_ = false;
  Status diverged_;
  std::uint64_t received_ = 0;  // every measurement, accepted or not
  std::uint64_t accepted_ = 0;
  Eigen::VectorXd u_last_;
  Eigen::VectorXd u_, y_;  // scratch for the current measurement
  std::int64_t last_active_ms_;
  std::chrono::steady_clock::time_point last_active_;
};

class SessionManager {
 public:
  SessionManager(const ModelRegistry& models, std::chrono::seconds idle_timeout, Limits limits = {});
  ~SessionManager();

  Result<std::shared_ptr<Session>> create(const std::string& tenant, const v1::CreateSessionRequest& request);
  Result<std::shared_ptr<Session>> get(const std::string& tenant, const std::string& id);
  std::vector<std::shared_ptr<Session>> list(const std::string& tenant);
  Status close(const std::string& tenant, const std::string& id);
  std::size_t size();

  // Removes sessions idle for longer than the timeout; returns how many.
  std::size_t expire_idle();

 private:
  const ModelRegistry& models_;
  const std::chrono::seconds idle_timeout_;
  const Limits limits_;  // max_sessions, max_tenant_sessions
  std::mutex mu_;
  std::map<std::string, std::shared_ptr<Session>> sessions_;
  std::condition_variable stop_cv_;
  bool stopping_ = false;
  std::thread reaper_;
};

}  // namespace riccati::service
