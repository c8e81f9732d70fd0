// The live view of `riccati stream`: a compact block redrawn in place on a
// terminal while a session streams (data time, throughput, round trips,
// every parameter with its standard deviation, the residual RMS), so the
// estimates can be watched converging.
#pragma once

#include <chrono>
#include <cstdio>
#include <string>
#include <vector>

#include "riccati/v1/models.pb.h"
#include "riccati/v1/sessions.pb.h"

namespace riccati::cli {

class LiveView {
 public:
  LiveView(const v1::ModelInfo& model, std::FILE* out);

  // Takes one estimate; redraws at most every `kRefresh`.
  void add(const v1::Estimate& e, double round_trip_us);
  // Draws the last state (at the end of the stream).
  void finish();

  // The block as text (no terminal codes), for tests and for finish().
  std::string render() const;

  static constexpr std::chrono::milliseconds kRefresh{200};

 private:
  void draw();

  const v1::ModelInfo& model_;
  std::FILE* out_;
  const std::chrono::steady_clock::time_point start_;
  std::chrono::steady_clock::time_point last_draw_{};
  int lines_drawn_ = 0;
  v1::Estimate last_;
  std::size_t estimates_ = 0;
  // Since the last redraw: residuals' sums of squares and round trips.
  std::vector<double> residual_sq_;
  std::size_t residual_count_ = 0;
  std::vector<double> residual_rms_;
  std::vector<double> trips_us_;
  double p50_us_ = 0.0, p99_us_ = 0.0;
};

}  // namespace riccati::cli
