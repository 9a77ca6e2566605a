#include "segment_solver.h"

#include "cvodes_solver.h"
#include "rk_solver.h"

namespace pk {
namespace internal {
std::unique_ptr<SegmentSolver> MakeSegmentSolver(const OdeSystem& system, const OdeOptions& options,
                                                 Propagator propagator, bool tape) {
  if (propagator == Propagator::kRungeKutta) return std::unique_ptr<SegmentSolver>(new RkSolver(system, options, tape));
  return std::unique_ptr<SegmentSolver>(new CvodesSolver(system, options));
}

}  // namespace internal
}  // namespace pk
