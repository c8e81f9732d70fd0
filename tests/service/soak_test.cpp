// Soak: a real riccatid on loopback under steady load for a bounded time:
// sessions streaming measurements at a rig's pace while identification jobs
// run back to back. No call may fail, and the daemon's memory must not grow
// once warmed up (RSS at the start and the end are printed).
//
//   RICCATI_SOAK_SECONDS=600 RICCATI_SOAK_SESSIONS=50 build/bin/soak_test
//
// CI runs it for 60 s with 20 sessions at 100 Hz (scripts/test.sh, label soak).
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <thread>
#include <vector>

#include "engine/data/dataset.hpp"
#include "riccati/v1/datasets.grpc.pb.h"
#include "riccati/v1/jobs.grpc.pb.h"
#include "riccati/v1/sessions.grpc.pb.h"
#include "service/daemon_fixture.hpp"
#include "support/requests.hpp"

namespace riccati {
namespace {

using Clock = std::chrono::steady_clock;

int env_int(const char* name, int fallback) {
  const char* v = std::getenv(name);
  return v != nullptr && v[0] != '\0' ? std::atoi(v) : fallback;
}

TEST(Soak, SessionsAndJobsForMinutesWithoutErrorsOrMemoryGrowth) {
  const int seconds = env_int("RICCATI_SOAK_SECONDS", 60);
  const int n_sessions = env_int("RICCATI_SOAK_SESSIONS", 20);
  const int rate_hz = env_int("RICCATI_SOAK_RATE", 100);
  testing::TempDir dir;
  testing::DaemonProcess daemon(dir.path() / "data");
  daemon.start();
  auto datasets = v1::DatasetService::NewStub(daemon.channel());
  auto jobs = v1::JobService::NewStub(daemon.channel());
  auto sessions = v1::SessionService::NewStub(daemon.channel());

  const std::string csv_path = std::string(RICCATI_TEST_DATA_DIR) + "/two_tank.csv";
  const Dataset data = read_csv_file(csv_path, ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}}).value();
  std::string dataset_id;
  {
    std::ifstream in(csv_path);
    std::stringstream bytes;
    bytes << in.rdbuf();
    v1::DatasetInfo info;
    ASSERT_TRUE(testing::upload_dataset(*datasets, "two_tank.csv", bytes.str(), {"F1", "F2"}, {"h1", "h2"}, &info).ok());
    dataset_id = info.id();
  }

  const auto start = Clock::now();
  const auto end = start + std::chrono::seconds(seconds);
  std::atomic<long> measurements{0}, failures{0}, jobs_done{0};
  std::vector<std::thread> threads;
  for (int s = 0; s < n_sessions; ++s) {
    threads.emplace_back([&, s] {
      v1::SessionInfo session;
      {
        grpc::ClientContext ctx;
        if (!sessions->CreateSession(&ctx, testing::two_tank_session(), &session).ok()) {
          ++failures;
          return;
        }
      }
      grpc::ClientContext ctx;
      auto stream = sessions->Stream(&ctx);
      v1::StreamRequest request;
      request.mutable_open()->set_session_id(session.id());
      stream->Write(request);
      const auto period = std::chrono::microseconds(1'000'000 / rate_hz);
      auto next = Clock::now() + period * s / n_sessions;  // spread the sessions over a period
      v1::StreamResponse response;
      for (long k = 0; Clock::now() < end; ++k) {
        std::this_thread::sleep_until(next);
        next += period;
        const Eigen::Index i = k % data.size();
        request.Clear();
        testing::add_sample(request, data, i, 0.1 * static_cast<double>(k));
        if (!stream->Write(request) || !stream->Read(&response) || response.results_size() != 1 ||
            !response.results(0).has_estimate()) {
          ++failures;
          return;
        }
        ++measurements;
      }
      stream->WritesDone();
      if (!stream->Finish().ok()) ++failures;
    });
  }
  threads.emplace_back([&] {
    while (Clock::now() < end) {
      grpc::ClientContext ctx;
      v1::Job job;
      if (!jobs->SubmitIdentification(&ctx, testing::hensen_spec(dataset_id, 3), &job).ok()) {
        ++failures;
        return;
      }
      grpc::ClientContext watch_ctx;
      v1::WatchJobRequest watch;
      watch.set_id(job.id());
      auto reader = jobs->WatchJob(&watch_ctx, watch);
      v1::Job seen;
      while (reader->Read(&seen)) {
      }
      if (!reader->Finish().ok() || seen.state() != v1::JOB_STATE_SUCCEEDED) {
        ++failures;
        return;
      }
      ++jobs_done;
    }
  });

  // Memory once warmed up (allocator pools, gRPC buffers, SQLite cache), and at the end.
  std::this_thread::sleep_until(start + std::chrono::seconds(std::max(5, seconds / 10)));
  const long rss_warm = daemon.rss_kib();
  const long measurements_warm = measurements.load();
  for (auto& t : threads) t.join();
  const long rss_end = daemon.rss_kib();
  const double elapsed = std::chrono::duration<double>(Clock::now() - start).count();

  // Growth after warm-up, against what a leak of 100 bytes per measurement
  // would add over the same measurements: with the defaults (60 s, 20
  // sessions at 100 Hz; CI's) 54 s x 2000/s = 108,000 measurements, 10.3
  // MiB. Observed on the 2-core machine (2026-11-24): 0.9 to 1.3 MiB in
  // four runs of 60 s, alone and beside other service tests, and 1.0 MiB
  // in 180 s, so it does not grow with time (SQLite's page cache, gRPC's
  // and the allocator's pools settling). 4 MiB is 3 times the most seen
  // and 2.6 times less than that leak; longer runs catch smaller leaks.
  const long kBoundKib = 4 * 1024;
  const long leak_kib = (measurements.load() - measurements_warm) * 100 / 1024;
  std::printf("soak: %d s, %d sessions at %d Hz, %ld measurements (%.0f/s), %ld jobs, %ld failures; "
              "daemon RSS %ld KiB warm, %ld KiB at the end: %+ld KiB (bound %ld KiB; a leak of 100 B per "
              "measurement would have added %ld KiB over the %ld measurements after warm-up)\n",
              seconds, n_sessions, rate_hz, measurements.load(), measurements.load() / elapsed, jobs_done.load(),
              failures.load(), rss_warm, rss_end, rss_end - rss_warm, kBoundKib, leak_kib,
              measurements.load() - measurements_warm);
  EXPECT_EQ(failures.load(), 0);
  EXPECT_GT(jobs_done.load(), 0);
  // At least 90% of the paced measurements went through (a loaded 2-core
  // machine may lag a little; it must not stall).
  EXPECT_GT(measurements.load(), static_cast<long>(0.9 * seconds * rate_hz * n_sessions));
  EXPECT_LT(rss_end - rss_warm, kBoundKib) << "KiB";
  if (leak_kib <= kBoundKib) {
    std::printf("soak: this run is too short for the bound to catch a leak of 100 B per measurement\n");
  }
  EXPECT_EQ(daemon.stop(), 0) << daemon.exit_report();
}

}  // namespace
}  // namespace riccati
