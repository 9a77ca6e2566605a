// SeedAlong (hyper_dual_sets.h).
#include "hyper_dual_sets.h"

#include "numerical_failure.h"

namespace pk {
namespace internal {

HyperDual3Vector SeedAlong(const ParameterLayout& layout, const DualVector& set,
                           const std::array<int, 3>& dir) {
  HyperDual3Vector v(set.size());
  for (Eigen::Index i = 0; i < set.size(); ++i) {
    v(i) = HyperDual3(set(i).value());
    const auto& d = set(i).derivatives();  // empty for a constant
    if (d.size() == 0) continue;
    for (int c = 0; c < 3; ++c) {
      if (dir[static_cast<size_t>(c)] >= 0) v(i).part(1 << c) = d(dir[static_cast<size_t>(c)]);
    }
  }
  if (!layout.ComputeModifiers(&v)) {
    throw NumericalFailure("the model's computed dose modifiers have no third-order evaluation");
  }
  return v;
}

}  // namespace internal
}  // namespace pk
