// Output offsets (not installed): a linear model's output y = C(θ)x + d(θ) with an amount-free part
// d, a baseline such as E = E0 + SLOPE·CE (pk/linear_model.h). Every Φ/Γ route, the eigen-
// coordinate path and the higher orders compute C x with its derivatives; d enters ŷ additively,
// so its value and derivatives are added here, once, from automatic differentiation of d:
//
//   ŷ_k += d_k(θ_k),   ∂ŷ_k/∂p += ∂d_k/∂p,   ∂V/∂p += Σ_k ∂ℓ/∂ŷ_k ∂d_k/∂p   (adjoint routes),
//   ∂²ŷ_k/∂p_a∂p_b += ∂²d_k/∂p_a∂p_b,   and the third order alike,
//
// where θ_k is the parameter set in force at sample k. The ODE propagators' linear path includes d
// in its output function (ode_system.cc), so predictions and first derivatives integrated there take
// none of this; the higher orders of a linear model come from the exact routes whatever the
// propagator, and take the offset's part here always.
#ifndef PK_SRC_OBJECTIVE_OUTPUT_OFFSETS_H_
#define PK_SRC_OBJECTIVE_OUTPUT_OFFSETS_H_

#include <array>
#include <vector>

#include <Eigen/Core>

#include "autodiff.h"
#include "events.h"
#include "pk/linear_model.h"

namespace pk {
namespace internal {

/// ŷ_k += d_k(θ) over the samples (record order).
void AddOutputOffsets(const LinearModel& model, const PreparedSubject& subject, Eigen::VectorXd* yhat);

/// ∂d_k/∂p (samples × num_free) from the sets seeded as pk::Dual (prediction.h's DualSets).
Eigen::MatrixXd OutputOffsetJacobian(const LinearModel& model, const PreparedSubject& subject,
                                     const std::vector<DualVector>& sets, int num_free);

/// (*out)[t] += ∂²d or ∂³d along directions[t] (positions among the num_free free parameters; a
/// third entry of −1 for a pair), from pk::HyperDual (pairs) or pk::HyperDual3 (triples) seeded along
/// them. Throws NumericalFailure for a triple when the model's derived coefficients have no third order.
void AddOutputOffsetDerivatives(const LinearModel& model, const PreparedSubject& subject,
                                const std::vector<DualVector>& sets, int num_free,
                                const std::vector<std::array<int, 3>>& directions, std::vector<Eigen::VectorXd>* out);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_OBJECTIVE_OUTPUT_OFFSETS_H_
