// The stiff one-step method of the rk propagator (not installed): RODAS4, the L-stable, stiffly
// accurate Rosenbrock method of Hairer & Wanner (Solving ODEs II, 2nd ed., §IV.7, RODAS; the
// coefficients Boost.Odeint's rosenbrock4 steps with), for the segments Dormand–Prince finds stiff.
//
// A step of an autonomous system x' = F(x) with W = I/(γh) − J, J = F_x(x₀):
//
//   W g₁ = F(x₀)
//   W g_i = F(x₀ + Σ_{j<i} a_ij g_j) + Σ_{j<i} (c_ij/h) g_j,     i = 2 … 5
//   x̃ = x₀ + Σ_{j<5} a_5j g_j + g₅,   W e = F(x̃) + Σ_{j≤5} (c_6j/h) g_j,   x₁ = x̃ + e,
//
// e the embedded error estimate. One LU of W serves the six solves; a step restarts nothing, so a
// dose costs one step, as for Dormand–Prince.
//
// Forward sensitivities integrate [x; S] as one system under one error control, with the exact
// Jacobian of the stacked system, which is block lower-triangular:
//
//   J_aug = | f_x   0  |,    B_a = ∂(f_x s_a + f_θ θ_a)/∂x = f''[(·, 0), (s_a, θ_a)]
//           | B_a  f_x |
//
// so W_aug is solved by block substitution with W's one LU (g_x = W⁻¹r_x, g_a = W⁻¹(r_a + B_a g_x)):
// O(n³ + k n²) a step instead of a dense LU of order n(1 + k). Boost.Odeint's rosenbrock4 factors
// the whole matrix, which is why this stepper is libpk's own. B_a comes from the model's program on
// pk::HyperDual (ode_model.h), or for a linear system from ∂A/∂θ along θ_a.
//
// As for Runge–Kutta methods, the method applied to the stacked system with its exact Jacobian is
// the derivative of the method's own step: W's dependence on x₀ (through f_x) is what B_a carries.
// The adjoint of a stiff segment uses that: with S(0) = [I | 0] and ∂θ/∂p, ∂u/∂p seeded after the
// n identity columns, S(h) = [Φ_x | Φ_p], λ(start) = Φ_xᵀ λ(end) and q = λ(end)ᵀ Φ_p. It takes the
// values pass's accepted steps, stored with x₀, so this is the exact derivative of the computed
// segment: the discrete adjoint, formed by forward mode over n + k columns in the backward pass.
#ifndef PK_SRC_ODE_ROSENBROCK_H_
#define PK_SRC_ODE_ROSENBROCK_H_

#include <vector>

#include <Eigen/Core>

#include "segment_solver.h"

namespace pk {
namespace internal {

class Rosenbrock {
 public:
  Rosenbrock(const OdeSystem& system, const OdeOptions& options, OdeStatistics* stats)
      : sys_(system), opt_(options), stats_(stats) {}

  /// x ← x(h) over the segment (values only); the accepted steps' lengths into *steps when given.
  void Advance(const SegmentInput& in, Eigen::VectorXd* x, std::vector<double>* steps = nullptr);
  /// x ← x(h) along the given steps, no error control (the map the adjoint differentiates).
  void AdvanceAlong(const SegmentInput& in, Eigen::VectorXd* x, const std::vector<double>& steps);
  /// x ← x(h) and s ← ∂x(h)/∂p (its k columns move with in.dtheta and, when it has k columns, in.du).
  void AdvanceSensitivity(const SegmentInput& in, Eigen::VectorXd* x, Eigen::MatrixXd* s);
  /// The segment's adjoint from its start x0 along the values pass's `steps` (Advance's): λ(start)
  /// and q = λ(end)ᵀ ∂x(h)/∂p.
  void AdjointSegment(const SegmentInput& in, const Eigen::VectorXd& x0, const std::vector<double>& steps,
                      const Eigen::VectorXd& lambda_end, Eigen::VectorXd* lambda_start, Eigen::RowVectorXd* q);

 private:
  struct Stepper;
  // x (and s when not null) over the segment; the error control reads s too when `control_s`. The
  // accepted steps into *record; or, with `replay`, those steps taken as they are.
  void Integrate(const SegmentInput& in, Eigen::VectorXd* x, Eigen::MatrixXd* s, bool control_s,
                 std::vector<double>* record, const std::vector<double>* replay);

  const OdeSystem& sys_;
  const OdeOptions opt_;
  OdeStatistics* stats_;
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_ODE_ROSENBROCK_H_
