#include "segment_solver.h"

#include <stdexcept>

#include "cvodes_solver.h"
#include "rk_solver.h"

namespace pk {
namespace internal {
namespace {

[[noreturn]] void NoAdjoint() {
  // The objective resolves the adjoint route to route (a) for such an integrator (ResolveRoute).
  throw std::logic_error("this ODE integrator has no adjoint route");
}

}  // namespace

void SegmentSolver::AdjointSegment(const SegmentInput&, const Eigen::VectorXd&, const AdjointScales&,
                                   const Eigen::VectorXd&, Eigen::VectorXd*, Eigen::RowVectorXd*) {
  NoAdjoint();
}
int SegmentSolver::StoreSegment(const SegmentInput&, Eigen::VectorXd*) { NoAdjoint(); }
void SegmentSolver::BackwardStored(int, const AdjointScales&, const Eigen::VectorXd&, Eigen::VectorXd*,
                                   Eigen::RowVectorXd*) {
  NoAdjoint();
}

std::unique_ptr<SegmentSolver> MakeSegmentSolver(const OdeSystem& system, const OdeOptions& options,
                                                 Propagator propagator) {
  if (propagator == Propagator::kRungeKutta) return std::unique_ptr<SegmentSolver>(new RkSolver(system, options));
  return std::unique_ptr<SegmentSolver>(new CvodesSolver(system, options));
}

}  // namespace internal
}  // namespace pk
