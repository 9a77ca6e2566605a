// What the ODE propagator asks of an integrator (not installed): one integration between two events
// at a time (cvodes_solver.h documents each call). Two integrators serve it: CVODES's BDF with its
// continuous adjoint (CvodesSolver) and the one-step Dormand–Prince 5(4) (RkSolver).
#ifndef PK_SRC_ODE_SEGMENT_SOLVER_H_
#define PK_SRC_ODE_SEGMENT_SOLVER_H_

#include <memory>
#include <utility>

#include <Eigen/Core>

#include "ode_system.h"
#include "pk/ode_options.h"
#include "pk/propagator.h"

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

/// The same shape and values (Eigen's == takes the shape as given: different shapes are undefined
/// there, and ∂u/∂p has either k columns or none).
inline bool SameMatrix(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  return a.rows() == b.rows() && a.cols() == b.cols() && a == b;
}

/// A read-only matrix shared by the values that hold it: ∂θ/∂p is one m×P matrix per parameter set,
/// held by every segment of that set (and by the adjoint's tape entries and stored segments) instead
/// of copied into each, which cost O(m·P) a segment and sample: a tenth of a 64-parameter adjoint.
/// Reads as a const Eigen::MatrixXd; assign a matrix to give it another value.
class SharedMatrix {
 public:
  SharedMatrix() = default;
  SharedMatrix(Eigen::MatrixXd m)  // NOLINT: implicit, as a matrix is assigned to it
      : m_(std::make_shared<const Eigen::MatrixXd>(std::move(m))) {}
  template <typename Derived>
  SharedMatrix(const Eigen::MatrixBase<Derived>& m)  // NOLINT: an expression, evaluated once
      : m_(std::make_shared<const Eigen::MatrixXd>(m)) {}
  const Eigen::MatrixXd& operator*() const { return m_ ? *m_ : Empty(); }
  const Eigen::MatrixXd* operator->() const { return &**this; }
  operator const Eigen::MatrixXd&() const { return **this; }  // NOLINT: reads as the matrix
  /// The same matrix object (not merely equal values).
  bool SameAs(const SharedMatrix& other) const { return m_ == other.m_; }
  /// The same matrix, or one of the same shape and values.
  bool Equals(const SharedMatrix& other) const { return SameAs(other) || SameMatrix(**this, *other); }

 private:
  static const Eigen::MatrixXd& Empty() {
    static const Eigen::MatrixXd empty;
    return empty;
  }
  std::shared_ptr<const Eigen::MatrixXd> m_;
};

/// One integration interval.
struct SegmentInput {
  double h = 0;
  Eigen::VectorXd u;        ///< input rates
  Eigen::MatrixXd du;       ///< ∂u/∂p (n×k); zero columns when no rate depends on p
  Eigen::VectorXd theta;    ///< model parameters
  SharedMatrix dtheta;      ///< ∂θ/∂p (m×k), shared by the segments of one parameter set
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

class SegmentSolver {
 public:
  virtual ~SegmentSolver() = default;
  virtual void Advance(const SegmentInput& in, Eigen::VectorXd* x, double* loss = nullptr, double* auc = nullptr,
                       double* loss_time = nullptr) = 0;
  virtual void AdvanceSensitivity(const SegmentInput& in, Eigen::VectorXd* x, Eigen::MatrixXd* s,
                                  double* loss = nullptr, Eigen::RowVectorXd* dloss = nullptr,
                                  double* loss_time = nullptr) = 0;
  /// The adjoint route's calls (see CvodesSolver and RkSolver for what each integrator does).
  virtual void AdjointSegment(const SegmentInput& in, const Eigen::VectorXd& x0, const AdjointScales& scales,
                              const Eigen::VectorXd& lambda_end, Eigen::VectorXd* lambda_start,
                              Eigen::RowVectorXd* q) = 0;
  virtual int StoreSegment(const SegmentInput& in, Eigen::VectorXd* x) = 0;
  virtual void BackwardStored(int handle, const AdjointScales& scales, const Eigen::VectorXd& lambda_end,
                              Eigen::VectorXd* lambda_start, Eigen::RowVectorXd* q) = 0;
  /// Whether a tape's forward pass stores every segment (StoreSegment) whatever
  /// OdeOptions::adjoint_store_all_segments says.
  virtual bool stores_every_segment() const { return false; }
  virtual const OdeStatistics& statistics() const = 0;
};

/// The integrator of `propagator` (kOde: CVODES; kRungeKutta: Dormand–Prince, RODAS4 where stiff).
/// `tape`: for the forward pass of the adjoint route.
std::unique_ptr<SegmentSolver> MakeSegmentSolver(const OdeSystem& system, const OdeOptions& options,
                                                 Propagator propagator, bool tape);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_ODE_SEGMENT_SOLVER_H_
