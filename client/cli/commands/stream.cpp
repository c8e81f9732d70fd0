// `riccati stream`: replays a recorded CSV file into a filter session, as a
// rig would, and writes the estimates as they come back.
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <memory>
#include <mutex>
#include <span>
#include <thread>

#include "commands/commands.hpp"
#include "csv/csv.hpp"
#include "live_view.hpp"
#include "output.hpp"

namespace riccati::cli {

namespace {

using Clock = std::chrono::steady_clock;
using StreamRpc = grpc::ClientReaderWriter<v1::StreamRequest, v1::StreamResponse>;

// The recording: each row is t, then the inputs, then the outputs.
struct Recording {
  csv::Table table;
  std::size_t inputs = 0;
};

// The columns: --inputs and --outputs, or, when neither is given, the
// model's input and output names.
bool read_recording(const StreamOptions& o, const v1::ModelInfo& model, Recording* out, std::string* error) {
  const RunSettings& s = o.settings;
  const bool named = s.inputs.empty() && s.outputs.empty();
  const std::vector<std::string> inputs =
      named ? std::vector<std::string>(model.input_names().begin(), model.input_names().end()) : s.inputs;
  const std::vector<std::string> outputs =
      named ? std::vector<std::string>(model.output_names().begin(), model.output_names().end()) : s.outputs;
  std::vector<std::string> columns{o.time};
  columns.insert(columns.end(), inputs.begin(), inputs.end());
  columns.insert(columns.end(), outputs.begin(), outputs.end());
  if (auto problem = csv::read_file(o.file, columns, &out->table)) {
    *error = *problem + " (stream reads CSV files)";
    return false;
  }
  out->inputs = inputs.size();
  return true;
}

grpc::Status create_session(Client& c, const RunSettings& s, v1::SessionInfo* session) {
  auto ctx = c.context();
  return c.sessions->CreateSession(ctx.get(), to_session_request(s), session);
}

void close_session(Client& c, const std::string& id) {
  auto ctx = c.context();
  v1::CloseSessionRequest close;
  close.set_id(id);
  v1::CloseSessionResponse closed;
  (void)c.sessions->CloseSession(ctx.get(), close, &closed);
}

// The estimates as CSV: t, [x; theta], their std, the innovations and the
// NIS, then whatever else the estimates carry (the optimal filter's
// estimated inputs and accelerations, and the residuals of its equations).
// The header follows the first estimate, so its columns are the rows'.
class EstimateCsv {
 public:
  EstimateCsv(std::FILE* out, const v1::ModelInfo& model) : out_(out), model_(model) {}

  void write(const v1::Estimate& e) {
    if (!header_written_) write_header(&e);
    std::fprintf(out_, "%.17g", e.t());
    for (double v : e.state()) std::fprintf(out_, ",%.17g", v);
    for (double v : e.std()) std::fprintf(out_, ",%.17g", v);
    for (double v : e.innovation()) std::fprintf(out_, ",%.17g", v);
    std::fprintf(out_, ",%.17g", e.nis());
    for (double v : e.estimated_inputs()) std::fprintf(out_, ",%.17g", v);
    for (double v : e.residuals()) std::fprintf(out_, ",%.17g", v);
    std::fprintf(out_, "\n");
  }

  // The header alone, when no estimate came.
  void finish() {
    if (!header_written_) write_header(nullptr);
  }

 private:
  void write_header(const v1::Estimate* first) {
    std::fprintf(out_, "t");
    for (const auto& n : model_.state_names()) std::fprintf(out_, ",%s", n.c_str());
    for (const auto& n : model_.param_names()) std::fprintf(out_, ",%s", n.c_str());
    for (const auto& n : model_.state_names()) std::fprintf(out_, ",std_%s", n.c_str());
    for (const auto& n : model_.param_names()) std::fprintf(out_, ",std_%s", n.c_str());
    for (const auto& n : model_.output_names()) std::fprintf(out_, ",innovation_%s", n.c_str());
    std::fprintf(out_, ",nis");
    const int ndof = static_cast<int>(model_.ndof());
    if (first != nullptr && first->estimated_inputs_size() > 0) {
      // [u; a]: the inputs, then the accelerations (named after the positions).
      for (const auto& n : model_.input_names()) std::fprintf(out_, ",est_%s", n.c_str());
      for (int i = 0; i < ndof; ++i) std::fprintf(out_, ",acc_%s", model_.state_names(i).c_str());
    }
    if (first != nullptr && first->residuals_size() > 0) {
      // The equations of motion, then the measured inputs and outputs.
      for (int i = 0; i < ndof; ++i) std::fprintf(out_, ",res_motion%d", i + 1);
      for (const auto& n : model_.input_names()) std::fprintf(out_, ",res_%s", n.c_str());
      for (const auto& n : model_.output_names()) std::fprintf(out_, ",res_%s", n.c_str());
    }
    std::fprintf(out_, "\n");
    header_written_ = true;
  }

  std::FILE* out_;
  const v1::ModelInfo& model_;
  bool header_written_ = false;
};

// Round trips of the batches: the writer stamps each batch as it sends it,
// the reader as its answer arrives.
class RoundTrips {
 public:
  void sent() {
    std::lock_guard lock(mu_);
    sent_.push_back(Clock::now());
  }

  // The round trip of the next batch answered, in microseconds (-1: unknown).
  double answered() {
    const auto now = Clock::now();
    std::lock_guard lock(mu_);
    double trip_us = -1.0;
    if (answered_ < sent_.size()) {
      trip_us = std::chrono::duration<double, std::micro>(now - sent_[answered_]).count();
      trips_us_.push_back(trip_us);
    }
    ++answered_;
    return trip_us;
  }

  // The p quantile of the round trips so far, in microseconds.
  double quantile(double p) {
    std::lock_guard lock(mu_);
    if (trips_us_.empty()) return 0.0;
    std::sort(trips_us_.begin(), trips_us_.end());
    return trips_us_[std::min(trips_us_.size() - 1, static_cast<std::size_t>(p * trips_us_.size()))];
  }

 private:
  std::mutex mu_;
  std::vector<Clock::time_point> sent_;  // per batch
  std::vector<double> trips_us_;
  std::size_t answered_ = 0;
};

struct Tally {
  std::size_t estimates = 0, refused = 0;
};

// The reader: each result as it arrives, estimates to the CSV (or, with
// --json, every result as one line of JSON) and the live view, refusals to
// stderr.
Tally print_results(StreamRpc* rpc, EstimateCsv* csv, std::FILE* json_lines, LiveView* view, RoundTrips* trips) {
  Tally tally;
  v1::StreamResponse response;
  while (rpc->Read(&response)) {
    const double trip_us = trips->answered();
    for (const auto& r : response.results()) {
      if (json_lines != nullptr) std::fprintf(json_lines, "%s\n", json_of(r).dump().c_str());
      if (r.has_error()) {
        ++tally.refused;
        std::fprintf(stderr, "measurement %llu refused: %s\n", static_cast<unsigned long long>(r.sequence()),
                     r.error().message().c_str());
        continue;
      }
      ++tally.estimates;
      if (json_lines == nullptr) csv->write(r.estimate());
      if (view != nullptr) view->add(r.estimate(), trip_us);
    }
  }
  return tally;
}

// The writer: the rows in batches, paced at `rate` measurements per second
// (0: as fast as possible).
void send_rows(StreamRpc* rpc, const Recording& recording, double rate, int batch_size, RoundTrips* trips) {
  const std::size_t rows = recording.table.rows();
  const auto batch = static_cast<std::size_t>(std::max(1, batch_size));
  const auto period = std::chrono::duration<double>(rate > 0 ? static_cast<double>(batch) / rate : 0.0);
  auto next = Clock::now();
  for (std::size_t k = 0; k < rows; k += batch) {
    if (rate > 0) {
      std::this_thread::sleep_until(next);
      next += std::chrono::duration_cast<Clock::duration>(period);
    }
    v1::StreamRequest request;
    for (std::size_t j = k; j < std::min(rows, k + batch); ++j) {
      const std::span<const double> row = recording.table.row(j);
      auto* m = request.mutable_batch()->add_measurements();
      m->set_t(row[0]);
      m->mutable_u()->Add(row.begin() + 1, row.begin() + 1 + static_cast<std::ptrdiff_t>(recording.inputs));
      m->mutable_y()->Add(row.begin() + 1 + static_cast<std::ptrdiff_t>(recording.inputs), row.end());
    }
    trips->sent();
    if (!rpc->Write(request)) break;
  }
}

// "auto": when stderr is a terminal that the estimates do not go to.
bool wants_live_view(const std::string& live, std::FILE* out) {
  if (live != "auto") return live == "always";
  return isatty(STDERR_FILENO) != 0 && (out != stdout || isatty(STDOUT_FILENO) == 0);
}

void print_summary(const Tally& tally, double seconds, RoundTrips* trips) {
  const std::size_t answered = tally.estimates + tally.refused;
  if (answered == 0) {
    // No rate nor round trip to speak of.
    std::fprintf(stderr, "no estimates, %.2f s\n", seconds);
    return;
  }
  std::fprintf(stderr, "%s, %zu refused, %.2f s (%.0f measurements/s), round trip p50 %.0f us, p99 %.0f us\n",
               counted(tally.estimates, "estimate").c_str(), tally.refused, seconds,
               static_cast<double>(answered) / seconds, trips->quantile(0.5), trips->quantile(0.99));
}

}  // namespace

int stream(Client& c, const StreamOptions& o) {
  RunSettings s = o.settings;
  v1::SessionInfo resumed;  // --session: where it stands
  if (!o.session.empty()) {
    auto ctx = c.context();
    v1::GetSessionRequest request;
    request.set_id(o.session);
    if (const grpc::Status status = c.sessions->GetSession(ctx.get(), request, &resumed); !status.ok()) {
      return c.fail("session " + o.session, status);
    }
    if (s.model && *s.model != resumed.model()) {
      std::fprintf(stderr, "riccati: --model %s: session %s runs model %s\n", s.model->c_str(), o.session.c_str(),
                   resumed.model().c_str());
      return kExitUsage;
    }
    s.model = resumed.model();
  }
  if (!s.model) {
    std::fprintf(stderr, "riccati: stream needs --model (or --session to resume)\n");
    return kExitUsage;
  }
  v1::ModelInfo info;  // names the estimates' columns and the live view's rows
  if (const grpc::Status status = c.get_model(*s.model, &info); !status.ok()) {
    return c.fail("model " + *s.model, status);
  }
  Recording recording;
  std::string error;
  if (!read_recording(o, info, &recording, &error)) {
    std::fprintf(stderr, "riccati: %s\n", error.c_str());
    return kExitUsage;
  }
  if (!o.session.empty() && resumed.measurements() > 0) {
    // The rows the session has not seen: those after its time.
    std::size_t seen = 0;
    const double last_t = recording.table.rows() > 0 ? recording.table.row(recording.table.rows() - 1)[0] : 0.0;
    while (seen < recording.table.rows() && recording.table.row(seen)[0] <= resumed.t()) ++seen;
    recording.table.values.erase(recording.table.values.begin(),
                                 recording.table.values.begin() + static_cast<std::ptrdiff_t>(seen * recording.table.columns));
    if (recording.table.rows() == 0) {
      // Nothing to send: say so rather than open a stream for no rows. The
      // session is left as it was (open), with or without --keep.
      std::fprintf(stderr,
                   "session %s has seen every row of %s (%s, the last at t = %.17g s; the session is at t = %.17g "
                   "s after %s): nothing to send; the session stays open\n",
                   o.session.c_str(), o.file.c_str(), counted(seen, "row").c_str(), last_t, resumed.t(),
                   counted(resumed.measurements(), "measurement").c_str());
      return kExitOk;
    }
    std::fprintf(stderr, "resuming session %s after t = %.17g s (%s skipped)\n", o.session.c_str(), resumed.t(),
                 counted(seen, "row").c_str());
  }
  std::FILE* out = o.output.empty() ? stdout : std::fopen(o.output.c_str(), "w");
  if (out == nullptr) {
    std::fprintf(stderr, "riccati: cannot write %s\n", o.output.c_str());
    return kExitUsage;
  }
  const auto close_output = [&] {
    if (out != stdout) std::fclose(out);
  };
  v1::SessionInfo session = resumed;
  if (o.session.empty()) {
    if (const grpc::Status status = create_session(c, s, &session); !status.ok()) {
      close_output();
      return c.fail("creating the session", status);
    }
    std::fprintf(stderr, "session %s\n", session.id().c_str());
  }

  EstimateCsv csv(out, info);
  const std::unique_ptr<LiveView> view =
      wants_live_view(o.live, out) ? std::make_unique<LiveView>(info, stderr) : nullptr;
  auto ctx = c.stream_context();
  const auto rpc = c.sessions->Stream(ctx.get());
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(session.id());
  open.mutable_open()->set_full_covariance(o.full_covariance);
  rpc->Write(open);

  const auto start = Clock::now();
  RoundTrips trips;
  Tally tally;
  std::thread reader([&] { tally = print_results(rpc.get(), &csv, c.json ? out : nullptr, view.get(), &trips); });
  send_rows(rpc.get(), recording, o.rate, o.batch, &trips);
  rpc->WritesDone();
  reader.join();
  if (!c.json) csv.finish();
  if (view) view->finish();
  const grpc::Status finished = rpc->Finish();
  const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
  close_output();
  print_summary(tally, seconds, &trips);
  if (!o.keep) close_session(c, session.id());
  if (!finished.ok()) return c.fail("stream", finished);
  return tally.refused > 0 ? kExitFailed : kExitOk;
}

}  // namespace riccati::cli
