// The companion-form route for transfer-function models (the seed's 6.5–6.8), not installed.
//
// For y = B(s)/A(s)·u in the companion realisation (states x_k = s^{n−k}/A·u):
//   ∂y/∂b_i = x_i                       (the plant itself: one filter 1/A driven by u)
//   ∂y/∂a_i = −s^{n−i}B/A²·u = ω_i,     ω = the same filter driven by −y.
// Plant and filter form one 2n-state linear system
//   d/dt [x; ω] = [[A_c, 0], [−e₁bᵀ, A_c]] [x; ω] + [e₁; 0] u,
// propagated exactly between events by the Φ/Γ recursion, so every ∂y/∂a_i and
// ∂y/∂b_i comes from one extra n-dimensional system, whatever n is. The
// identity needs time-invariant coefficients (one parameter set).
#ifndef PK_SRC_EXACT_COMPANION_ROUTE_H_
#define PK_SRC_EXACT_COMPANION_ROUTE_H_

#include <Eigen/Core>

#include "../events.h"
#include "pk/linear_model.h"

namespace pk {
namespace internal {

/// ŷ and ∂ŷ/∂(a₁..aₙ, b₁..bₙ) (N×2n) for a tf<n> model. Throws NumericalFailure
/// on numerical trouble or time-varying coefficients.
void CompanionJacobian(const LinearModel& model, const ParameterLayout& layout, const PreparedSubject& subject,
                       Eigen::VectorXd* yhat, Eigen::MatrixXd* jacobian);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_EXACT_COMPANION_ROUTE_H_
