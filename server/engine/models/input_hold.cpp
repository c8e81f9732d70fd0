#include "engine/models/input_hold.hpp"

#include <string>

namespace riccati {

const char* hold_order_name(HoldOrder hold) { return hold == HoldOrder::kZero ? "zoh" : "foh"; }

Result<HoldOrder> parse_hold_order(std::string_view name) {
  if (name == "zoh" || name == "0") return HoldOrder::kZero;
  if (name == "foh" || name == "1") return HoldOrder::kFirst;
  return invalid_argument("unknown input hold \"" + std::string(name) + "\" (expected zoh or foh)");
}

}  // namespace riccati
