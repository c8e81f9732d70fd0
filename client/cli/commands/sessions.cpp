// `riccati sessions list | show | close`: the filter sessions of the caller's
// tenant, on every instance that shares the store.
#include <cstdio>

#include "commands/commands.hpp"
#include "output.hpp"
#include "riccati/enum_names.hpp"

namespace riccati::cli {

namespace {

std::string session_state(v1::SessionState state) {
  const auto* value = v1::SessionState_descriptor()->FindValueByNumber(state);
  return value != nullptr && state != v1::SESSION_STATE_UNSPECIFIED ? api::enum_value_name(*value) : "unknown";
}

std::string filter_name(v1::FilterKind kind) {
  const auto* value = v1::FilterKind_descriptor()->FindValueByNumber(kind == 0 ? v1::FILTER_KIND_EKF : kind);
  return value != nullptr ? api::enum_value_name(*value) : "unknown";
}

void print_line(const v1::SessionInfo& s) {
  std::printf("%-22s %-20s %-8s %-10s %12llu %14.6g  %s\n", s.id().c_str(), s.model().c_str(),
              filter_name(s.filter()).c_str(), session_state(s.state()).c_str(),
              static_cast<unsigned long long>(s.measurements()), s.t(),
              s.instance().empty() ? "-" : s.instance().c_str());
}

}  // namespace

int sessions_list(Client& c) {
  auto ctx = c.context();
  v1::ListSessionsResponse list;
  const grpc::Status s = c.sessions->ListSessions(ctx.get(), {}, &list);
  if (!s.ok()) return c.fail("listing sessions", s);
  if (c.json) {
    std::printf("%s\n", to_json(list).c_str());
    return kExitOk;
  }
  std::printf("%-22s %-20s %-8s %-10s %12s %14s  %s\n", "id", "model", "filter", "state", "measurements", "t",
              "instance");
  for (const auto& session : list.sessions()) print_line(session);
  return kExitOk;
}

int session_show(Client& c, const std::string& id) {
  auto ctx = c.context();
  v1::GetSessionRequest request;
  request.set_id(id);
  v1::SessionInfo info;
  const grpc::Status s = c.sessions->GetSession(ctx.get(), request, &info);
  if (!s.ok()) return c.fail("session " + id, s);
  if (c.json) {
    std::printf("%s\n", to_json(info).c_str());
    return kExitOk;
  }
  std::printf("%s  %s (%s)\n  state: %s, %s, t = %.17g s\n  instance: %s\n", info.id().c_str(),
              info.model().c_str(), filter_name(info.filter()).c_str(), session_state(info.state()).c_str(),
              counted(info.measurements(), "measurement").c_str(), info.t(),
              info.instance().empty() ? "-" : info.instance().c_str());
  if (info.state_estimate_size() > 0) std::printf("  estimate: %s\n", values_list(info.state_estimate()).c_str());
  // The noise the filter runs with now (what `sessions retune` changes).
  const auto noise = [](const char* name, const v1::Covariance& given) {
    if (given.has_diagonal()) std::printf("  %s: diag %s\n", name, values_list(given.diagonal().values()).c_str());
    if (given.has_full()) std::printf("  %s: %u x %u, full\n", name, given.full().rows(), given.full().cols());
    if (given.form_case() == v1::Covariance::kScalar) std::printf("  %s: %.17g on the diagonal\n", name, given.scalar());
  };
  noise("Q", info.q());
  noise("R", info.r());
  noise("V", info.v());
  noise("W", info.w());
  if (info.has_error()) std::printf("  diverged: %s\n", info.error().message().c_str());
  return kExitOk;
}

int session_close(Client& c, const std::string& id) {
  auto ctx = c.context();
  v1::CloseSessionRequest request;
  request.set_id(id);
  v1::CloseSessionResponse response;
  const grpc::Status s = c.sessions->CloseSession(ctx.get(), request, &response);
  if (!s.ok()) return c.fail("closing session " + id, s);
  if (c.json) std::printf("%s\n", to_json(nlohmann::json{{"id", id}, {"closed", true}}).c_str());
  return kExitOk;
}

int session_retune(Client& c, const std::string& id, const RunSettings& s) {
  if (s.given.empty()) {
    std::fprintf(stderr, "riccati: sessions retune needs --q, --r (EKF, UKF), --v or --w (the optimal filter)\n");
    return kExitUsage;
  }
  const v1::RetuneSessionRequest request = to_retune_request(s, id);
  auto ctx = c.context();
  v1::SessionInfo info;
  const grpc::Status status = c.sessions->RetuneSession(ctx.get(), request, &info);
  if (!status.ok()) return c.fail("retuning session " + id, status);
  if (c.json) {
    std::printf("%s\n", to_json(info).c_str());
    return kExitOk;
  }
  std::printf("retuned %s at t = %.17g s, after %s (retuning %d)\n", info.id().c_str(), info.t(),
              counted(info.measurements(), "measurement").c_str(), info.retunings_size());
  return kExitOk;
}

}  // namespace riccati::cli
