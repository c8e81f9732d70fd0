// `riccati stream`: replays a recorded CSV file into a filter session, as a
// rig would, and writes the estimates as they come back.
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <memory>
#include <mutex>
#include <thread>

#include "commands/commands.hpp"
#include "csv/csv.hpp"
#include "live_view.hpp"

namespace riccati::cli {

int stream(Client& c, const StreamOptions& o) {
  const RunSettings& s = o.settings;
  if (!s.model) {
    std::fprintf(stderr, "riccati: stream needs --model\n");
    return kExitUsage;
  }
  // Each row: t, then the inputs, then the outputs.
  std::vector<std::string> columns{o.time};
  columns.insert(columns.end(), s.inputs.begin(), s.inputs.end());
  columns.insert(columns.end(), s.outputs.begin(), s.outputs.end());
  csv::Table table;
  if (auto error = csv::read_file(o.file, columns, &table)) {
    std::fprintf(stderr, "riccati: %s (stream reads CSV files)\n", error->c_str());
    return kExitUsage;
  }
  v1::ModelInfo model;
  grpc::Status status = c.get_model(*s.model, &model);
  if (!status.ok()) return c.fail("model " + *s.model, status);
  const v1::ModelInfo* info = &model;
  const v1::CreateSessionRequest create = to_session_request(s);
  v1::SessionInfo session;
  {
    auto ctx = c.context();
    status = c.sessions->CreateSession(ctx.get(), create, &session);
    if (!status.ok()) return c.fail("creating the session", status);
  }
  std::fprintf(stderr, "session %s\n", session.id().c_str());

  std::FILE* out = stdout;
  if (!o.output.empty()) {
    out = std::fopen(o.output.c_str(), "w");
    if (out == nullptr) {
      std::fprintf(stderr, "riccati: cannot write %s\n", o.output.c_str());
      return kExitUsage;
    }
  }
  const int nz = info->state_names_size() + info->param_names_size();
  const bool optimal = create.filter().kind() == v1::FILTER_KIND_OPTIMAL;
  std::fprintf(out, "t");
  for (const auto& n : info->state_names()) std::fprintf(out, ",%s", n.c_str());
  for (const auto& n : info->param_names()) std::fprintf(out, ",%s", n.c_str());
  for (const auto& n : info->state_names()) std::fprintf(out, ",std_%s", n.c_str());
  for (const auto& n : info->param_names()) std::fprintf(out, ",std_%s", n.c_str());
  for (const auto& n : info->output_names()) std::fprintf(out, ",innovation_%s", n.c_str());
  std::fprintf(out, ",nis");
  if (optimal) {
    // The estimated inputs and accelerations (named after the positions),
    // then the residuals of the equations of motion, inputs and outputs.
    const int ndof = static_cast<int>(info->ndof());
    for (const auto& n : info->input_names()) std::fprintf(out, ",est_%s", n.c_str());
    for (int i = 0; i < ndof; ++i) std::fprintf(out, ",acc_%s", info->state_names(i).c_str());
    for (int i = 0; i < ndof; ++i) std::fprintf(out, ",res_motion%d", i + 1);
    for (const auto& n : info->input_names()) std::fprintf(out, ",res_%s", n.c_str());
    for (const auto& n : info->output_names()) std::fprintf(out, ",res_%s", n.c_str());
  }
  std::fprintf(out, "\n");
  const bool live = o.live == "always" ||
                    (o.live == "auto" && isatty(STDERR_FILENO) != 0 && (out != stdout || isatty(STDOUT_FILENO) == 0));
  std::unique_ptr<LiveView> view = live ? std::make_unique<LiveView>(*info, stderr) : nullptr;

  auto ctx = c.stream_context();
  auto rpc = c.sessions->Stream(ctx.get());
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(session.id());
  open.mutable_open()->set_full_covariance(o.full_covariance);
  rpc->Write(open);

  using Clock = std::chrono::steady_clock;
  std::mutex mu;
  std::vector<Clock::time_point> sent;  // per batch
  std::vector<double> trips_us;
  std::atomic<std::size_t> estimates{0}, refused{0};
  const auto start = Clock::now();
  // The reader: prints results as they arrive.
  std::thread reader([&] {
    v1::StreamResponse response;
    std::size_t batch = 0;
    while (rpc->Read(&response)) {
      const auto now = Clock::now();
      double trip_us = -1.0;
      {
        std::lock_guard lock(mu);
        if (batch < sent.size()) {
          trip_us = std::chrono::duration<double, std::micro>(now - sent[batch]).count();
          trips_us.push_back(trip_us);
        }
      }
      ++batch;
      for (const auto& r : response.results()) {
        if (r.has_error()) {
          ++refused;
          std::fprintf(stderr, "measurement %llu refused: %s\n", static_cast<unsigned long long>(r.sequence()),
                       r.error().message().c_str());
          continue;
        }
        ++estimates;
        const auto& e = r.estimate();
        std::fprintf(out, "%.17g", e.t());
        for (int i = 0; i < nz; ++i) std::fprintf(out, ",%.17g", e.state(i));
        for (int i = 0; i < nz; ++i) std::fprintf(out, ",%.17g", e.std(i));
        for (double v : e.innovation()) std::fprintf(out, ",%.17g", v);
        std::fprintf(out, ",%.17g", e.nis());
        for (double v : e.estimated_inputs()) std::fprintf(out, ",%.17g", v);
        for (double v : e.residuals()) std::fprintf(out, ",%.17g", v);
        std::fprintf(out, "\n");
        if (view) view->add(e, trip_us);
      }
    }
  });
  // The writer: paces batches at the rate (measurements per second).
  const int batch = std::max(1, o.batch);
  auto next = start;
  const auto period = o.rate > 0 ? std::chrono::duration<double>(batch / o.rate) : std::chrono::duration<double>(0);
  for (std::size_t k = 0; k < table.rows(); k += static_cast<std::size_t>(batch)) {
    if (o.rate > 0) {
      std::this_thread::sleep_until(next);
      next += std::chrono::duration_cast<Clock::duration>(period);
    }
    v1::StreamRequest request;
    for (std::size_t j = k; j < std::min(table.rows(), k + static_cast<std::size_t>(batch)); ++j) {
      const std::span<const double> row = table.row(j);
      const auto inputs_end = row.begin() + 1 + static_cast<std::ptrdiff_t>(s.inputs.size());
      auto* m = request.mutable_batch()->add_measurements();
      m->set_t(row[0]);
      m->mutable_u()->Add(row.begin() + 1, inputs_end);
      m->mutable_y()->Add(inputs_end, row.end());
    }
    {
      std::lock_guard lock(mu);
      sent.push_back(Clock::now());
    }
    if (!rpc->Write(request)) break;
  }
  rpc->WritesDone();
  reader.join();
  if (view) view->finish();
  const grpc::Status finished = rpc->Finish();
  const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
  if (out != stdout) std::fclose(out);
  std::sort(trips_us.begin(), trips_us.end());
  auto pct = [&](double p) {
    return trips_us.empty() ? 0.0 : trips_us[std::min(trips_us.size() - 1, static_cast<std::size_t>(p * trips_us.size()))];
  };
  std::fprintf(stderr, "%zu estimates, %zu refused, %.2f s (%.0f measurements/s), round trip p50 %.0f us, p99 %.0f us\n",
               estimates.load(), refused.load(), seconds, (estimates + refused) / seconds, pct(0.5), pct(0.99));
  if (!o.keep) {
    auto close_ctx = c.context();
    v1::CloseSessionRequest close;
    close.set_id(session.id());
    v1::CloseSessionResponse closed;
    (void)c.sessions->CloseSession(close_ctx.get(), close, &closed);
  }
  if (!finished.ok()) return c.fail("stream", finished);
  return refused > 0 ? kExitFailed : kExitOk;
}

}  // namespace riccati::cli
