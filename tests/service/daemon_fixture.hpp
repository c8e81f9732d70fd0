// A real riccatid, started as a child process on a free loopback port with
// its own data directory, for tests that talk to it over gRPC.
#pragma once

#include <fcntl.h>

#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <future>
#include <limits>
#include <memory>
#include <stdexcept>
#include <sstream>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "riccati/v1/datasets.grpc.pb.h"
#include "riccati/v1/jobs.grpc.pb.h"
#include "riccati/v1/models.grpc.pb.h"
#include "riccati/v1/sessions.grpc.pb.h"
#include "support/requests.hpp"
#include "support/wait.hpp"

namespace riccati::testing {

// The sanitized build (scripts/sanitize.sh), where everything runs tens of
// times slower and RSS means nothing: tests that load the daemon with work
// do less of it there, and memory bounds are not checked.
#ifdef RICCATI_SANITIZED
inline constexpr bool kSanitized = true;
#else
inline constexpr bool kSanitized = false;
#endif

class DaemonProcess {
 public:
  // `data_dir` is kept across stop() and start(), so a restart finds its data.
  explicit DaemonProcess(std::filesystem::path data_dir, std::vector<std::string> extra_args = {})
      : data_dir_(std::move(data_dir)), extra_args_(std::move(extra_args)) {}
  // A daemon still running at the end is stopped as an operator would
  // (SIGTERM), and must exit 0: a sanitizer's report at exit (LeakSanitizer
  // among them) makes the exit status non-zero, and fails the test here.
  // Tests that mean to kill a daemon do it themselves (kill_now()).
  ~DaemonProcess() {
    if (pid_ <= 0) return;
    const int status = stop();
    if (status != 0) {
      ADD_FAILURE() << "riccatid (pid " << last_pid_ << ") did not stop cleanly at the end of the test: "
                    << exit_report();
    }
  }
  DaemonProcess(const DaemonProcess&) = delete;
  DaemonProcess& operator=(const DaemonProcess&) = delete;

  // How long a SIGTERM may take before the daemon is killed and the stop
  // counts as failed: its shutdown grace is 5 s; the rest is for a loaded
  // machine or a sanitized build.
  static constexpr std::chrono::seconds kStopDeadline{kSanitized ? 120 : 30};

  void start() {
    const auto port_file = data_dir_ / "port";
    std::filesystem::create_directories(data_dir_);
    std::filesystem::remove(port_file);
    // Defaults, unless the test gives the flag itself.
    const std::vector<std::pair<std::string, std::string>> defaults = {
        {"--models-dir", RICCATI_TEST_PLUGIN_DIR}, {"--workers", "2"}, {"--log-level", log_level()}};
    std::vector<std::string> args = {RICCATI_DAEMON_BIN, "--listen", "127.0.0.1:0", "--data-dir", data_dir_.string(),
                                     "--port-file", port_file.string()};
    for (const auto& [flag, value] : defaults) {
      if (std::find(extra_args_.begin(), extra_args_.end(), flag) == extra_args_.end()) {
        args.push_back(flag);
        args.push_back(value);
      }
    }
    args.insert(args.end(), extra_args_.begin(), extra_args_.end());
    log_start_ = 0;
    if (!log_file_.empty()) {
      std::error_code ec;
      const auto size = std::filesystem::file_size(log_file_, ec);
      log_start_ = ec ? 0 : size;
    }
    pid_ = fork();
    if (pid_ == 0) {
      if (!log_file_.empty()) {
        const int fd = ::open(log_file_.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
        if (fd >= 0) dup2(fd, STDERR_FILENO);
      }
      if (file_size_limit_ > 0) {
        const rlimit limit{file_size_limit_, file_size_limit_};
        setrlimit(RLIMIT_FSIZE, &limit);
      }
      std::vector<char*> argv;
      for (auto& a : args) argv.push_back(a.data());
      argv.push_back(nullptr);
      execv(argv[0], argv.data());
      _exit(127);
    }
    // Wait for the port file (the daemon writes it once it listens).
    for (int i = 0; i < 1000; ++i) {
      std::ifstream in(port_file);
      if (in >> port_ && port_ > 0) break;
      int status = 0;
      if (waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        throw std::runtime_error("riccatid exited at start: " + describe(status) + stderr_hint());
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    if (port_ <= 0) throw std::runtime_error("riccatid did not start listening");
    grpc::ChannelArguments channel_args;
    channel_args.SetMaxReceiveMessageSize(-1);  // unlimited: results of long identifications are large
    channel_ = grpc::CreateCustomChannel(address(), grpc::InsecureChannelCredentials(), channel_args);
  }

  // The daemon's log level: warn, or RICCATI_TEST_LOG_LEVEL (to debug a test).
  static std::string log_level() {
    const char* level = std::getenv("RICCATI_TEST_LOG_LEVEL");
    return level != nullptr && level[0] != '\0' ? level : "warn";
  }

  // The daemon's log (its standard error) goes to this file, appended, from
  // the next start() on; empty: the test's own standard error.
  void set_log_file(std::filesystem::path path) { log_file_ = std::move(path); }
  // The largest file the daemon may write (RLIMIT_FSIZE, as `ulimit -f` or
  // systemd's LimitFSIZE set it), from the next start(); 0: no limit.
  void set_file_size_limit(std::uint64_t bytes) { file_size_limit_ = bytes; }

  // SIGTERM, then wait up to kStopDeadline (then SIGKILL); returns the exit
  // status: 0 for a clean stop, 128 + the signal for a death by signal (a
  // sanitizer report with abort_on_error is SIGABRT; a stop that timed out
  // is SIGKILL). exit_report() says which, in words.
  int stop() { return signal_and_wait(SIGTERM); }
  // SIGKILL, as a crash would.
  int kill_now() { return signal_and_wait(SIGKILL); }
  // The last stop or kill, in words ("exit status 0", "killed by signal 9
  // (Killed) after 30 s without stopping on SIGTERM", ...), and where the
  // daemon's standard error is (the end of its log file, when it has one):
  // for the message of a test that checks what stop() returned.
  std::string exit_report() const { return last_exit_ + stderr_hint(); }
  // SIGSTOP and SIGCONT: a frozen daemon does nothing until thawed (or
  // killed), so a test can look at the shared store while it holds still.
  void freeze() const {
    if (pid_ > 0) ::kill(pid_, SIGSTOP);
  }
  void thaw() const {
    if (pid_ > 0) ::kill(pid_, SIGCONT);
  }

  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }
  std::shared_ptr<grpc::Channel> channel() const { return channel_; }
  // A new channel to the daemon with other credentials (TLS).
  std::shared_ptr<grpc::Channel> channel(const std::shared_ptr<grpc::ChannelCredentials>& credentials) const {
    return grpc::CreateChannel(address(), credentials);
  }
  const std::filesystem::path& data_dir() const { return data_dir_; }
  pid_t pid() const { return pid_; }
  // Resident memory of the daemon (VmRSS), in KiB.
  long rss_kib() const { return proc_status("VmRSS:"); }
  // The most resident memory the daemon has had (its high-water mark).
  long peak_rss_kib() const { return proc_status("VmHWM:"); }
  long threads() const { return proc_status("Threads:"); }

 private:
  // A number from /proc/<pid>/status (-1: none).
  long proc_status(const std::string& key) const {
    std::ifstream status("/proc/" + std::to_string(pid_) + "/status");
    std::string line;
    while (std::getline(status, line)) {
      if (line.rfind(key, 0) == 0) return std::stol(line.substr(key.size()));
    }
    return -1;
  }

  int signal_and_wait(int sig) {
    if (pid_ <= 0) return -1;
    // Our channel goes first: a daemon that stops waits for its clients'
    // connections to close (up to its grace period), and with no stub left
    // on this one it closes now rather than at gRPC's next poll.
    channel_.reset();
    ::kill(pid_, SIGCONT);  // a frozen daemon (freeze()) handles no signal but SIGKILL
    ::kill(pid_, sig);
    int status = 0;
    bool timed_out = false;
    if (sig == SIGKILL) {
      waitpid(pid_, &status, 0);
    } else {
      const auto deadline = std::chrono::steady_clock::now() + kStopDeadline;
      while (waitpid(pid_, &status, WNOHANG) == 0) {
        if (std::chrono::steady_clock::now() > deadline) {
          timed_out = true;
          ::kill(pid_, SIGKILL);
          waitpid(pid_, &status, 0);
          break;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
      }
    }
    last_pid_ = pid_;
    last_exit_ = describe(status) + (timed_out ? " after " + std::to_string(kStopDeadline.count()) +
                                                     " s without stopping on SIGTERM"
                                               : "");
    pid_ = -1;
    port_ = 0;
    return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  }

  static std::string describe(int status) {
    if (WIFEXITED(status)) {
      const int code = WEXITSTATUS(status);
      return "exit status " + std::to_string(code) + (code == 23 ? " (LeakSanitizer's: leaks)" : "");
    }
    if (WIFSIGNALED(status)) {
      const int sig = WTERMSIG(status);
      return "killed by signal " + std::to_string(sig) + " (" + strsignal(sig) + ")" +
             (sig == SIGABRT ? ", as a sanitizer report with abort_on_error is" : "");
    }
    return "wait status " + std::to_string(status);
  }

  // Where the daemon's standard error (its log, and any sanitizer report)
  // is: the end of the log file, or the test's own output.
  std::string stderr_hint() const {
    if (log_file_.empty()) return "; its standard error is in the test's output above";
    std::ifstream in(log_file_, std::ios::binary);
    constexpr std::streamoff kTail = 16 * 1024;
    in.seekg(0, std::ios::end);
    const std::streamoff end = in.tellg();
    const std::streamoff from = std::max<std::streamoff>(static_cast<std::streamoff>(log_start_), end - kTail);
    in.seekg(from);
    std::string tail(static_cast<std::size_t>(std::max<std::streamoff>(0, end - from)), '\0');
    in.read(tail.data(), static_cast<std::streamsize>(tail.size()));
    return "; the end of its log, " + log_file_.string() + (from > static_cast<std::streamoff>(log_start_) ? " (cut)" : "") +
           ":\n" + tail;
  }

  std::filesystem::path data_dir_;
  std::vector<std::string> extra_args_;
  std::filesystem::path log_file_;
  std::uint64_t file_size_limit_ = 0;
  std::uintmax_t log_start_ = 0;  // the log file's size at the last start(): this run's log follows
  pid_t pid_ = -1;
  pid_t last_pid_ = -1;
  std::string last_exit_;
  int port_ = 0;
  std::shared_ptr<grpc::Channel> channel_;
};

// The first message of an upload: the file's name and its column mapping.
inline v1::UploadDatasetRequest upload_header(const std::string& name, const std::vector<std::string>& inputs,
                                              const std::vector<std::string>& outputs) {
  v1::UploadDatasetRequest header;
  header.mutable_header()->set_name(name);
  for (const auto& i : inputs) header.mutable_header()->add_input_columns(i);
  for (const auto& o : outputs) header.mutable_header()->add_output_columns(o);
  return header;
}

// Uploads `bytes` as the file `name` in chunks of `chunk_size`, on `ctx`
// (which may carry a tenant's token); the status of the upload. With
// `declare_size`, the header gives the size (as the CLI does).
inline grpc::Status upload_dataset(v1::DatasetService::Stub& datasets, grpc::ClientContext* ctx,
                                   const std::string& name, const std::string& bytes,
                                   const std::vector<std::string>& inputs, const std::vector<std::string>& outputs,
                                   v1::DatasetInfo* info, std::size_t chunk_size = 64 * 1024,
                                   bool declare_size = false) {
  auto writer = datasets.UploadDataset(ctx, info);
  v1::UploadDatasetRequest header = upload_header(name, inputs, outputs);
  if (declare_size) header.mutable_header()->set_size_bytes(bytes.size());
  if (writer->Write(header)) {
    for (std::size_t at = 0; at < bytes.size(); at += chunk_size) {
      v1::UploadDatasetRequest chunk;
      chunk.set_chunk(bytes.substr(at, chunk_size));
      if (!writer->Write(chunk)) break;  // refused: Finish() says why
    }
  }
  writer->WritesDone();
  return writer->Finish();
}

// The same without a token, in 64 KiB chunks, as the CLI does.
inline grpc::Status upload_dataset(v1::DatasetService::Stub& datasets, const std::string& name,
                                   const std::string& bytes, const std::vector<std::string>& inputs,
                                   const std::vector<std::string>& outputs, v1::DatasetInfo* info) {
  grpc::ClientContext ctx;
  return upload_dataset(datasets, &ctx, name, bytes, inputs, outputs, info);
}

// riccatid run to its end with `args` (for what it refuses at start): its
// exit code and everything it printed. One that starts instead is killed
// after a minute (exit code 124), so such a test fails rather than hangs.
struct Outcome {
  int exit_code;
  std::string output;
};

// A gRPC health check of the daemon as a whole ("" service: SERVING when
// it answers), and how long it took in `seconds` if given. The generic stub
// sends the empty request without a copy of grpc.health.v1 in proto/.
inline grpc::Status health_check(const std::shared_ptr<grpc::Channel>& channel, double* seconds = nullptr,
                                 std::chrono::seconds deadline = std::chrono::seconds(30)) {
  grpc::GenericStub stub(channel);
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + deadline);
  grpc::Slice empty("");
  const grpc::ByteBuffer request(&empty, 1);
  grpc::ByteBuffer response;
  std::promise<grpc::Status> done;
  const auto began = std::chrono::steady_clock::now();
  stub.UnaryCall(&ctx, "/grpc.health.v1.Health/Check", grpc::StubOptions(), &request, &response,
                 [&](grpc::Status st) { done.set_value(st); });
  const grpc::Status status = done.get_future().get();
  if (seconds != nullptr) *seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - began).count();
  return status;
}

inline Outcome riccatid(const std::string& args) {
  const std::string command = "timeout 60 " + std::string(RICCATI_DAEMON_BIN) + " " + args + " 2>&1";
  std::FILE* pipe = ::popen(command.c_str(), "r");
  std::string output;
  std::array<char, 4096> buffer;
  while (std::fgets(buffer.data(), buffer.size(), pipe) != nullptr) output += buffer.data();
  const int status = ::pclose(pipe);
  return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, output};
}

// A fresh directory under the system's temp directory, removed at the end.
class TempDir {
 public:
  TempDir() {
    std::string tmpl = (std::filesystem::temp_directory_path() / "riccati-test-XXXXXX").string();
    if (mkdtemp(tmpl.data()) == nullptr) throw std::runtime_error("mkdtemp failed");
    path_ = tmpl;
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

// Streams samples [from, to) of `data` into session `id` in messages of
// `batch`, ends the stream and returns the estimates in order; every
// measurement is expected to get one.
inline std::vector<v1::Estimate> stream_samples(v1::SessionService::Stub& sessions, grpc::ClientContext* ctx,
                                                const std::string& id, const Dataset& data, Eigen::Index from,
                                                Eigen::Index to, Eigen::Index batch) {
  auto rw = sessions.Stream(ctx);
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(id);
  EXPECT_TRUE(rw->Write(open));
  std::vector<v1::Estimate> out;
  for (Eigen::Index first = from; first < to; first += batch) {
    v1::StreamRequest request;
    for (Eigen::Index k = first; k < std::min(first + batch, to); ++k) add_sample(request, data, k);
    v1::StreamResponse response;
    if (!rw->Write(request) || !rw->Read(&response)) break;
    for (const auto& r : response.results()) {
      EXPECT_TRUE(r.has_estimate()) << r.error().message();
      out.push_back(r.estimate());
    }
  }
  rw->WritesDone();
  const grpc::Status s = rw->Finish();
  EXPECT_TRUE(s.ok()) << s.error_message();
  return out;
}

// A file's bytes ("" when it cannot be read).
inline std::string read_file(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// How long a test waits for the daemon to reach a state it must reach
// (wait_until); far beyond what it takes, so that only a daemon that never
// gets there fails, however loaded the machine or slow the build.
inline constexpr std::chrono::milliseconds kWait = std::chrono::seconds(kSanitized ? 120 : 30);

// One daemon per test on its own data directory, with a stub per service.
class DaemonTest : public ::testing::Test {
 protected:
  void SetUp() override {
    daemon_ = std::make_unique<DaemonProcess>(dir_.path() / "data");
    daemon_->start();
    connect();
  }

  void connect() {
    models_ = v1::ModelService::NewStub(daemon_->channel());
    datasets_ = v1::DatasetService::NewStub(daemon_->channel());
    jobs_ = v1::JobService::NewStub(daemon_->channel());
    sessions_ = v1::SessionService::NewStub(daemon_->channel());
  }

  grpc::Status upload(const std::string& name, const std::string& bytes, std::vector<std::string> inputs,
                      std::vector<std::string> outputs, v1::DatasetInfo* info) {
    return upload_dataset(*datasets_, name, bytes, inputs, outputs, info);
  }

  std::string upload_two_tank() {
    v1::DatasetInfo info;
    const grpc::Status s = upload("two_tank.csv", read_file(std::string(RICCATI_TEST_DATA_DIR) + "/two_tank.csv"), {"F1", "F2"}, {"h1", "h2"}, &info);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return info.id();
  }

  static v1::IdentificationSpec hensen(const std::string& dataset_id, int passes = 10) {
    return hensen_spec(dataset_id, passes);
  }

  // Watches a job to its end and returns its last state.
  v1::Job wait_for(const std::string& id) {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
    v1::WatchJobRequest request;
    request.set_id(id);
    auto reader = jobs_->WatchJob(&ctx, request);
    v1::Job job;
    while (reader->Read(&job)) {
    }
    const grpc::Status s = reader->Finish();
    EXPECT_TRUE(s.ok()) << s.error_message();
    return job;
  }

  v1::JobResult result_of(const std::string& id) {
    grpc::ClientContext ctx;
    v1::GetResultRequest request;
    request.set_job_id(id);
    v1::JobResult result;
    const grpc::Status s = jobs_->GetResult(&ctx, request, &result);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return result;
  }

  v1::Job get_job(const std::string& id) {
    grpc::ClientContext ctx;
    v1::GetJobRequest get;
    get.set_id(id);
    v1::Job job;
    const grpc::Status s = jobs_->GetJob(&ctx, get, &job);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return job;
  }

  // Polls job `id` until it runs with at least `passes` passes completed,
  // or has ended; returns what it saw last (the caller checks the state:
  // a job that ended is not running).
  v1::Job wait_running(const std::string& id, std::uint32_t passes = 0) {
    v1::Job job;
    const auto seen = [&] {
      job = get_job(id);
      return (job.state() == v1::JOB_STATE_RUNNING && job.progress().pass_number() >= passes) ||
             job.state() >= v1::JOB_STATE_SUCCEEDED;
    };
    EXPECT_TRUE(wait_until(seen, kWait,
                                    "job " + id + " runs with " + std::to_string(passes) + " passes completed"))
        << job.ShortDebugString();
    return job;
  }

  v1::Job submit(const v1::IdentificationSpec& spec) {
    grpc::ClientContext ctx;
    v1::Job job;
    const grpc::Status s = jobs_->SubmitIdentification(&ctx, spec, &job);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return job;
  }

  void expect_serving() {
    grpc::ClientContext ctx;
    v1::ListModelsResponse list;
    ASSERT_TRUE(models_->ListModels(&ctx, {}, &list).ok());
    EXPECT_EQ(list.models_size(), 4);
  }

  TempDir dir_;
  std::unique_ptr<DaemonProcess> daemon_;
  std::unique_ptr<v1::ModelService::Stub> models_;
  std::unique_ptr<v1::DatasetService::Stub> datasets_;
  std::unique_ptr<v1::JobService::Stub> jobs_;
  std::unique_ptr<v1::SessionService::Stub> sessions_;
};

}  // namespace riccati::testing
