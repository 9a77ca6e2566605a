// The right-hand side seen by the ODE propagator (not installed): either a
// nonlinear OdeModel or a LinearModel run through CVODES (f = A(θ)x), so that
// every catalogue model can use the ODE routes.
//
// An observation is identified by an "output key": the DVID for a nonlinear
// model (output 1, 2, …), the 1-based compartment for a linear model (its
// concentration, as in the exact propagator), or n + DVID for a linear model's
// named output (PreparedSubject::cmt).
#ifndef PK_SRC_ODE_ODE_SYSTEM_H_
#define PK_SRC_ODE_ODE_SYSTEM_H_

#include <memory>
#include <vector>

#include <Eigen/Core>

#include "pk/dataset.h"
#include "pk/linear_model.h"
#include "pk/ode_model.h"
#include "ode/coloured_jacobian.h"

namespace pk {
namespace internal {

class OdeSystem {
 public:
  /// Throws pk::InputError for a model that is neither linear nor an OdeModel.
  explicit OdeSystem(const Model& model);

  int n() const { return n_; }
  int num_theta() const { return m_; }
  const Model& model() const { return model_; }
  bool is_linear() const { return linear_ != nullptr; }
  /// The nonlinear model (null for a linear one).
  const OdeModel* nonlinear() const { return ode_; }
  /// The linear model (null for a nonlinear one).
  const LinearModel* linear() const { return linear_; }

  void Rhs(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, Eigen::VectorXd* f) const;
  /// f and f_x dx + f_θ dtheta (n×k).
  void RhsDirectional(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, const Eigen::MatrixXd& dx,
                      const Eigen::MatrixXd& dtheta, Eigen::VectorXd* f, Eigen::MatrixXd* df) const;
  /// The same into raw storage, x (n) and dx (n×k, column-major) read in place, f (n) and df (n×k) written
  /// in place, when a nonlinear model evaluates k ≤ 8 directions on lanes; false otherwise (nothing written):
  /// a solver's right-hand side then need not copy its state out and back.
  bool RhsDirectionalInPlace(const double* x, const double* dx, int k, const Eigen::VectorXd& theta,
                             const Eigen::MatrixXd& dtheta, double* f, double* df) const {
    return ode_ != nullptr && ode_->DirectionalOnLanes(x, dx, k, theta, dtheta, f, df);
  }
  /// f, wᵀf_x and wᵀf_θ (reverse mode for nonlinear models).
  void RhsVectorJacobian(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, const Eigen::VectorXd& w,
                         Eigen::VectorXd* f, Eigen::VectorXd* wfx, Eigen::VectorXd* wftheta) const;
  /// f_x (n×n).
  Eigen::MatrixXd StateJacobian(const Eigen::VectorXd& x, const Eigen::VectorXd& theta) const;
  /// The same into *fx, whose storage is reused when it has the size.
  void StateJacobian(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, Eigen::MatrixXd* fx) const;
  /// B_a = ∂(f_x s_a + f_θ dtheta_a)/∂x (n×n) for each column a of s (n×k) and dtheta (m×k): the
  /// lower blocks of the Jacobian of the stacked sensitivity system (rosenbrock.h).
  void SensitivityJacobians(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, const Eigen::MatrixXd& s,
                            const Eigen::MatrixXd& dtheta, std::vector<Eigen::MatrixXd>* b) const;

  double Observe(int key, const Eigen::VectorXd& x, const Eigen::VectorXd& theta) const;
  /// y and g_x dx + g_θ dtheta (1×k).
  void ObserveDirectional(int key, const Eigen::VectorXd& x, const Eigen::VectorXd& theta,
                          const Eigen::MatrixXd& dx, const Eigen::MatrixXd& dtheta, double* y,
                          Eigen::RowVectorXd* dy) const;

  /// y and its gradients g_x (n) and g_θ (m): reverse mode for a nonlinear model.
  double ObserveGradient(int key, const Eigen::VectorXd& x, const Eigen::VectorXd& theta, Eigen::VectorXd* gx,
                         Eigen::VectorXd* gtheta) const;

  /// The key of the model's default output (central concentration).
  int central_key() const;

 private:
  const Model& model_;
  const LinearModel* linear_ = nullptr;
  const OdeModel* ode_ = nullptr;
  int n_ = 0;
  int m_ = 0;
};

/// Vector–Jacobian products at the stages of one step of a one-step method, for its discrete
/// adjoint (rk_solver.cc). The stages share θ: it is recorded once, as the first nodes of the
/// calling thread's tape, and wᵀf_θ accumulates there over every stage swept, so a step costs one
/// recording of f a stage (which also gives the stage's slope) and one sweep a stage, and no
/// evaluation twice. The stages also share the nodes of x, which hold no values: each sweep reads
/// its wᵀf_x there before the next. A linear system, f = A(θ)x, has no recording: A is formed once,
/// wᵀf_x = Aᵀw, and wᵀf_θ = ∂⟨Σ w Xᵀ, A(θ)⟩/∂θ is contracted once, in ThetaProduct.
/// The thread's tape is this object's until it is destroyed (which clears it); a recording made on
/// it meanwhile by anything else is detected at the next Sweep (std::logic_error).
/// With `compressed`, a nonlinear f whose Jacobian compresses into at most 8 lanes
/// (coloured_jacobian.h) is evaluated on them instead of recorded, and the tape is not used.
class StageTape {
 public:
  StageTape(const OdeSystem& system, const Eigen::VectorXd& theta, bool compressed = true);
  ~StageTape();
  StageTape(const StageTape&) = delete;
  StageTape& operator=(const StageTape&) = delete;

  /// Forgets the stages recorded so far (θ and its accumulated products stay).
  void NewStep();
  /// Records f at x as the next stage of this step, its value into *f.
  void Record(const Eigen::VectorXd& x, Eigen::VectorXd* f);
  /// The same into n numbers at f (a column of the caller's matrix).
  void Record(const Eigen::VectorXd& x, double* f);
  /// wᵀf_x at stage `stage` (in recording order) into *wfx, and wᵀf_θ added to ThetaProduct.
  /// Each stage is swept once.
  void Sweep(int stage, const Eigen::VectorXd& w, Eigen::VectorXd* wfx);
  /// The same into n numbers at wfx.
  void Sweep(int stage, const Eigen::VectorXd& w, double* wfx);
  /// Σ wᵀf_θ over every stage swept since construction.
  Eigen::VectorXd ThetaProduct() const;
  /// Whether the stages are evaluated on a compressed Jacobian's lanes rather than recorded.
  bool compressed() const { return coloured_ != nullptr; }

 private:
  std::unique_ptr<ColouredJacobian> coloured_;
  const OdeSystem& sys_;
  const Eigen::VectorXd& theta_;
  int n_, m_;
  std::vector<TapeScalar> theta_vars_;  // nodes 0…m−1 of the thread's tape, shared by every stage
  std::vector<int> start_;  // a stage's first node, and one past its last at the end
  std::vector<int> f_node_;  // n a stage: f_i's node, −1 for a constant
  std::vector<TapeScalar> xs_, fs_;  // Record's x and f, kept between stages
  std::vector<double> adj_;
  int zeroed_ = 0;  // adj_ is zero on [m + n, zeroed_) but for what sweeps put there
  // Linear systems: A(θ), the stages' points, and Σ w Xᵀ over the stages swept.
  Eigen::MatrixXd a_;
  std::vector<Eigen::VectorXd> points_;
  Eigen::MatrixXd contraction_;
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_ODE_ODE_SYSTEM_H_
