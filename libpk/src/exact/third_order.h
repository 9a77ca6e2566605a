// Exact third-order sensitivities of a linear model's predictions (not installed): second_order.h
// one order up, for the population's Laplace gradient (the log det of the exact ½∇²l moves with
// the parameters, and ½∇²l holds ∂²ŷ).
//
// Every derivative of the state up to order 3 in the p free parameters, at once: its truncated
// Taylor series x(p̂ + δ) = Σ_α x_α δ^α, x_α = ∂^α x/α!, one block per monomial of degree ≤ 3 that
// divides a requested triple's p_i p_j p_k (all 20 for every triple of p = 3). From x' = A x + u with A's own series A(p̂ + δ) = Σ A_α δ^α, matching powers
// of δ gives
//
//   x_γ' = Σ_{α + β = γ} A_α x_β          (u and the doses enter x_0 alone: they do not depend on p; moving_events.h when they do),
//
// from 0 for γ ≠ 0. The stacked state z = [x_γ] is the state of one linear system whose matrix M
// has the block A_α at (α + β, β): block lower-triangular by degree, A on its diagonal. The exact
// propagator steps it as it steps x, steady states by the fixed point of M's interval map (Van Loan,
// IEEE TAC 1978; the seed's §5 and its reference [1] use such block exponentials for first and
// higher orders), its exponentials those of the jet A(δ) (jet_exponential.h) rather than of the
// dense M. At a sample y = C x, y_γ = Σ_{α + β = γ} C_α x_β and
//
//   ∂³ŷ/∂p_i∂p_j∂p_k = γ! · y_γ,   γ = p_i p_j p_k.
//
// A's and C's coefficients come from evaluations on pk::HyperDual3 along each triple (i, j, k),
// through a model file's derived coefficients too (DerivedCoefficients::evaluate_third).
#ifndef PK_SRC_EXACT_THIRD_ORDER_H_
#define PK_SRC_EXACT_THIRD_ORDER_H_

#include <array>
#include <vector>

#include <Eigen/Core>

#include "../autodiff.h"
#include "../events.h"
#include "pk/hyper_dual.h"
#include "pk/linear_model.h"

namespace pk {
namespace internal {

/// [θ; ψ] on HyperDual3: the model parameters θ as given (linear in the free parameters: parts
/// 1, 2 and 4 only), then the derived coefficients ψ(θ) with every part (a model file's
/// DerivedCoefficients::evaluate_third). Throws NumericalFailure when ψ has no third order.
std::vector<HyperDual3> ExtendedThird(const LinearModel& model, std::vector<HyperDual3> theta);

/// (*out)[t] = ∂³ŷ/∂p_i∂p_j∂p_k over the samples, in record order, for triples[t] = (i, j, k)
/// (indices into the free parameters, which `sets` seed as pk::Dual derivatives). Throws
/// NumericalFailure on numerical trouble, or when a model file's derived coefficients have no
/// third order. The events must not depend on p.
void ThirdOrderSensitivities(const LinearModel& model, const ParameterLayout& layout, const PreparedSubject& subject,
                             const std::vector<DualVector>& sets, int num_free,
                             const std::vector<std::array<int, 3>>& triples, std::vector<Eigen::VectorXd>* out);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_EXACT_THIRD_ORDER_H_
