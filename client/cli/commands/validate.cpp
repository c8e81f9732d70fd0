#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cctype>
#include <cstdio>

#include "commands/commands.hpp"

namespace riccati::cli {

bool resolve_parameters(Client& c, const std::string& params, std::optional<int> estimate, v1::ValidationSpec* spec,
                        std::vector<double>* theta, std::string* error) {
  if (params.rfind("job-", 0) == 0) {
    if (spec != nullptr) {
      spec->set_identification_job_id(params);  // riccatid takes the estimate (spec.estimate) itself
      return true;
    }
    auto ctx = c.context();
    v1::GetResultRequest request;
    request.set_job_id(params);
    v1::JobResult r;
    const grpc::Status s = c.jobs->GetResult(ctx.get(), request, &r);
    if (!s.ok()) {
      *error = "job " + params + ": " + s.error_message();
      return false;
    }
    if (r.has_estimation()) {
      if (estimate) {  // as riccatid says of a validation asking the same
        *error = "--estimate: job " + params +
                 " is an output-error or likelihood identification, with one estimate; the choice is the iterated "
                 "filter's";
        return false;
      }
      theta->assign(r.estimation().theta().begin(), r.estimation().theta().end());
      return true;
    }
    if (!r.has_identification()) {
      *error = "--params: job " + params + " is not an identification";
      return false;
    }
    const auto& chosen = estimate == v1::ESTIMATE_CHOICE_FINAL ? r.identification().theta() : r.identification().theta_mean();
    theta->assign(chosen.begin(), chosen.end());
    return true;
  }
  if (estimate) {
    *error = "--estimate chooses among an identification job's estimates; --params " + params + " is not a job";
    return false;
  }
  if (is_local_file(params)) {
    try {
      const YAML::Node root = YAML::LoadFile(params);
      theta->clear();
      for (const auto& v : root["theta"]) theta->push_back(v.as<double>());
    } catch (const YAML::Exception& e) {
      *error = params + ": " + e.what() + " (expected a YAML file with theta: [...])";
      return false;
    }
  } else if (!parse_list(params, theta, error)) {
    *error = "--params: " + *error + " (give a job id, a YAML file or a list of numbers)";
    return false;
  }
  if (spec != nullptr) spec->mutable_theta()->mutable_values()->Add(theta->begin(), theta->end());
  return true;
}

int validate(Client& c, const ValidateOptions& o) {
  const RunSettings& s = o.settings;
  const v1::ValidationSpec asked = to_validation_spec(s, "");
  for (const std::string& name : asked.initial_state().estimate()) {
    // --estimate-x0 M was the sample count until the flag meant in validate what it means in identify.
    if (!name.empty() && std::all_of(name.begin(), name.end(), [](unsigned char ch) { return std::isdigit(ch); })) {
      std::fprintf(stderr,
                   "riccati: --estimate-x0 %s: the flag names the initial states to fit (or all), as in identify; "
                   "the samples they are fitted on are --x0-samples %s\n",
                   name.c_str(), name.c_str());
      return kExitUsage;
    }
  }
  std::string dataset;
  if (const int rc = dataset_for(c, s.data.value_or(""), s.inputs, s.outputs, &dataset, s.model.value_or(""));
      rc != kExitOk) {
    return rc;
  }
  v1::ValidationSpec spec = to_validation_spec(s, dataset);
  std::string error;
  std::vector<double> theta;
  if (!resolve_parameters(c, o.params, estimate_choice(s), &spec, &theta, &error)) {
    std::fprintf(stderr, "riccati: %s\n", error.c_str());
    return kExitUsage;
  }
  v1::Job job;
  {
    auto ctx = c.context();
    const grpc::Status status = c.jobs->SubmitValidation(ctx.get(), spec, &job);
    if (!status.ok()) return c.fail("submitting the validation", status);
  }
  v1::Job last;
  if (const int rc = watch_until_done(c, job.id(), &last, OnInterrupt::kCancelJob); rc != kExitOk) return rc;
  return result(c, job.id(), c.json ? "json" : "table", "", {});
}

}  // namespace riccati::cli
