// libFuzzer target: the text model compiler (YAML, expressions, graph,
// derivatives, tapes; server/engine/models/text). Any bytes either give a
// model or an INVALID_ARGUMENT; a model then evaluates f, g and both
// Jacobians at its defaults without a crash, whatever values come out (a
// NaN is the Model's error, not the fuzzer's).
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string_view>
#include <vector>

#include "engine/models/text/text_model.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  auto compiled = riccati::compile_text_model(text, "fuzz.yaml");
  if (!compiled.is_ok()) {
    if (compiled.status().code() != riccati::StatusCode::kInvalidArgument) std::abort();
    return 0;
  }
  const riccati::Model& m = *compiled.value().model;
  std::vector<double> x(static_cast<std::size_t>(m.nx()), 0.5), u(static_cast<std::size_t>(m.nu()), 0.25);
  std::vector<double> f(static_cast<std::size_t>(m.nx())), g(static_cast<std::size_t>(m.ny()));
  std::vector<double> jf(static_cast<std::size_t>(m.nx() * m.nz())), jg(static_cast<std::size_t>(m.ny() * m.nz()));
  const double* theta = m.theta_default().data();
  (void)m.f(1.0, u.data(), 1, 1, x.data(), theta, f.data());
  (void)m.g(1.0, u.data(), 1, 1, x.data(), theta, g.data());
  (void)m.f_jacobian(1.0, u.data(), x.data(), theta, f.data(), jf.data());
  (void)m.g_jacobian(1.0, u.data(), x.data(), theta, g.data(), jg.data());
  return 0;
}
