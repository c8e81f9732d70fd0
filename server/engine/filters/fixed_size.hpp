// Kernels instantiated per size, chosen once per filter.
//
// The filters' innermost loops run over a few states (the two-tank model has
// 2 states and 4 parameters). With sizes known only at run time the
// compiler wraps every tiny loop in checks that cost more than the
// arithmetic; with the size a template argument the loops unroll. A filter
// therefore picks, when it is made, the instantiation for its model's sizes
// up to kMaxFixedSize (states + parameters <= 12 covers the models people
// identify; kDynamicSize, the general kernel, serves the rest).
#pragma once

#include <utility>

namespace riccati {

inline constexpr int kDynamicSize = -1;
inline constexpr int kMaxFixedSize = 12;

// make.template operator()<N>() for N = n when First <= n <= Last, else for
// N = kDynamicSize. `make` is a lambda templated on an int that returns a
// pointer to the instantiation for N.
template <int First, int Last, typename Make>
auto kernel_for(int n, Make make) {
  auto fn = make.template operator()<kDynamicSize>();
  if constexpr (Last >= First) {
    [&]<int... Is>(std::integer_sequence<int, Is...>) {
      ((n == First + Is ? (void)(fn = make.template operator()<First + Is>()) : void()), ...);
    }(std::make_integer_sequence<int, Last - First + 1>{});
  }
  return fn;
}

// The size a kernel uses: its template argument, or the run-time value.
template <int N>
constexpr int size_or(int runtime) {
  return N == kDynamicSize ? runtime : N;
}

}  // namespace riccati
