// Soak: a real riccatid on loopback under steady load for a bounded time:
// sessions streaming measurements at a rig's pace while identification jobs
// run back to back. No call may fail, and the daemon's memory must not grow
// once warmed up (RSS at the start and the end are printed).
//
//   RICCATI_SOAK_SECONDS=600 RICCATI_SOAK_SESSIONS=50 build/bin/soak_test
//
// CI runs it for 60 s with 20 sessions at 100 Hz (scripts/test.sh, label
// soak), and the mixed load below for 60 s.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <cmath>
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

// What the daemon holds, read from /proc: resident memory, threads, open
// file descriptors, and the store's files (the database and its WAL).
struct Footprint {
  double seconds = 0;
  long rss_kib = 0;
  long threads = 0;
  long fds = 0;
  long store_kib = 0;
};

long count_fds(pid_t pid) {
  std::error_code ec;
  long n = 0;
  for (auto it = std::filesystem::directory_iterator("/proc/" + std::to_string(pid) + "/fd", ec);
       !ec && it != std::filesystem::directory_iterator(); it.increment(ec)) {
    ++n;
  }
  return n;
}

long store_kib(const std::filesystem::path& data_dir) {
  std::error_code ec;
  std::uintmax_t bytes = 0;
  for (const char* name : {"riccati.db", "riccati.db-wal", "riccati.db-shm"}) {
    const auto size = std::filesystem::file_size(data_dir / name, ec);
    if (!ec) bytes += size;
  }
  return static_cast<long>(bytes / 1024);
}

// The adversarial mix of issue 15, for minutes: sessions streaming (with a
// NaN measurement now and then), uploads and deletions (with bad files among
// them), identification jobs watched to their end, bursts of watches opened
// and cancelled, Simulate calls (with one past max_simulation_steps among
// them). Every call must get the answer it should, and the daemon's memory,
// threads, file descriptors and store must stay bounded: retention
// (max_tenant_jobs_kept) keeps the store from growing with the jobs.
//
//   RICCATI_SOAK_SECONDS=600 build/bin/soak_test --gtest_filter=Soak.Mixed*
TEST(Soak, MixedLoadWithBadInputsKeepsMemoryThreadsFilesAndTheStoreBounded) {
  const int seconds = env_int("RICCATI_SOAK_SECONDS", 60);
  const int n_sessions = 10;
  const int rate_hz = 100;
  testing::TempDir dir;
  const auto data_dir = dir.path() / "data";
  testing::DaemonProcess daemon(data_dir, {"--max-tenant-jobs-kept", "20", "--max-simulation-steps", "2000000"});
  daemon.start();
  auto datasets = v1::DatasetService::NewStub(daemon.channel());
  auto jobs = v1::JobService::NewStub(daemon.channel());
  auto sessions = v1::SessionService::NewStub(daemon.channel());
  auto models = v1::ModelService::NewStub(daemon.channel());

  const std::string csv_path = std::string(RICCATI_TEST_DATA_DIR) + "/two_tank.csv";
  const Dataset data = read_csv_file(csv_path, ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}}).value();
  const std::string csv = testing::read_file(csv_path);
  std::string dataset_id;
  {
    v1::DatasetInfo info;
    ASSERT_TRUE(testing::upload_dataset(*datasets, "two_tank.csv", csv, {"F1", "F2"}, {"h1", "h2"}, &info).ok());
    dataset_id = info.id();
  }

  const auto start = Clock::now();
  const auto end = start + std::chrono::seconds(seconds);
  std::atomic<long> failures{0}, measurements{0}, refused_measurements{0}, jobs_done{0}, uploads{0},
      bad_uploads{0}, watches{0}, simulations{0};
  std::mutex failure_mu;
  std::string first_failure;
  auto fail = [&](const std::string& what) {
    if (failures++ == 0) {
      std::lock_guard lock(failure_mu);
      first_failure = what;
    }
  };
  std::vector<std::thread> threads;

  // Sessions at a rig's pace; every 500th measurement has a NaN output,
  // which is refused alone while the session goes on.
  for (int s = 0; s < n_sessions; ++s) {
    threads.emplace_back([&, s] {
      v1::SessionInfo session;
      {
        grpc::ClientContext ctx;
        if (!sessions->CreateSession(&ctx, testing::two_tank_session(), &session).ok()) return fail("CreateSession");
      }
      grpc::ClientContext ctx;
      auto stream = sessions->Stream(&ctx);
      v1::StreamRequest request;
      request.mutable_open()->set_session_id(session.id());
      stream->Write(request);
      const auto period = std::chrono::microseconds(1'000'000 / rate_hz);
      auto next = Clock::now() + period * s / n_sessions;
      v1::StreamResponse response;
      for (long k = 0; Clock::now() < end; ++k) {
        std::this_thread::sleep_until(next);
        next += period;
        request.Clear();
        v1::Measurement* m = testing::add_sample(request, data, k % data.size(), 0.1 * static_cast<double>(k));
        const bool bad = k % 500 == 499;
        if (bad) m->set_y(0, std::nan(""));
        if (!stream->Write(request) || !stream->Read(&response) || response.results_size() != 1) {
          return fail("stream");
        }
        if (bad != !response.results(0).has_estimate()) return fail("measurement " + std::to_string(k));
        ++(bad ? refused_measurements : measurements);
      }
      stream->WritesDone();
      if (!stream->Finish().ok()) fail("stream end");
      grpc::ClientContext close_ctx;
      v1::CloseSessionRequest close;
      close.set_id(session.id());
      v1::CloseSessionResponse closed;
      if (!sessions->CloseSession(&close_ctx, close, &closed).ok()) fail("CloseSession");
    });
  }
  // Identifications, each watched to its end.
  threads.emplace_back([&] {
    while (Clock::now() < end) {
      grpc::ClientContext ctx;
      v1::Job job;
      if (!jobs->SubmitIdentification(&ctx, testing::hensen_spec(dataset_id, 2), &job).ok()) return fail("submit");
      grpc::ClientContext watch_ctx;
      v1::WatchJobRequest watch;
      watch.set_id(job.id());
      auto reader = jobs->WatchJob(&watch_ctx, watch);
      v1::Job seen;
      while (reader->Read(&seen)) {
      }
      if (!reader->Finish().ok() || seen.state() != v1::JOB_STATE_SUCCEEDED) return fail("job " + job.id());
      ++jobs_done;
    }
  });
  // Uploads of the dataset, deleted again; and bad files, refused.
  threads.emplace_back([&] {
    const std::vector<std::pair<std::string, std::string>> bad_files = {
        {"missing_column.csv", "t,F1,h1,h2\n0,1,1,1\n1,1,1,1\n"},
        {"backwards.csv", "t,F1,F2,h1,h2\n0,1,1,1,1\n1,1,1,1,1\n0.5,1,1,1,1\n"},
        {"junk.csv", std::string("\x00\xff\x1b[2J", 6)},
        {"junk.mat", "MATLAB 5.0 MAT-file, but nothing after"}};
    for (long k = 0; Clock::now() < end; ++k) {
      v1::DatasetInfo info;
      grpc::ClientContext ctx;
      if (!testing::upload_dataset(*datasets, &ctx, "again.csv", csv, {"F1", "F2"}, {"h1", "h2"}, &info, 64 << 10,
                                   /*declare_size=*/k % 2 == 0)
               .ok()) {
        return fail("upload");
      }
      grpc::ClientContext delete_ctx;
      v1::DeleteDatasetRequest del;
      del.set_id(info.id());
      v1::DeleteDatasetResponse deleted;
      if (!datasets->DeleteDataset(&delete_ctx, del, &deleted).ok()) return fail("DeleteDataset");
      ++uploads;
      const auto& [name, bytes] = bad_files[static_cast<std::size_t>(k) % bad_files.size()];
      grpc::ClientContext bad_ctx;
      const grpc::Status s =
          testing::upload_dataset(*datasets, &bad_ctx, name, bytes, {"F1", "F2"}, {"h1", "h2"}, &info);
      if (s.error_code() != grpc::StatusCode::INVALID_ARGUMENT) return fail("bad upload " + name + ": " + s.error_message());
      ++bad_uploads;
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
  });
  // Bursts of 50 watches of the dataset's jobs, opened and cancelled.
  threads.emplace_back([&] {
    while (Clock::now() < end) {
      grpc::ClientContext list_ctx;
      v1::ListJobsResponse listed;
      if (!jobs->ListJobs(&list_ctx, {}, &listed).ok()) return fail("ListJobs");
      if (listed.jobs().empty()) {
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
        continue;
      }
      std::vector<std::unique_ptr<grpc::ClientContext>> contexts;
      std::vector<std::unique_ptr<grpc::ClientReader<v1::Job>>> readers;
      for (int i = 0; i < 50; ++i) {
        contexts.push_back(std::make_unique<grpc::ClientContext>());
        v1::WatchJobRequest watch;
        watch.set_id(listed.jobs(listed.jobs_size() - 1).id());
        readers.push_back(jobs->WatchJob(contexts.back().get(), watch));
        v1::Job first;
        if (!readers.back()->Read(&first)) {
          const grpc::Status s = readers.back()->Finish();
          // The job may have been deleted by retention meanwhile.
          if (s.error_code() != grpc::StatusCode::NOT_FOUND && !s.ok()) return fail("watch: " + s.error_message());
          readers.pop_back();
          contexts.pop_back();
        }
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
      for (auto& c : contexts) c->TryCancel();
      for (auto& r : readers) r->Finish();
      watches += static_cast<long>(readers.size());
    }
  });
  // Simulations, and now and then one past max_simulation_steps.
  threads.emplace_back([&] {
    for (long k = 0; Clock::now() < end; ++k) {
      const bool too_big = k % 10 == 9;
      v1::SimulateRequest r;
      r.set_model("two_tank");
      for (double x : {0.4, 0.15}) r.add_x0(x);
      const int samples = 200;
      for (int i = 0; i < samples; ++i) r.add_t(0.1 * i);
      r.mutable_u()->set_rows(2);
      r.mutable_u()->set_cols(samples);
      for (int i = 0; i < 2 * samples; ++i) r.mutable_u()->add_values(0.01);
      r.mutable_integrator()->set_substeps(too_big ? 100'000 : 10);
      grpc::ClientContext ctx;
      v1::SimulateResponse response;
      const grpc::Status s = models->Simulate(&ctx, r, &response);
      if (too_big ? s.error_code() != grpc::StatusCode::RESOURCE_EXHAUSTED : !s.ok()) {
        return fail("simulate: " + s.error_message());
      }
      ++simulations;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
  });

  // The footprint every tenth of the run (at least every 10 s).
  std::vector<Footprint> samples;
  const auto every = std::chrono::seconds(std::max(2, std::min(10, seconds / 10)));
  for (auto at = start; at < end; at += every) {
    std::this_thread::sleep_until(at);
    samples.push_back({std::chrono::duration<double>(Clock::now() - start).count(), daemon.rss_kib(),
                       daemon.threads(), count_fds(daemon.pid()), store_kib(data_dir)});
  }
  for (auto& t : threads) t.join();
  samples.push_back({std::chrono::duration<double>(Clock::now() - start).count(), daemon.rss_kib(), daemon.threads(),
                     count_fds(daemon.pid()), store_kib(data_dir)});

  std::printf("soak mixed: %d s: %ld measurements (%ld NaN refused), %ld jobs, %ld uploads and deletions, %ld bad "
              "uploads refused, %ld watches, %ld simulations, %ld failures%s%s\n",
              seconds, measurements.load(), refused_measurements.load(), jobs_done.load(), uploads.load(),
              bad_uploads.load(), watches.load(), simulations.load(), failures.load(),
              first_failure.empty() ? "" : ", the first: ", first_failure.c_str());
  std::printf("soak mixed:      s   RSS KiB  threads  fds  store KiB\n");
  for (const Footprint& f : samples) {
    std::printf("soak mixed: %6.0f %9ld %8ld %4ld %10ld\n", f.seconds, f.rss_kib, f.threads, f.fds, f.store_kib);
  }
  EXPECT_EQ(failures.load(), 0) << first_failure;
  EXPECT_GT(jobs_done.load(), 0);
  EXPECT_GT(uploads.load(), 0);
  EXPECT_GT(watches.load(), 0);
  EXPECT_GT(simulations.load(), 0);
  EXPECT_GT(refused_measurements.load(), 0);
  // Bounded after warm-up (the second tenth on): every later sample within
  // a margin of the warm one. The margins hold what gRPC's pools, SQLite's
  // cache and the allocator settle to; growth with the work done (a thread,
  // a descriptor or a job's rows per call) passes them within a minute.
  ASSERT_GE(samples.size(), 3u);
  const Footprint& warm = samples[1];
  for (std::size_t i = 2; i < samples.size(); ++i) {
    const Footprint& f = samples[i];
    EXPECT_LE(f.threads, warm.threads + 16) << "threads at " << f.seconds << " s";
    EXPECT_LE(f.fds, warm.fds + 32) << "file descriptors at " << f.seconds << " s";
    if (!testing::kSanitized) {
      EXPECT_LE(f.rss_kib, warm.rss_kib + 16 * 1024) << "RSS at " << f.seconds << " s";
    }
    // Retention keeps 20 jobs; the uploads' rows are deleted and their pages reused.
    EXPECT_LE(f.store_kib, std::max(2 * warm.store_kib, warm.store_kib + 16 * 1024)) << "store at " << f.seconds << " s";
  }
  datasets.reset();
  jobs.reset();
  sessions.reset();
  models.reset();
  EXPECT_EQ(daemon.stop(), 0) << daemon.exit_report();
}

}  // namespace
}  // namespace riccati
