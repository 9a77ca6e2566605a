// Exact third-order sensitivities of a linear model's predictions (not installed): second_order.h
// one order up, for the population's Laplace gradient (the log det of the exact ½∇²l moves with
// the parameters, and ½∇²l holds ∂²ŷ).
//
// Along three free parameters i, j, k (directions 1, 2, 4 as bit masks), the state's derivatives
// x_S = ∂^|S| x / ∂p_S for every subset S of them obey, from the product rule on x' = A x + u,
//
//   x_S' = Σ_{T ⊆ S} A_{S∖T} x_T          (A_∅ = A, A_S the mixed derivative of A along S),
//
// from 0 for S ≠ ∅, jumping only where x does (doses do not depend on p). The stacked state
// z = [x_0; x_1; …; x_7] is the state of one linear system whose matrix M has the block A_{S∖T} at
// (S, T) for T ⊆ S: block lower-triangular, A on its diagonal. The exact propagator steps it as it
// steps x (e^{Mh}, Van Loan's Γ_M, steady states by the fixed point of M's interval map; Van Loan,
// IEEE TAC 1978; the seed's §5 and its reference [1] use the same block exponential for first and
// higher orders). At a sample y = C x,
//
//   ∂³ŷ/∂p_i∂p_j∂p_k = Σ_{T ⊆ 7} C_{7∖T} x_T.
//
// A and C with all their mixed derivatives come from one evaluation on pk::HyperDual3, through a
// model file's derived coefficients too (DerivedCoefficients::evaluate_third).
#ifndef PK_SRC_EXACT_THIRD_ORDER_H_
#define PK_SRC_EXACT_THIRD_ORDER_H_

#include <array>
#include <vector>

#include <Eigen/Core>

#include "../autodiff.h"
#include "../events.h"
#include "pk/linear_model.h"

namespace pk {
namespace internal {

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
