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

#include "ode_system.h"
#include "pk/ode_options.h"

namespace pk {
namespace internal {

/// Part of a continuous record of output `key` over one segment: the record
/// y_m(t) and its weight per unit time w(t) are linear in the absolute time t
/// (the seed's dF/dt), and the loss grows by ½ w (y − y_m)².
struct ContinuousTerm {
  int key = 1;
  double ym0 = 0, ym_slope = 0;  ///< y_m(t) = ym0 + ym_slope·(t − t0)
  double w0 = 0, w_slope = 0;    ///< w(t) = w0 + w_slope·(t − t0)
};

/// One integration interval.
struct SegmentInput {
  double h = 0;
  Eigen::VectorXd u;        ///< input rates
  Eigen::MatrixXd du;       ///< ∂u/∂p (n×k); may have zero columns
  Eigen::VectorXd theta;    ///< model parameters
  Eigen::MatrixXd dtheta;   ///< ∂θ/∂p (m×k)
  std::vector<ContinuousTerm> continuous;
  int auc_key = 0;          ///< output integrated by Advance(…, auc)
};

using OdeStatistics = pk::OdeStatistics;

/// The continuous loss integrand L = Σ ½ w (y − y_m)² of a segment at local time
/// t, with (optionally) ∂L/∂y per term, L_t = ∂L/∂t and ∂L_t/∂y per term.
double ContinuousLoss(const OdeSystem& sys, const SegmentInput& in, double t, const Eigen::VectorXd& x,
                      Eigen::VectorXd* dl_dy = nullptr, double* lt = nullptr, Eigen::VectorXd* dlt_dy = nullptr);

/// What the adjoint's backward solves need to know of the whole gradient (see
/// CvodesSolver::Impl::Backward): S = Σ_k |Δλ_k|ᵀ|x(t_k)| over all samples
/// (0: unknown), and the gradient accumulated so far (null: none).
struct AdjointScales {
  double state = 0;
  const Eigen::VectorXd* gradient = nullptr;
};

class CvodesSolver {
 public:
  CvodesSolver(const OdeSystem& system, const OdeOptions& options);
  ~CvodesSolver();
  CvodesSolver(const CvodesSolver&) = delete;
  CvodesSolver& operator=(const CvodesSolver&) = delete;

  /// x ← x(h). Adds the continuous records' loss over the segment to *loss,
  /// and ∫ y_auc_key dt to *auc (when given). Throws NumericalFailure when
  /// CVODES fails.
  /// With `loss_time`, also adds ∫ ∂L/∂t ds, the integrand's explicit time
  /// derivative (needed when the segment's start time moves with p).
  void Advance(const SegmentInput& in, Eigen::VectorXd* x, double* loss = nullptr, double* auc = nullptr,
               double* loss_time = nullptr);

  /// x ← x(h) and S ← S(h), dS/dt = f_x S + f_θ ∂θ/∂p + ∂u/∂p (the seed's
  /// forward sensitivity equations, k = S.cols()), with error control on S.
  /// With continuous records, also the loss and its gradient (1×k).
  void AdvanceSensitivity(const SegmentInput& in, Eigen::VectorXd* x, Eigen::MatrixXd* s, double* loss = nullptr,
                          Eigen::RowVectorXd* dloss = nullptr, double* loss_time = nullptr);

  /// The adjoint over one segment (the seed's §4): from x0, CVodeF stores the
  /// trajectory with checkpoints; then λ runs backward from λ(h) = lambda_end,
  ///   dλ/dt = −f_xᵀλ − Σ g_xᵀ w (y − y_m),
  /// to λ(0), and the quadrature
  ///   q = ∫₀ʰ λᵀ(f_θ ∂θ/∂p + ∂u/∂p) + Σ w (y − y_m) g_θ ∂θ/∂p ds   (1×k).
  /// `scales` set the error control of λ and of q (see AdjointScales).
  void AdjointSegment(const SegmentInput& in, const Eigen::VectorXd& x0, const AdjointScales& scales,
                      const Eigen::VectorXd& lambda_end, Eigen::VectorXd* lambda_start, Eigen::RowVectorXd* q);

  /// The same in two halves, keeping every segment's trajectory: the forward
  /// pass integrates x over the segment (x ← x(h)) into a CVODES adjoint
  /// memory, returning a handle (-1 for an empty segment); the sweep then runs
  /// backward on it. A segment that continues the previous one's initial value
  /// problem (a sample between them) extends the same memory. One forward pass
  /// instead of two, at the price of holding all segments at once.
  int StoreSegment(const SegmentInput& in, Eigen::VectorXd* x);
  void BackwardStored(int handle, const AdjointScales& scales, const Eigen::VectorXd& lambda_end,
                      Eigen::VectorXd* lambda_start, Eigen::RowVectorXd* q);

  const OdeStatistics& statistics() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_ODE_CVODES_SOLVER_H_
