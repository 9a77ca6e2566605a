// Parameter sets on pk::HyperDual3, seeded along two or three free parameters (not installed): the
// event engine runs on them when doses move with the parameters (exact/moving_events.h,
// ode/moving_events.h).
#ifndef PK_SRC_HYPER_DUAL_SETS_H_
#define PK_SRC_HYPER_DUAL_SETS_H_

#include <array>

#include "autodiff.h"
#include "events.h"
#include "pk/hyper_dual.h"
#include "pk/parameters.h"

namespace pk {
namespace internal {

using HyperDual3Vector = Vec<HyperDual3>;

/// One parameter set on HyperDual3 along `dir` (positions among the derivatives `set`
/// carries; −1 for none): part 1 << c of each entry is its derivative along dir[c] (the free
/// parameters enter the layout linearly, so there are no mixed parts), and the computed modifiers
/// get theirs, mixed parts included, from their own evaluation. Throws NumericalFailure when the
/// model's computed modifiers have no evaluation on HyperDual3.
HyperDual3Vector SeedAlong(const ParameterLayout& layout, const DualVector& set,
                           const std::array<int, 3>& dir);

/// How many of dir's entries are directions (2 or 3), and so the jet's parts: 1 << that.
inline int JetParts(const std::array<int, 3>& dir) { return dir[2] < 0 ? 4 : 8; }

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_HYPER_DUAL_SETS_H_
