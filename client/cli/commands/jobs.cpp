#include <semaphore.h>
#include <signal.h>
#include <unistd.h>

#include <atomic>
#include <optional>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <thread>

#include "commands/commands.hpp"
#include "mat_export.hpp"
#include "output.hpp"
#include "riccati/enum_names.hpp"

namespace riccati::cli {

int jobs_list(Client& c, const JobsOptions& o) {
  v1::ListJobsRequest request;
  for (const std::string& state : o.states) {
    const auto* value = api::find_enum_value(*v1::JobState_descriptor(), state);
    if (value == nullptr || value->number() == 0) {
      std::fprintf(stderr, "riccati: --state: \"%s\" is not a job state (%s)\n", state.c_str(),
                   api::enum_choice_list(*v1::JobState_descriptor()).c_str());
      return kExitUsage;
    }
    request.add_states(static_cast<v1::JobState>(value->number()));
  }
  request.set_model(o.model);
  request.set_page_size(o.limit);
  request.set_page_token(o.page_token);
  auto ctx = c.context();
  v1::ListJobsResponse list;
  const grpc::Status s = c.jobs->ListJobs(ctx.get(), request, &list);
  if (!s.ok()) return c.fail("listing jobs", s);
  if (c.json) {
    std::printf("%s\n", to_json(list).c_str());
    return kExitOk;
  }
  std::printf("%s\n", job_header().c_str());
  for (const auto& j : list.jobs()) std::printf("%s\n", job_line(j).c_str());
  if (!list.next_page_token().empty()) {
    std::fprintf(stderr, "more: riccati jobs --page-token %s (with the same filters)\n", list.next_page_token().c_str());
  }
  return kExitOk;
}

int job_show(Client& c, const std::string& id) {
  auto ctx = c.context();
  v1::GetJobRequest request;
  request.set_id(id);
  v1::Job job;
  const grpc::Status s = c.jobs->GetJob(ctx.get(), request, &job);
  if (!s.ok()) return c.fail("job " + id, s);
  if (c.json) {
    std::printf("%s\n", to_json(job).c_str());
  } else {
    std::printf("%s\n", job_line(job).c_str());
    // Claimed more than once: an instance died with it, or could not store its end.
    if (job.attempts() > 1) std::printf("  attempts: %u\n", job.attempts());
    if (job.has_error()) std::printf("  error: %s\n", job.error().message().c_str());
  }
  return kExitOk;
}

int job_watch(Client& c, const std::string& id) {
  v1::Job last;
  const int rc = watch_until_done(c, id, &last);
  if (c.json) {
    std::printf("%s\n", to_json(last).c_str());
  } else if (last.state() == v1::JOB_STATE_SUCCEEDED) {
    // Its end, and where the answer is (a job watched after it ended shows
    // only its last progress, which says neither).
    std::printf("job %s succeeded; its result: riccati result %s\n", id.c_str(), id.c_str());
  }
  return rc;
}

int job_cancel(Client& c, const std::string& id) {
  auto ctx = c.context();
  v1::CancelJobRequest request;
  request.set_id(id);
  v1::Job job;
  const grpc::Status s = c.jobs->CancelJob(ctx.get(), request, &job);
  if (!s.ok()) return c.fail("cancelling job " + id, s);
  std::printf("%s\n", c.json ? to_json(job).c_str() : job_line(job).c_str());
  return kExitOk;
}

int job_delete(Client& c, const std::string& id) {
  auto ctx = c.context();
  v1::DeleteJobRequest request;
  request.set_id(id);
  v1::DeleteJobResponse response;
  const grpc::Status s = c.jobs->DeleteJob(ctx.get(), request, &response);
  if (!s.ok()) return c.fail("deleting job " + id, s);
  if (c.json) std::printf("%s\n", to_json(nlohmann::json{{"id", id}, {"deleted", true}}).c_str());
  return kExitOk;
}

namespace {

// SIGINT while a watch runs: the handler only posts a semaphore (all a
// signal handler may safely do); a thread waiting on it cancels the watch's
// call, which ends the watch. The default action is back after the first
// SIGINT (SA_RESETHAND), so a second Ctrl-C ends the command at once.
sem_t interrupt_semaphore;
std::atomic<bool> interrupt_signalled{false};

extern "C" void on_sigint(int) {
  interrupt_signalled.store(true);
  sem_post(&interrupt_semaphore);
}

class CancelWatchOnInterrupt {
 public:
  explicit CancelWatchOnInterrupt(grpc::ClientContext* watch) {
    interrupt_signalled.store(false);
    sem_init(&interrupt_semaphore, 0, 0);
    struct sigaction action {};
    action.sa_handler = on_sigint;
    sigemptyset(&action.sa_mask);
    action.sa_flags = SA_RESETHAND;
    sigaction(SIGINT, &action, &previous_);
    waiter_ = std::thread([watch] {
      while (sem_wait(&interrupt_semaphore) != 0) {
      }  // (EINTR: again)
      if (interrupt_signalled.load()) watch->TryCancel();
    });
  }
  ~CancelWatchOnInterrupt() {
    sigaction(SIGINT, &previous_, nullptr);
    sem_post(&interrupt_semaphore);  // ends the waiter if no SIGINT came
    waiter_.join();
    sem_destroy(&interrupt_semaphore);
  }
  CancelWatchOnInterrupt(const CancelWatchOnInterrupt&) = delete;
  CancelWatchOnInterrupt& operator=(const CancelWatchOnInterrupt&) = delete;

  bool interrupted() const { return interrupt_signalled.load(); }

 private:
  struct sigaction previous_ {};
  std::thread waiter_;
};

// After Ctrl-C: cancels job `id`, saying so on stderr ("cancelling job-...;
// cancelled"), and waits (one --timeout at most) for a running job to stop.
int cancel_interrupted(Client& c, const std::string& id) {
  std::fprintf(stderr, "\ncancelling %s; ", id.c_str());
  std::fflush(stderr);
  v1::Job job;
  {
    auto ctx = c.context();
    v1::CancelJobRequest request;
    request.set_id(id);
    if (const grpc::Status s = c.jobs->CancelJob(ctx.get(), request, &job); !s.ok()) {
      std::fprintf(stderr, "failed\n");
      c.fail("cancelling job " + id, s);
      return kExitInterrupted;
    }
  }
  if (job.state() == v1::JOB_STATE_CANCELLING) {
    auto ctx = c.context();
    v1::WatchJobRequest request;
    request.set_id(id);
    auto reader = c.jobs->WatchJob(ctx.get(), request);
    for (v1::Job update; reader->Read(&update);) job = update;
    (void)reader->Finish();
  }
  std::fprintf(stderr, "%s\n", state_name(job.state()).c_str());
  return kExitInterrupted;
}

}  // namespace

int watch_until_done(Client& c, const std::string& id, v1::Job* last, OnInterrupt on_interrupt) {
  auto ctx = c.stream_context();
  std::optional<CancelWatchOnInterrupt> interrupt;
  if (on_interrupt == OnInterrupt::kCancelJob) {
    interrupt.emplace(ctx.get());
    std::fprintf(stderr, "job %s (Ctrl-C cancels it)\n", id.c_str());
  }
  v1::WatchJobRequest request;
  request.set_id(id);
  auto reader = c.jobs->WatchJob(ctx.get(), request);
  const bool tty = isatty(STDERR_FILENO) != 0 && !c.json;
  uint32_t last_pass_printed = 0, last_iteration_printed = 0;
  while (reader->Read(last)) {
    const auto& p = last->progress();
    if (tty && p.iteration() > 0) {
      // OE and ML: the optimiser's iterations, whose number is not known ahead.
      std::fprintf(stderr, "\r%s   ", progress_text(p).c_str());
    } else if (tty && p.samples() > 0 && p.passes() > 0) {
      const double done = ((p.pass_number() > 0 ? p.pass_number() - 1 : 0) + double(p.sample()) / double(p.samples())) / p.passes();
      const int width = 30;
      const int filled = static_cast<int>(done * width);
      std::string theta;
      for (double v : p.theta()) theta += format(" %.5g", v);
      std::fprintf(stderr, "\r[%-*s] pass %u/%u sample %llu/%llu theta%s   ", width, std::string(filled, '#').c_str(),
                   p.pass_number(), p.passes(), static_cast<unsigned long long>(p.sample()),
                   static_cast<unsigned long long>(p.samples()), theta.c_str());
    } else if (!tty && !c.json && p.iteration() > last_iteration_printed) {
      std::fprintf(stderr, "%s\n", progress_text(p).c_str());
      last_iteration_printed = p.iteration();
    } else if (!tty && !c.json && p.iteration() == 0 && p.pass_number() != last_pass_printed && p.sample() == p.samples() &&
               p.pass_number() > 0) {
      std::fprintf(stderr, "pass %u/%u done\n", p.pass_number(), p.passes());
      last_pass_printed = p.pass_number();
    }
  }
  if (tty) std::fprintf(stderr, "\n");
  const grpc::Status s = reader->Finish();
  if (interrupt && interrupt->interrupted()) {
    interrupt.reset();  // a second Ctrl-C now ends the command
    return cancel_interrupted(c, id);
  }
  if (!s.ok()) return c.fail("watching job " + id, s);
  if (last->state() != v1::JOB_STATE_SUCCEEDED) {
    const std::string& why = last->error().message();
    std::fprintf(stderr, "riccati: job %s %s%s\n", id.c_str(), state_name(last->state()).c_str(),
                 why.empty() ? "" : (": " + why).c_str());
    return kExitFailed;
  }
  return kExitOk;
}

namespace {

// What a result's tables take from its job and model: the parameters it
// started from (theta0, else the model's defaults) and the names of the
// model's states, inputs and outputs. Without the model (no longer
// loaded), the names are numbered and the start is theta0 alone.
void job_context(Client& c, const v1::Job& job, std::vector<double>* initial, ModelNames* names) {
  const std::string& model = job.has_smoothing()    ? job.smoothing().model()
                             : job.has_validation() ? job.validation().model()
                                                    : job.identification().model();
  v1::ModelInfo info;
  const bool known = !model.empty() && c.get_model(model, &info).ok();
  if (known) *names = model_names(info);
  if (!job.has_identification()) return;
  const auto& theta0 = job.identification().theta0();
  if (!theta0.empty()) {
    initial->assign(theta0.begin(), theta0.end());
  } else if (known) {
    initial->assign(info.theta_default().begin(), info.theta_default().end());
  }
}

// The true parameters that the job's dataset declares (data upload
// --truth), in the result's order; empty unless it declares every one.
std::vector<double> declared_truth(Client& c, const v1::Job& job, const v1::JobResult& r) {
  const auto& names = r.has_estimation() ? r.estimation().param_names() : r.identification().param_names();
  if (!job.has_identification() || names.empty()) return {};
  auto ctx = c.context();
  v1::GetDatasetRequest request;
  request.set_id(job.identification().dataset_id());
  v1::DatasetInfo info;
  if (!c.datasets->GetDataset(ctx.get(), request, &info).ok()) return {};
  std::vector<double> truth;
  for (const std::string& name : names) {
    const auto it = info.true_parameters().find(name);
    if (it == info.true_parameters().end()) return {};
    truth.push_back(it->second);
  }
  return truth;
}

}  // namespace

int result(Client& c, const std::string& id, const std::string& format_name, const std::string& output,
           const std::vector<double>& truth) {
  v1::JobResult r;
  v1::Job job;
  {
    auto ctx = c.context();
    v1::GetResultRequest request;
    request.set_job_id(id);
    const grpc::Status s = c.jobs->GetResult(ctx.get(), request, &r);
    if (!s.ok()) return c.fail("result of job " + id, s);
  }
  {
    auto ctx = c.context();
    v1::GetJobRequest request;
    request.set_id(id);
    (void)c.jobs->GetJob(ctx.get(), request, &job);
  }
  std::vector<double> initial;
  ModelNames names;
  if (format_name != "json") job_context(c, job, &initial, &names);
  std::string text;
  if (format_name == "json") {
    text = to_json(r) + "\n";
  } else if (format_name == "csv") {
    text = result_csv(r, names);
  } else if (format_name == "table") {
    text = result_table(r, initial, truth.empty() ? declared_truth(c, job, r) : truth, names);
  } else {
    std::fprintf(stderr, "riccati: unknown format \"%s\" (table, json or csv)\n", format_name.c_str());
    return kExitUsage;
  }
  if (output.empty()) {
    std::fputs(text.c_str(), stdout);
  } else {
    std::ofstream out(output);
    out << text;
    if (!out) {
      std::fprintf(stderr, "riccati: cannot write %s\n", output.c_str());
      return kExitUsage;
    }
  }
  return kExitOk;
}

int result_export(Client& c, const std::string& id, const std::string& path) {
  const std::string extension = std::filesystem::path(path).extension().string();
  if (extension != ".csv" && extension != ".json" && extension != ".mat") {
    std::fprintf(stderr, "riccati: --export %s: the file's extension says the format: .csv, .json or .mat\n",
                 path.c_str());
    return kExitUsage;
  }
  if (extension != ".mat") {
    const int rc = result(c, id, extension.substr(1), path, {});
    if (rc == kExitOk) std::fprintf(stderr, "wrote %s\n", path.c_str());
    return rc;
  }
  v1::JobResult r;
  {
    auto ctx = c.context();
    v1::GetResultRequest request;
    request.set_job_id(id);
    if (const grpc::Status s = c.jobs->GetResult(ctx.get(), request, &r); !s.ok()) {
      return c.fail("result of job " + id, s);
    }
  }
  v1::Job job;
  {
    auto ctx = c.context();
    v1::GetJobRequest request;
    request.set_id(id);
    (void)c.jobs->GetJob(ctx.get(), request, &job);  // without it (deleted since), the names are numbered
  }
  std::vector<double> initial;
  ModelNames names;
  job_context(c, job, &initial, &names);
  if (const auto problem = write_result_mat(r, names, path)) {
    std::fprintf(stderr, "riccati: --export %s: %s\n", path.c_str(), problem->c_str());
    return kExitFailed;
  }
  std::fprintf(stderr, "wrote %s\n", path.c_str());
  return kExitOk;
}

}  // namespace riccati::cli
