// The one-step integrator of the ODE propagator (not installed): Dormand–Prince 5(4) with error
// control and its dense output (Boost.Odeint's runge_kutta_dopri5, compiled with the model's types).
//
// PK systems are small (1–10 states), mostly non-stiff and restarted at every dose, infusion start and
// stop. A multistep method (CVODES's BDF) pays its start-up — order 1, tiny steps — at each restart; a
// one-step method restarts at the cost of one step. Samples do not end a step either: a segment that
// continues the previous one's initial value problem (same θ, inputs and state; a sample between
// them) carries on with the same stepper and reads its end from the dense output (the 4th-order
// interpolant of Dormand–Prince), so the step sequence does not depend on where the samples are.
//
// Values and quadratures (continuous-record loss, AUC) are integrated as one state. Route (a)'s
// forward sensitivities are the seed's dS/dt = f_x S + f_θ ∂θ/∂p + ∂u/∂p, integrated as part of the
// state [x; vec S], so S is under the same error control as x.
//
// Route (b) is the discrete adjoint of the method's own steps (Impl::Backward): the exact gradient of
// the computed loss for the accepted step sizes, with no backward integration and no error control of
// its own. With a tape, every segment is stepped to end exactly at its end (no continuation through
// samples: the backward pass takes one segment at a time), its accepted steps' starts and lengths are
// kept (n + 1 numbers a step), and the backward pass recomputes each step's stages from its start,
// recording f there once a stage (StageTape, ode_system.h). A stored segment that continues the last
// one (a sample between them) starts with the step the control proposed there, as stepping through
// would; a segment that is replayed instead of stored (a steady state's cycle) starts afresh, so its
// replay takes the same steps. Segments with continuous records take route (a).
//
// Stiff segments go to RODAS4 (rosenbrock.h). An explicit method's steps on a stiff system are bounded
// by its stability region, not by accuracy: each segment is tested first, h·‖f_x(x₀)‖∞ > 1000 (the
// row-sum norm bounds the spectral radius; Dormand–Prince is stable to about 3.3 on the negative
// axis), and every 25 steps, h·‖f_x(x)‖∞ > 2.5 (a step held by that boundary) at four checks in a
// row. Such a segment is done from its start by RODAS4 in every route; one that also integrates a
// quadrature (continuous loss, AUC) by a CvodesSolver kept for the purpose. The tests read only the
// segment and its steps, so a replay decides alike.
#ifndef PK_SRC_ODE_RK_SOLVER_H_
#define PK_SRC_ODE_RK_SOLVER_H_

#include <functional>
#include <memory>

#include "segment_solver.h"

namespace pk {
namespace internal {

/// z ← z(h) for the autonomous z' = rhs(z) by controlled Dormand–Prince 5(4) steps (Boost.Odeint,
/// sealed in rk_solver.cc), the last one ending at h, under one error control over every component.
/// *first_step: the first step to try when > 0 (else h), and on return the last proposal of a step
/// not cut short by h. Throws NumericalFailure past `max_steps` steps or on a non-finite z.
void DormandPrinceTo(const std::function<void(const Eigen::VectorXd&, Eigen::VectorXd*)>& rhs, double h, double atol,
                     double rtol, long max_steps, Eigen::VectorXd* z, double* first_step);

class RkSolver final : public SegmentSolver {
 public:
  /// `tape`: the forward pass of the adjoint route (see above).
  RkSolver(const OdeSystem& system, const OdeOptions& options, bool tape);
  ~RkSolver() override;
  RkSolver(const RkSolver&) = delete;
  RkSolver& operator=(const RkSolver&) = delete;

  void Advance(const SegmentInput& in, Eigen::VectorXd* x, double* loss = nullptr, double* auc = nullptr,
               double* loss_time = nullptr) override;
  void AdvanceSensitivity(const SegmentInput& in, Eigen::VectorXd* x, Eigen::MatrixXd* s, double* loss = nullptr,
                          Eigen::RowVectorXd* dloss = nullptr, double* loss_time = nullptr) override;
  void AdjointSegment(const SegmentInput& in, const Eigen::VectorXd& x0, const AdjointScales& scales,
                      const Eigen::VectorXd& lambda_end, Eigen::VectorXd* lambda_start, Eigen::RowVectorXd* q) override;
  int StoreSegment(const SegmentInput& in, Eigen::VectorXd* x) override;
  void BackwardStored(int handle, const AdjointScales& scales, const Eigen::VectorXd& lambda_end,
                      Eigen::VectorXd* lambda_start, Eigen::RowVectorXd* q) override;
  /// Every segment of a tape is stored: a replay must take the forward pass's steps.
  bool stores_every_segment() const override { return true; }
  const OdeStatistics& statistics() const override;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_ODE_RK_SOLVER_H_
