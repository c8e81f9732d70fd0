#include "store/store.hpp"

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

bool is_terminal(JobState state) {
  return state == JobState::kSucceeded || state == JobState::kFailed || state == JobState::kCancelled;
}

Status job_lease_lost(const std::string& id, const std::string& owner) {
  return {StatusCode::kAborted, "job " + id + " is no longer held by " + owner +
                                    " (it ended, or its lease expired and another instance took it)"};
}

}  // namespace riccati
