// A dataset bound to a model: its inputs and outputs in the model's order.
#pragma once

#include "engine/data/dataset.hpp"
#include "engine/models/model.hpp"
#include "engine/status.hpp"

namespace riccati {

// Orders a dataset's inputs and outputs as the model's (by name when the
// names match, else by position when the counts match) and checks the sizes.
Result<Dataset> bind_dataset(const Model& model, const Dataset& data);

// Whether a dataset with these input and output columns binds to `model`
// (what bind_dataset checks of the names, without the samples): submits
// refuse a mismatch with this message before a job is queued.
Status check_columns(const Model& model, const std::vector<std::string>& inputs,
                     const std::vector<std::string>& outputs);

}  // namespace riccati
