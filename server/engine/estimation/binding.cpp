#include "engine/estimation/binding.hpp"

#include <string>
#include <vector>

namespace riccati {

namespace {

// Row order of `wanted` names inside `have`, or an empty vector if some are missing.
std::vector<Eigen::Index> order_by_name(const std::vector<std::string>& wanted, const std::vector<std::string>& have) {
  std::vector<Eigen::Index> order;
  for (const auto& w : wanted) {
    Eigen::Index found = -1;
    for (std::size_t i = 0; i < have.size(); ++i) {
      if (have[i] == w) found = static_cast<Eigen::Index>(i);
    }
    if (found < 0) return {};
    order.push_back(found);
  }
  return order;
}


Status check_counts(const char* what, const std::vector<std::string>& wanted, const std::vector<std::string>& have,
                    const std::string& model_name) {
  if (have.size() == wanted.size()) return Status::ok();
  return invalid_argument("model " + model_name + " has " + std::to_string(wanted.size()) + " " + what + " (" +
                          join_names(wanted) + "), the dataset has " + std::to_string(have.size()) + " (" +
                          (have.empty() ? std::string("none") : join_names(have)) + ")");
}

// Reorders the rows of m (one variable per row) as `wanted` says they are
// named in `have`; positional when the names do not all match.
Status bind_rows(const char* what, const std::vector<std::string>& wanted, const std::vector<std::string>& have,
                 const std::string& model_name, Eigen::MatrixXd* m, std::vector<std::string>* names) {
  RICCATI_RETURN_IF_ERROR(check_counts(what, wanted, have, model_name));
  const auto order = order_by_name(wanted, have);
  if (!order.empty()) {
    Eigen::MatrixXd reordered(m->rows(), m->cols());
    for (std::size_t i = 0; i < order.size(); ++i) reordered.row(i) = m->row(order[i]);
    *m = std::move(reordered);
  }
  *names = wanted;
  return Status::ok();
}

}  // namespace

Status check_columns(const Model& model, const std::vector<std::string>& inputs,
                     const std::vector<std::string>& outputs) {
  RICCATI_RETURN_IF_ERROR(check_counts("inputs", model.input_names(), inputs, model.name()));
  return check_counts("outputs", model.output_names(), outputs, model.name());
}

Result<Dataset> bind_dataset(const Model& model, const Dataset& data) {
  RICCATI_RETURN_IF_ERROR(validate_dataset(data));
  Dataset bound = data;
  RICCATI_RETURN_IF_ERROR(
      bind_rows("inputs", model.input_names(), data.input_names, model.name(), &bound.u, &bound.input_names));
  RICCATI_RETURN_IF_ERROR(
      bind_rows("outputs", model.output_names(), data.output_names, model.name(), &bound.y, &bound.output_names));
  return bound;
}

}  // namespace riccati
