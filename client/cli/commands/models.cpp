#include <cstdio>

#include "commands/commands.hpp"
#include "output.hpp"

namespace riccati::cli {

int models_list(Client& c) {
  auto ctx = c.context();
  v1::ListModelsResponse list;
  const grpc::Status s = c.models->ListModels(ctx.get(), {}, &list);
  if (!s.ok()) return c.fail("listing models", s);
  if (c.json) {
    std::printf("%s\n", to_json(list).c_str());
    return kExitOk;
  }
  std::printf("%-22s %4s %7s %4s %4s  %s\n", "model", "nx", "ntheta", "nu", "ny", "description");
  for (const auto& m : list.models()) {
    std::printf("%-22s %4d %7d %4d %4d  %s\n", m.name().c_str(), m.state_names_size(), m.param_names_size(),
                m.input_names_size(), m.output_names_size(), m.description().c_str());
  }
  return kExitOk;
}

int models_show(Client& c, const std::string& name) {
  v1::ModelInfo info;
  if (const grpc::Status s = c.get_model(name, &info); !s.ok()) return c.fail("model " + name, s);
  if (c.json) {
    std::printf("%s\n", to_json(info).c_str());
    return kExitOk;
  }
  std::printf("%s %s: %s\n", info.name().c_str(), info.version().c_str(), info.description().c_str());
  std::printf("  states:  %s\n  inputs:  %s\n  outputs: %s\n", join(info.state_names()).c_str(),
              join(info.input_names()).c_str(), join(info.output_names()).c_str());
  std::printf("  Jacobians: f %s, g %s\n", info.exact_f_jacobian() ? "exact" : "finite differences",
              info.exact_g_jacobian() ? "exact" : "finite differences");
  const v1::JacobianCheck& check = info.jacobian_check();
  if (!check.checked()) {
    std::printf("    not checked: %s\n", check.detail().c_str());
  } else if (check.agrees()) {
    std::printf("    agree with finite differences (%s)\n", check.detail().c_str());
  } else {
    // Loud: estimates made with a wrong Jacobian are wrong without any other sign.
    std::printf("    WRONG: they disagree with finite differences (%s):\n", check.detail().c_str());
    for (const std::string& d : check.disagreements()) std::printf("      %s\n", d.c_str());
  }
  std::printf("  %-10s %12s %12s %12s\n", "parameter", "default", "lower", "upper");
  for (int i = 0; i < info.param_names_size(); ++i) {
    std::printf("  %-10s %12.6g %12.6g %12.6g\n", info.param_names(i).c_str(), info.theta_default(i),
                info.theta_lower(i), info.theta_upper(i));
  }
  return kExitOk;
}

}  // namespace riccati::cli
