// RICCATI_SCALAR_LOOPS compiles a function's loops without the vectoriser
// (GCC's optimize attribute): loops of 3 to 5 iterations run faster scalar
// than through the vectoriser's set-up and remainders (docs/benchmarks-log.md,
// the optimal filter's step). Clang has no such attribute, so its builds
// (the sanitizers') keep the vectoriser there.
#pragma once

#if defined(__clang__)
#define RICCATI_SCALAR_LOOPS
#else
#define RICCATI_SCALAR_LOOPS __attribute__((optimize("no-tree-vectorize")))
#endif
