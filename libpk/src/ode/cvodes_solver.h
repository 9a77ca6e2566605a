// CVODES behind a small interface (not installed): one integration between two
// events at a time, with constant input rates u and parameters θ. SUNDIALS
// handles are owned by the solver and released in its destructor.
//
// Between events the system is autonomous, so every segment runs on local time
// [0, h]; `t0` (the absolute start time) matters only to continuous records.
#ifndef PK_SRC_ODE_CVODES_SOLVER_H_
#define PK_SRC_ODE_CVODES_SOLVER_H_

#include <memory>
#include <vector>

#include <Eigen/Core>

#include "segment_solver.h"

namespace pk {
namespace internal {

class CvodesSolver final : public SegmentSolver {
 public:
  CvodesSolver(const OdeSystem& system, const OdeOptions& options);
  ~CvodesSolver() override;
  CvodesSolver(const CvodesSolver&) = delete;
  CvodesSolver& operator=(const CvodesSolver&) = delete;

  /// x ← x(h). Adds the continuous records' loss over the segment to *loss,
  /// and ∫ y_auc_key dt to *auc (when given). Throws NumericalFailure when
  /// CVODES fails.
  /// With `loss_time`, also adds ∫ ∂L/∂t ds, the integrand's explicit time
  /// derivative (needed when the segment's start time moves with p).
  void Advance(const SegmentInput& in, Eigen::VectorXd* x, double* loss = nullptr, double* auc = nullptr,
               double* loss_time = nullptr) override;

  /// x ← x(h) and S ← S(h), dS/dt = f_x S + f_θ ∂θ/∂p + ∂u/∂p (the seed's
  /// forward sensitivity equations, k = S.cols()), with error control on S.
  /// With continuous records, also the loss and its gradient (1×k).
  void AdvanceSensitivity(const SegmentInput& in, Eigen::VectorXd* x, Eigen::MatrixXd* s, double* loss = nullptr,
                          Eigen::RowVectorXd* dloss = nullptr, double* loss_time = nullptr) override;

  /// The adjoint over one segment (the seed's §4): from x0, CVodeF stores the
  /// trajectory with checkpoints; then λ runs backward from λ(h) = lambda_end,
  ///   dλ/dt = −f_xᵀλ − Σ g_xᵀ w (y − y_m),
  /// to λ(0), and the quadrature
  ///   q = ∫₀ʰ λᵀ(f_θ ∂θ/∂p + ∂u/∂p) + Σ w (y − y_m) g_θ ∂θ/∂p ds   (1×k).
  /// `scales` set the error control of λ and of q (see AdjointScales).
  void AdjointSegment(const SegmentInput& in, const Eigen::VectorXd& x0, const AdjointScales& scales,
                      const Eigen::VectorXd& lambda_end, Eigen::VectorXd* lambda_start, Eigen::RowVectorXd* q) override;

  /// The same in two halves, keeping every segment's trajectory: the forward
  /// pass integrates x over the segment (x ← x(h)) into a CVODES adjoint
  /// memory, returning a handle (-1 for an empty segment); the sweep then runs
  /// backward on it. A segment that continues the previous one's initial value
  /// problem (a sample between them) extends the same memory. One forward pass
  /// instead of two, at the price of holding all segments at once.
  int StoreSegment(const SegmentInput& in, Eigen::VectorXd* x) override;
  void BackwardStored(int handle, const AdjointScales& scales, const Eigen::VectorXd& lambda_end,
                      Eigen::VectorXd* lambda_start, Eigen::RowVectorXd* q) override;

  const OdeStatistics& statistics() const override;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_ODE_CVODES_SOLVER_H_
