// Per-evaluation matrices of a linear model and their θ-derivatives (not installed).
//
// For each parameter set (the θ in force over an interval) this holds A(θ),
// ∂A/∂θ_j from automatic differentiation, and ∂θ_j/∂p, the derivative of the
// set's model parameters with respect to the P estimated parameters (zero where
// a data column supplies the value). Per distinct (set, h) it caches
//
//   Φ(h), Γ(h)      from exp([[A, I],[0, 0]] h)                          (Van Loan)
//   ∂Φ/∂θ_j, ∂Γ/∂θ_j  from the lower-left block of exp([[M, 0],[M_j, M]] h),
//                   M = [[A, I],[0, 0]], M_j = [[∂A/∂θ_j, 0],[0, 0]]   (seed 5.4/5.7)
//
// and, for the discrete adjoint, accumulates the steps so that the gradient
// with respect to every θ_j costs one pass per set (see discretization.h for
// the two exact paths: eigendecomposition, or block exponentials with one
// Fréchet derivative L(hMᵀ, Σλ̃x̃ᵀ) per distinct interval).
#ifndef PK_SRC_EXACT_LINEAR_DERIVATIVES_H_
#define PK_SRC_EXACT_LINEAR_DERIVATIVES_H_

#include <map>
#include <memory>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "../autodiff.h"
#include "discretization.h"
#include "pk/linear_model.h"

namespace pk {
namespace internal {

class LinearDerivatives {
 public:
  using Step = Discretization::Step;
  /// dphi/dgamma have one entry per active(set) parameter.
  using StepSensitivity = Discretization::Sensitivity;

  LinearDerivatives(const LinearModel& model, const std::vector<DualVector>& sets, int num_free);

  int n() const { return n_; }
  int num_free() const { return p_; }
  const Eigen::MatrixXd& A(int set) const { return sets_[set].a; }
  /// ∂A/∂θ_j (built on first use).
  const Eigen::MatrixXd& dA(int set, int j);
  /// m×P: derivatives of the set's model parameters with respect to the estimated ones.
  const Eigen::MatrixXd& dtheta(int set) const { return sets_[set].dtheta; }
  /// Model parameters j whose dθ_j/dp is not zero in this set.
  const std::vector<int>& active(int set) const { return sets_[set].active; }

  /// Output row c(θ) of compartment `cmt` (1-based), and dc/dp (n×P: column k is ∂c/∂p_k).
  const Eigen::RowVectorXd& C(int set, int cmt);
  const Eigen::MatrixXd& dCdp(int set, int cmt);

  /// Φ(h) and Γ(h); Γ is left empty when `with_gamma` is false.
  const Step& Get(int set, double h, bool with_gamma) { return sets_[set].disc->Get(h, with_gamma); }
  Discretization* discretization(int set) { return sets_[set].disc.get(); }
  /// ∂Φ/∂θ_j (and ∂Γ/∂θ_j when `with_gamma`) for the active j of the set.
  const StepSensitivity& GetSensitivity(int set, double h, bool with_gamma);

  /// Adds the outer product [λ; 0][x; u]ᵀ of one step to the (set, h) accumulator.
  void AccumulateFrechet(int set, double h, const Eigen::VectorXd& lambda_after, const Eigen::VectorXd& x_before,
                         const Eigen::VectorXd& u);
  /// Turns the accumulators into ∂/∂θ (per set), and adds Σ_set dθᵀ g_θ to `grad`.
  void FinishAdjoint(const std::vector<Eigen::VectorXd>& theta_grad, Eigen::VectorXd* grad);

  /// Number of matrix exponentials computed (for benchmarks).
  long exponentials() const;

 private:
  struct SetData {
    Eigen::MatrixXd a;
    std::vector<Eigen::MatrixXd> da;         // ∂A/∂θ_j, built on first use
    std::vector<Eigen::MatrixXd> active_da;  // the same for active(set), in order
    Eigen::MatrixXd dtheta;
    std::vector<int> active;
    Eigen::VectorXd theta;
    std::unique_ptr<Discretization> disc;
    std::map<int, std::pair<Eigen::RowVectorXd, Eigen::MatrixXd>> outputs;
  };
  const LinearModel& model_;
  int n_;
  int m_;
  int p_;
  std::vector<SetData> sets_;
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_EXACT_LINEAR_DERIVATIVES_H_
