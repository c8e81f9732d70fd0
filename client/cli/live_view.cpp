#include "live_view.hpp"

#include <algorithm>
#include <cmath>

#include "output.hpp"

namespace riccati::cli {

LiveView::LiveView(const v1::ModelInfo& model, std::FILE* out)
    : model_(model), out_(out), start_(std::chrono::steady_clock::now()) {}

void LiveView::add(const v1::Estimate& e, double round_trip_us) {
  last_ = e;
  ++estimates_;
  // The innovations of the outputs: what the filter could not explain.
  if (residual_sq_.size() != static_cast<std::size_t>(e.innovation_size())) {
    residual_sq_.assign(e.innovation_size(), 0.0);
  }
  for (int i = 0; i < e.innovation_size(); ++i) residual_sq_[i] += e.innovation(i) * e.innovation(i);
  ++residual_count_;
  if (round_trip_us >= 0) trips_us_.push_back(round_trip_us);
  if (std::chrono::steady_clock::now() - last_draw_ >= kRefresh) draw();
}

void LiveView::finish() { draw(); }

std::string LiveView::render() const {
  std::string text;
  char line[256];
  const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  std::snprintf(line, sizeof line, "t = %.3f s   %s   %.0f/s   round trip p50 %.0f us  p99 %.0f us\n",
                last_.t(), counted(estimates_, "estimate").c_str(), elapsed > 0 ? estimates_ / elapsed : 0.0, p50_us_, p99_us_);
  text += line;
  std::snprintf(line, sizeof line, "%-12s %14s %12s\n", "parameter", "estimate", "std");
  text += line;
  const int nx = model_.state_names_size();
  for (int j = 0; j < model_.param_names_size(); ++j) {
    const int i = nx + j;
    const double value = i < last_.state_size() ? last_.state(i) : std::nan("");
    const double sd = i < last_.std_size() ? last_.std(i) : std::nan("");
    std::snprintf(line, sizeof line, "%-12s %14.7g %12.3g\n", model_.param_names(j).c_str(), value, sd);
    text += line;
  }
  text += "residual RMS";
  for (int i = 0; i < model_.output_names_size(); ++i) {
    const double rms = static_cast<std::size_t>(i) < residual_rms_.size() ? residual_rms_[i] : std::nan("");
    std::snprintf(line, sizeof line, "  %s %.3g", model_.output_names(i).c_str(), rms);
    text += line;
  }
  text += "\n";
  return text;
}

void LiveView::draw() {
  last_draw_ = std::chrono::steady_clock::now();
  if (residual_count_ > 0) {
    residual_rms_.resize(residual_sq_.size());
    for (std::size_t i = 0; i < residual_sq_.size(); ++i) residual_rms_[i] = std::sqrt(residual_sq_[i] / residual_count_);
    std::fill(residual_sq_.begin(), residual_sq_.end(), 0.0);
    residual_count_ = 0;
  }
  if (!trips_us_.empty()) {
    std::sort(trips_us_.begin(), trips_us_.end());
    p50_us_ = trips_us_[trips_us_.size() / 2];
    p99_us_ = trips_us_[std::min(trips_us_.size() - 1, trips_us_.size() * 99 / 100)];
    trips_us_.clear();
  }
  // Back to the top of the previous block, then overwrite it line by line.
  if (lines_drawn_ > 0) std::fprintf(out_, "\x1b[%dA", lines_drawn_);
  const std::string text = render();
  int lines = 0;
  std::size_t begin = 0;
  for (std::size_t end = text.find('\n'); end != std::string::npos; end = text.find('\n', begin)) {
    std::fprintf(out_, "\x1b[2K%.*s\n", static_cast<int>(end - begin), text.data() + begin);
    begin = end + 1;
    ++lines;
  }
  lines_drawn_ = lines;
  std::fflush(out_);
}

}  // namespace riccati::cli
