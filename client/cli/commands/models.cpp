#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

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

namespace {

// "h1 [m], h2 [m]": names with their units, where the model gives them.
std::string with_units(const google::protobuf::RepeatedPtrField<std::string>& names,
                       const google::protobuf::RepeatedPtrField<std::string>& units) {
  std::string out;
  for (int i = 0; i < names.size(); ++i) {
    out += (i > 0 ? ", " : "") + names.Get(i);
    if (i < units.size() && !units.Get(i).empty()) out += " [" + units.Get(i) + "]";
  }
  return out;
}

}  // namespace

int models_show(Client& c, const std::string& name) {
  v1::ModelInfo info;
  if (const grpc::Status s = c.get_model(name, &info); !s.ok()) return c.fail("model " + name, s);
  if (c.json) {
    std::printf("%s\n", to_json(info).c_str());
    return kExitOk;
  }
  std::printf("%s %s: %s\n", info.name().c_str(), info.version().c_str(), info.description().c_str());
  std::printf("  states:  %s\n  inputs:  %s\n  outputs: %s\n",
              with_units(info.state_names(), info.state_units()).c_str(),
              with_units(info.input_names(), info.input_units()).c_str(),
              with_units(info.output_names(), info.output_units()).c_str());
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
  std::printf("  %-10s %12s %12s %12s  %s\n", "parameter", "default", "lower", "upper", "unit");
  for (int i = 0; i < info.param_names_size(); ++i) {
    const std::string unit = i < info.param_units_size() ? info.param_units(i) : "";
    std::printf("  %-10s %12.6g %12.6g %12.6g  %s\n", info.param_names(i).c_str(), info.theta_default(i),
                info.theta_lower(i), info.theta_upper(i), unit.c_str());
  }
  if (info.has_text()) print_text_model(info);
  return kExitOk;
}

namespace {

// A column header of one character per z = [x; theta]: the names' first
// letters would collide, so the columns are numbered and the names listed.
void print_sparsity(const v1::ModelInfo& info, const char* what,
                    const google::protobuf::RepeatedPtrField<std::string>& rows,
                    const google::protobuf::RepeatedPtrField<std::string>& row_names, const char* prime) {
  std::printf("  d%s/d[x; theta] ('x' may be non-zero, '.' is zero everywhere):\n", what);
  for (int i = 0; i < rows.size(); ++i) {
    std::printf("    %-12s %s\n", (row_names.Get(i) + prime).c_str(), rows.Get(i).c_str());
  }
  (void)info;
}

}  // namespace

void print_text_model(const v1::ModelInfo& info) {
  const v1::TextModelInfo& text = info.text();
  if (text.revision() > 0) {
    std::printf("  text model, revision %llu (%s@%llu), sha256 %s\n", static_cast<unsigned long long>(text.revision()),
                info.name().c_str(), static_cast<unsigned long long>(text.revision()), text.sha256().c_str());
    std::string revisions;
    for (const auto r : text.revisions()) revisions += (revisions.empty() ? "" : ", ") + std::to_string(r);
    if (!revisions.empty()) std::printf("  stored revisions: %s\n", revisions.c_str());
  } else {
    std::printf("  text model from the models directory, sha256 %s\n", text.sha256().c_str());
  }
  std::printf("  equations:\n");
  for (const auto& e : text.equations()) std::printf("    %s\n", e.c_str());
  std::string columns;
  for (const auto& n : info.state_names()) columns += (columns.empty() ? "" : " ") + n;
  for (const auto& n : info.param_names()) columns += " " + n;
  std::printf("  Jacobian columns [x; theta]: %s\n", columns.c_str());
  print_sparsity(info, "f", text.f_sparsity(), info.state_names(), "'");
  print_sparsity(info, "g", text.g_sparsity(), info.output_names(), "");
  std::printf("  compiled: %llu instructions for f and its Jacobian\n",
              static_cast<unsigned long long>(text.tape_length()));
}

int models_add(Client& c, const std::string& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) {
    std::fprintf(stderr, "riccati: cannot open %s\n", file.c_str());
    return kExitUsage;
  }
  std::ostringstream source;
  source << in.rdbuf();
  v1::CreateModelRequest request;
  request.set_source(source.str());
  request.set_file_name(std::filesystem::path(file).filename().string());
  auto ctx = c.context();
  v1::ModelInfo info;
  if (const grpc::Status s = c.models->CreateModel(ctx.get(), request, &info); !s.ok()) {
    return c.fail("adding model " + file, s);
  }
  if (c.json) {
    std::printf("%s\n", to_json(info).c_str());
    return kExitOk;
  }
  std::printf("%s@%llu: %s, %s, %s, %s\n", info.name().c_str(),
              static_cast<unsigned long long>(info.text().revision()),
              counted(static_cast<unsigned>(info.state_names_size()), "state").c_str(),
              counted(static_cast<unsigned>(info.param_names_size()), "parameter").c_str(),
              counted(static_cast<unsigned>(info.input_names_size()), "input").c_str(),
              counted(static_cast<unsigned>(info.output_names_size()), "output").c_str());
  const v1::JacobianCheck& check = info.jacobian_check();
  if (check.checked() && !check.agrees()) {
    std::printf("  WRONG: its Jacobians disagree with finite differences (%s)\n", check.detail().c_str());
  }
  return kExitOk;
}

int models_remove(Client& c, const std::string& name) {
  v1::DeleteModelRequest request;
  request.set_name(name);
  auto ctx = c.context();
  v1::DeleteModelResponse response;
  if (const grpc::Status s = c.models->DeleteModel(ctx.get(), request, &response); !s.ok()) {
    return c.fail("removing model " + name, s);
  }
  if (c.json) {
    std::printf("%s\n", to_json(nlohmann::json{{"name", name}, {"removed", true}}).c_str());
  } else {
    std::printf("removed %s\n", name.c_str());
  }
  return kExitOk;
}

int models_reload(Client& c) {
  auto ctx = c.context();
  v1::ReloadModelsResponse report;
  if (const grpc::Status s = c.models->ReloadModels(ctx.get(), {}, &report); !s.ok()) {
    return c.fail("reloading the models directory", s);
  }
  if (c.json) {
    std::printf("%s\n", to_json(report).c_str());
    return kExitOk;
  }
  auto line = [](const char* what, const google::protobuf::RepeatedPtrField<std::string>& names) {
    if (!names.empty()) std::printf("%-10s %s\n", what, join(names).c_str());
  };
  line("added:", report.added());
  line("changed:", report.changed());
  line("removed:", report.removed());
  std::printf("%-10s %d\n", "unchanged:", report.unchanged_size());
  for (const auto& r : report.refused()) std::printf("refused:   %s\n", r.reason().c_str());
  return kExitOk;
}

}  // namespace riccati::cli
