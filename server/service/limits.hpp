// What one tenant, and the daemon as a whole, may use. Every limit has a
// config key and a flag of the same name (--max-..., from kLimitSpecs, so
// the two cannot drift apart); a request past one is answered
// RESOURCE_EXHAUSTED with a message that names the limit and its value.
#pragma once

#include <cstdint>
#include <string>

#include "engine/status.hpp"

namespace riccati::service {

struct Limits {
  std::int64_t max_message_bytes = 64ll << 20;         // largest gRPC message received
  std::int64_t max_dataset_bytes = 256ll << 20;        // one upload, and its values inflated
  std::int64_t max_dataset_samples = 10'000'000;       // samples of one dataset
  std::int64_t max_tenant_dataset_bytes = 4ll << 30;   // all of a tenant's stored datasets
  std::int64_t max_batch = 4096;                       // measurements per stream message
  std::int64_t max_sessions = 1000;                    // open sessions, all tenants
  std::int64_t max_tenant_sessions = 100;              // open sessions of one tenant
  std::int64_t max_jobs = 1000;                        // queued and running jobs, all tenants
  std::int64_t max_tenant_jobs = 100;                  // queued and running jobs of one tenant
  std::int64_t max_passes = 10'000;                    // passes of one identification
  std::int64_t max_simulation_steps = 20'000'000;      // integration steps of one Simulate call; of one sample elsewhere
  std::int64_t max_simulations = 4;                    // Simulate calls running at once, all tenants
  std::int64_t max_time_step_s = 3600;                 // a session's step between two measurements
  std::int64_t max_uploads = 16;                       // uploads in flight, all tenants
  std::int64_t max_result_bytes = 256ll << 20;         // a job's result, as estimated at submit
  std::int64_t max_job_attempts = 3;                   // claims of one job that did not end it
  std::int64_t max_tenant_result_bytes = 4ll << 30;    // all of a tenant's stored job results
  std::int64_t max_tenant_jobs_kept = 10'000;          // ended jobs kept per tenant (older ones deleted)
  std::int64_t max_job_age_days = 365;                 // ended jobs older than this are deleted
  std::int64_t max_streams = 4096;                     // long-lived calls open, all tenants
  std::int64_t max_tenant_streams = 256;               // long-lived calls open, one tenant
  std::int64_t max_tenant_models = 1000;               // stored text model revisions of one tenant
  std::int64_t max_tenant_model_bytes = 64ll << 20;    // their sources, bytes
  std::int64_t max_stored_request_bytes = 1ll << 20;   // a job's spec or a session's request, as stored
  std::int64_t max_tenant_uploads = 4;                 // uploads in flight, one tenant
  std::int64_t upload_idle_seconds = 60;               // an upload that sends nothing for this long is ended
  std::int64_t max_result_read_bytes = 512ll << 20;    // stored results being read at once, all tenants
  std::int64_t max_model_check_operations = 1'000'000'000;  // a text model's Jacobian check, estimated
  std::int64_t max_tenant_event_streams = 16;          // workbench event streams open, one tenant (of 32)
};

struct LimitSpec {
  const char* key;  // config key; the flag is --key with '-' for '_'
  std::int64_t Limits::*value;
  const char* help;
};

inline constexpr LimitSpec kLimitSpecs[] = {
    {"max_message_bytes", &Limits::max_message_bytes, "Largest gRPC message received (bytes)"},
    {"max_dataset_bytes", &Limits::max_dataset_bytes, "Largest upload, and most bytes the values of a MAT upload may inflate to"},
    {"max_dataset_samples", &Limits::max_dataset_samples, "Most samples in one dataset"},
    {"max_tenant_dataset_bytes", &Limits::max_tenant_dataset_bytes, "All of a tenant's datasets (bytes uploaded)"},
    {"max_batch", &Limits::max_batch, "Most measurements in one stream message"},
    {"max_sessions", &Limits::max_sessions, "Most open sessions, all tenants"},
    {"max_tenant_sessions", &Limits::max_tenant_sessions, "Most open sessions of one tenant"},
    {"max_jobs", &Limits::max_jobs, "Most queued and running jobs, all tenants"},
    {"max_tenant_jobs", &Limits::max_tenant_jobs, "Most queued and running jobs of one tenant"},
    {"max_passes", &Limits::max_passes, "Most passes of one identification"},
    {"max_simulation_steps", &Limits::max_simulation_steps,
     "Most integration steps (substeps, or an adaptive integrator's internal steps) of one Simulate call, and of "
     "one sample of a session or job"},
    {"max_simulations", &Limits::max_simulations, "Most Simulate calls running at once, all tenants"},
    {"max_time_step_s", &Limits::max_time_step_s,
     "Longest step between two measurements of a session (s): a longer one is refused, the session goes on"},
    {"max_uploads", &Limits::max_uploads, "Most uploads in flight, all tenants"},
    {"max_result_bytes", &Limits::max_result_bytes,
     "Largest result of one job (bytes), as estimated at submit from its samples, passes and model"},
    {"max_job_attempts", &Limits::max_job_attempts,
     "Most times a job is claimed without ending (its instance died, or could not store its end) before it fails"},
    {"max_tenant_result_bytes", &Limits::max_tenant_result_bytes,
     "All of a tenant's stored job results (bytes): a job whose estimated result would pass it is refused at submit"},
    {"max_tenant_jobs_kept", &Limits::max_tenant_jobs_kept,
     "Most ended jobs kept per tenant: the oldest beyond it are deleted with their results"},
    {"max_job_age_days", &Limits::max_job_age_days,
     "Ended jobs older than this (days) are deleted with their results"},
    {"max_streams", &Limits::max_streams,
     "Most long-lived calls open at once (session streams, job watches, uploads, workbench event streams), all "
     "tenants"},
    {"max_tenant_streams", &Limits::max_tenant_streams,
     "Most long-lived calls open at once (session streams, job watches, uploads, workbench event streams) of one "
     "tenant"},
    {"max_tenant_models", &Limits::max_tenant_models,
     "Most stored text model revisions of one tenant (every CreateModel is one; a deleted model's no longer count)"},
    {"max_tenant_model_bytes", &Limits::max_tenant_model_bytes,
     "All of a tenant's stored text model revisions (bytes of source; a deleted model's no longer count)"},
    {"max_stored_request_bytes", &Limits::max_stored_request_bytes,
     "Largest job spec or session request kept in the store (bytes, encoded): its settings, masks and names"},
    {"max_tenant_uploads", &Limits::max_tenant_uploads,
     "Most uploads in flight of one tenant (its share of max_uploads)"},
    {"upload_idle_seconds", &Limits::upload_idle_seconds,
     "An upload that sends no bytes for this long (s) is ended with DEADLINE_EXCEEDED, its room given back"},
    {"max_result_read_bytes", &Limits::max_result_read_bytes,
     "Stored results being read at once (GetResult and CompareJobs, gRPC and HTTP), all tenants (bytes as stored; each takes 3 to 5 "
     "times that while converted): a read waits for room, then is refused"},
    {"max_model_check_operations", &Limits::max_model_check_operations,
     "Most operations (about nanoseconds) of a text model's Jacobian check, estimated from its size before it "
     "runs: CreateModel refuses a model past it"},
    {"max_tenant_event_streams", &Limits::max_tenant_event_streams,
     "Most workbench event streams (job and session events over HTTP) open at once by one tenant, of the 32 the "
     "workbench serves"},
};

// RESOURCE_EXHAUSTED: "limit <key> = <limit> reached: <what>".
inline Status limit_reached(const char* key, std::int64_t limit, const std::string& what) {
  return {StatusCode::kResourceExhausted,
          std::string("limit ") + key + " = " + std::to_string(limit) + " reached: " + what};
}

}  // namespace riccati::service
