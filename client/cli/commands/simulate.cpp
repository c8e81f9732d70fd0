#include <algorithm>
#include <cstdio>
#include <string>
#include <vector>

#include "commands/commands.hpp"
#include "csv/csv.hpp"
#include "output.hpp"

namespace riccati::cli {

namespace {

// x0 when --x0 is not given, by the rule identify and validate follow
// (x0 `first`): a state named as an output starts at the first value of that
// output's column, when the file has one; every other state at 0.
std::vector<double> first_values(const std::string& file, const v1::ModelInfo& info) {
  std::vector<double> x0(static_cast<std::size_t>(info.state_names_size()), 0.0);
  for (int i = 0; i < info.state_names_size(); ++i) {
    const std::string& state = info.state_names(i);
    const auto& outputs = info.output_names();
    if (std::find(outputs.begin(), outputs.end(), state) == outputs.end()) continue;
    const std::string column[] = {state};
    csv::Table table;
    if (!csv::read_file(file, column, &table) && table.rows() > 0) x0[static_cast<std::size_t>(i)] = table.row(0)[0];
  }
  return x0;
}

}  // namespace

int simulate(Client& c, const SimulateOptions& o) {
  const RunSettings& s = o.settings;
  const std::string model = s.model.value_or("");
  v1::ModelInfo info;  // the default input columns, x0's size and the outputs' names
  if (const grpc::Status status = c.get_model(model, &info); !status.ok()) return c.fail("model " + model, status);
  const std::vector<std::string> inputs =
      o.input_columns.empty() ? std::vector<std::string>(info.input_names().begin(), info.input_names().end())
                              : o.input_columns;
  std::vector<std::string> columns{o.time};
  columns.insert(columns.end(), inputs.begin(), inputs.end());
  csv::Table table;  // each row: t, then the inputs
  if (auto problem = csv::read_file(o.inputs_file, columns, &table)) {
    std::fprintf(stderr, "riccati: %s\n", problem->c_str());
    return kExitUsage;
  }

  v1::SimulateRequest request = to_simulate_request(s);
  std::string error;
  std::vector<double> theta;
  if (!o.params.empty() && !resolve_parameters(c, o.params, estimate_choice(s), nullptr, &theta, &error)) {
    std::fprintf(stderr, "riccati: %s\n", error.c_str());
    return kExitUsage;
  }
  request.mutable_theta()->Add(theta.begin(), theta.end());
  std::vector<double> x0;
  if (!o.x0.empty() && !parse_list(o.x0, &x0, &error)) {
    std::fprintf(stderr, "riccati: --x0: %s\n", error.c_str());
    return kExitUsage;
  }
  if (x0.empty()) x0 = first_values(o.inputs_file, info);
  request.mutable_x0()->Add(x0.begin(), x0.end());
  request.mutable_u()->set_rows(static_cast<uint32_t>(inputs.size()));
  request.mutable_u()->set_cols(static_cast<uint32_t>(table.rows()));
  for (std::size_t k = 0; k < table.rows(); ++k) {
    request.add_t(table.row(k)[0]);
    request.mutable_u()->mutable_values()->Add(table.row(k).begin() + 1, table.row(k).end());  // column-major
  }

  v1::SimulateResponse response;
  {
    auto ctx = c.context();
    const grpc::Status status = c.models->Simulate(ctx.get(), request, &response);
    if (!status.ok()) return c.fail("simulation", status);
  }
  std::FILE* out = o.output.empty() ? stdout : std::fopen(o.output.c_str(), "w");
  if (out == nullptr) {
    std::fprintf(stderr, "riccati: cannot write %s\n", o.output.c_str());
    return kExitUsage;
  }
  if (c.json) {
    // {"model": ..., "t": [...], "inputs": {name: [...]}, "outputs": {name: [...]}}
    nlohmann::json j{{"model", model}, {"t", nlohmann::json::array()}};
    for (std::size_t k = 0; k < table.rows(); ++k) j["t"].push_back(table.row(k)[0]);
    for (std::size_t i = 0; i < inputs.size(); ++i) {
      auto& column = j["inputs"][inputs[i]] = nlohmann::json::array();
      for (std::size_t k = 0; k < table.rows(); ++k) column.push_back(table.row(k)[1 + i]);
    }
    for (uint32_t i = 0; i < response.y().rows(); ++i) {
      auto& column = j["outputs"][info.output_names(static_cast<int>(i))] = nlohmann::json::array();
      for (std::size_t k = 0; k < table.rows(); ++k) column.push_back(element(response.y(), i, static_cast<uint32_t>(k)));
    }
    std::fprintf(out, "%s\n", to_json(j).c_str());
  } else {
    std::fprintf(out, "t");
    for (const auto& n : inputs) std::fprintf(out, ",%s", n.c_str());
    for (const auto& n : info.output_names()) std::fprintf(out, ",%s", n.c_str());
    std::fprintf(out, "\n");
    for (std::size_t k = 0; k < table.rows(); ++k) {
      std::fprintf(out, "%.17g", table.row(k)[0]);
      for (double v : table.row(k).subspan(1)) std::fprintf(out, ",%.17g", v);
      for (uint32_t i = 0; i < response.y().rows(); ++i) {
        std::fprintf(out, ",%.17g", element(response.y(), i, static_cast<uint32_t>(k)));
      }
      std::fprintf(out, "\n");
    }
  }
  if (out != stdout) std::fclose(out);
  return kExitOk;
}

}  // namespace riccati::cli
