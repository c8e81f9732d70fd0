// A dataset bound to a model: its inputs and outputs in the model's order.
#pragma once

#include "engine/data/dataset.hpp"
#include "engine/models/model.hpp"
#include "engine/status.hpp"

namespace riccati {

// Orders a dataset's inputs and outputs as the model's (by name when the
// names match, else by position when the counts match) and checks the sizes.
Result<Dataset> bind_dataset(const Model& model, const Dataset& data);

}  // namespace riccati
