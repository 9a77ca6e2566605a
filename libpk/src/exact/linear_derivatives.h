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
// and, for the discrete adjoint, accumulates W = Σ λ̃ x̃ᵀ over all steps with
// the same (set, h), so that one Fréchet derivative L(hMᵀ, W) per distinct
// interval gives the gradient with respect to every θ_j:
//   Σ λ̃ᵀ ∂exp(Mh)/∂θ_j x̃ = h ⟨L(hMᵀ, W), M_j⟩.
#ifndef PK_SRC_EXACT_LINEAR_DERIVATIVES_H_
#define PK_SRC_EXACT_LINEAR_DERIVATIVES_H_

#include <map>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "../autodiff.h"
#include "pk/linear_model.h"

namespace pk {
namespace internal {

class LinearDerivatives {
 public:
  struct Step {
    Eigen::MatrixXd phi;
    Eigen::MatrixXd gamma;
  };
  struct StepSensitivity {
    std::vector<Eigen::MatrixXd> dphi;    // one per active(set) entry
    std::vector<Eigen::MatrixXd> dgamma;
  };

  LinearDerivatives(const LinearModel& model, const std::vector<DualVector>& sets, int num_free);

  int n() const { return n_; }
  int num_free() const { return p_; }
  const Eigen::MatrixXd& A(int set) const { return sets_[set].a; }
  const Eigen::MatrixXd& dA(int set, int j) const { return sets_[set].da[j]; }
  /// m×P: derivatives of the set's model parameters with respect to the estimated ones.
  const Eigen::MatrixXd& dtheta(int set) const { return sets_[set].dtheta; }
  /// Model parameters j whose dθ_j/dp is not zero in this set.
  const std::vector<int>& active(int set) const { return sets_[set].active; }

  /// Output row c(θ) of compartment `cmt` (1-based), and dc/dp (n×P: column k is ∂c/∂p_k).
  const Eigen::RowVectorXd& C(int set, int cmt);
  const Eigen::MatrixXd& dCdp(int set, int cmt);

  const Step& Get(int set, double h);
  const StepSensitivity& GetSensitivity(int set, double h);

  /// Adds the outer product [λ; 0][x; u]ᵀ of one step to the (set, h) accumulator.
  void AccumulateFrechet(int set, double h, const Eigen::VectorXd& lambda_after, const Eigen::VectorXd& x_before,
                         const Eigen::VectorXd& u);
  /// Turns the accumulators into ∂/∂θ (per set), and adds Σ_set dθᵀ g_θ to `grad`.
  void FinishAdjoint(const std::vector<Eigen::VectorXd>& theta_grad, Eigen::VectorXd* grad);

  /// Number of matrix exponentials computed (for benchmarks).
  long exponentials() const { return exponentials_; }

 private:
  struct SetData {
    Eigen::MatrixXd a;
    std::vector<Eigen::MatrixXd> da;
    Eigen::MatrixXd dtheta;
    std::vector<int> active;
    Eigen::VectorXd theta;
    std::map<double, Step> steps;
    std::map<double, StepSensitivity> sens;
    std::map<double, Eigen::MatrixXd> frechet;  // W accumulators
    std::map<int, std::pair<Eigen::RowVectorXd, Eigen::MatrixXd>> outputs;
  };
  const LinearModel& model_;
  int n_;
  int m_;
  int p_;
  std::vector<SetData> sets_;
  long exponentials_ = 0;
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_EXACT_LINEAR_DERIVATIVES_H_
