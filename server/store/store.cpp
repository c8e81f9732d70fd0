#include "store/store.hpp"

#include <charconv>
#include <cstdio>

namespace riccati {

const char* job_state_name(JobState state) {
  switch (state) {
    case JobState::kQueued: return "queued";
    case JobState::kRunning: return "running";
    case JobState::kSucceeded: return "succeeded";
    case JobState::kFailed: return "failed";
    case JobState::kCancelled: return "cancelled";
  }
  return "unknown";
}

std::optional<JobState> parse_job_state(const std::string& name) {
  for (JobState state : {JobState::kQueued, JobState::kRunning, JobState::kSucceeded, JobState::kFailed,
                         JobState::kCancelled}) {
    if (name == job_state_name(state)) return state;
  }
  return std::nullopt;
}

namespace {
constexpr JobKind kKnownJobKinds[] = {JobKind::kIdentification, JobKind::kValidation, JobKind::kSmoothing};
}  // namespace

const char* job_kind_name(JobKind kind) {
  switch (kind) {
    case JobKind::kIdentification: return "identification";
    case JobKind::kValidation: return "validation";
    case JobKind::kSmoothing: return "smoothing";
    case JobKind::kUnknown: break;
  }
  return "unknown";
}

JobKind parse_job_kind(const std::string& name) {
  for (JobKind kind : kKnownJobKinds) {
    if (name == job_kind_name(kind)) return kind;
  }
  return JobKind::kUnknown;
}

std::string known_job_kinds_sql() {
  std::string list;
  for (JobKind kind : kKnownJobKinds) {
    list += std::string(list.empty() ? "" : ", ") + "'" + job_kind_name(kind) + "'";
  }
  return list;
}

std::string encode_named_values(const std::map<std::string, double>& values) {
  std::string out;
  char number[32];
  for (const auto& [name, value] : values) {
    const auto end = std::to_chars(number, number + sizeof number, value).ptr;  // shortest round trip
    out.append(name).append("=").append(number, end).append("\n");
  }
  return out;
}

std::map<std::string, double> decode_named_values(const std::string& text) {
  std::map<std::string, double> values;
  std::size_t at = 0;
  while (at < text.size()) {
    std::size_t end = text.find('\n', at);
    if (end == std::string::npos) end = text.size();
    const std::size_t equals = text.find('=', at);
    if (equals < end) {
      double value = 0.0;
      std::from_chars(text.data() + equals + 1, text.data() + end, value);
      values[text.substr(at, equals - at)] = value;
    }
    at = end + 1;
  }
  return values;
}

bool is_terminal(JobState state) {
  return state == JobState::kSucceeded || state == JobState::kFailed || state == JobState::kCancelled;
}

Status job_lease_lost(const std::string& id, const std::string& owner) {
  return {StatusCode::kAborted, "job " + id + " is no longer held by " + owner +
                                    " (it ended, or its lease expired and another instance took it)"};
}

Status job_not_ended(const std::string& id, const std::string& state) {
  return failed_precondition("job " + id + " is " + state +
                             ": cancel it (CancelJob, riccati job cancel) and delete it once it has ended");
}

Status session_lease_lost(const std::string& id, const std::string& owner) {
  return {StatusCode::kAborted, "session " + id + " is no longer held by " + owner +
                                    " (its lease expired and another instance resumed it)"};
}

Status session_held_elsewhere(const std::string& id, const std::string& holder, std::int64_t remaining_ms) {
  char seconds[32];
  std::snprintf(seconds, sizeof seconds, "%.1f", static_cast<double>(remaining_ms) / 1000.0);
  return {StatusCode::kFailedPrecondition,
          "session " + id + " is held by instance " + holder + " (lease for " + seconds +
              " s more): open its stream there, or here once that instance has stopped"};
}

Status Store::put_session_snapshot(const std::string& tenant, const std::string& session_id, const std::string& owner,
                                   std::int64_t lease_ms, const std::string& snapshot) {
  const std::vector<SessionSnapshotWrite> one = {{tenant, session_id, snapshot}};
  RICCATI_ASSIGN_OR_RETURN(const std::vector<Status> stored, put_session_snapshots(owner, lease_ms, one));
  return stored.front();
}

Result<std::string> named_object(const std::string& request_id, const std::string& stored_kind,
                                 const std::string& object_id, const std::string& kind) {
  if (stored_kind != kind) {
    return invalid_argument("request_id \"" + request_id + "\" was given to create " + stored_kind + " " + object_id +
                            ", not a " + kind + ": give each request its own id");
  }
  return object_id;
}

}  // namespace riccati
