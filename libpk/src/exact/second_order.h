// Exact second-order sensitivities of a linear model's predictions (not installed): the seed's §5
// one order up.
//
// For free parameters p that move A(θ) and C(θ) but no event (no free F, ALAG, R or D, no
// parameter a computed modifier reads: moving_events.h takes those), the first
// and second derivatives of the state, s_k = ∂x/∂p_k and w = ∂²x/∂p_k∂p_l, obey linear equations
// driven by x itself:
//
//   s_k' = A s_k + A_k x,        w' = A w + A_k s_l + A_l s_k + A_kl x,
//
// with A_k = ∂A/∂p_k and A_kl = ∂²A/∂p_k∂p_l, and start from 0 and jump only where x does not
// (doses do not depend on p). So the stacked state z = [x; s_k; s_l; w] is the state of one
// linear system with the block lower-triangular matrix
//
//        | A     0    0    0 |
//   M =  | A_k   A    0    0 |      (inputs and doses enter the x block),
//        | A_l   0    A    0 |
//        | A_kl  A_l  A_k  A |
//
// which the exact propagator steps as it steps x: Φ_M(h) = e^{Mh} and Γ_M(h) by Van Loan's
// augmented exponential, steady states by the fixed point of M's dosing-interval map. (Van Loan,
// IEEE TAC 1978, gives the block exponential; the seed's §5 and its reference [1] use it for first
// and higher orders.) At a sample y = C x,
//
//   ∂²ŷ/∂p_k∂p_l = C w + C_k s_l + C_l s_k + C_kl x.
//
// A, C and their first and second directional derivatives come from one evaluation on a
// hyper-dual scalar (hyper_dual_number.h), through a model file's derived coefficients too.
#ifndef PK_SRC_EXACT_SECOND_ORDER_H_
#define PK_SRC_EXACT_SECOND_ORDER_H_

#include <utility>
#include <vector>

#include <Eigen/Core>

#include "../autodiff.h"
#include "../events.h"
#include "pk/hyper_dual.h"
#include "pk/linear_model.h"

namespace pk {
namespace internal {

/// [θ; ψ] of one parameter set on pk::HyperDual, θ moving along free parameters k (ε₁) and l (ε₂)
/// (positions among the derivatives `set` carries): ψ's parts from DerivedCoefficients::evaluate_second.
std::vector<HyperDual> ExtendedSecond(const LinearModel& model, const DualVector& set, int num_free, int k, int l);

/// (*out)[i] = ∂²ŷ/∂p_k∂p_l over the samples, in record order, for pairs[i] = (k, l) (indices
/// into the free parameters, which `sets` seed as pk::Dual derivatives). With
/// `eigen_coordinates`, subjects without steady states whose A is real-diagonalisable and well
/// conditioned (modal.h) take the Daleckii–Krein form of M's exponential (second_order.cc);
/// the others, and all without it, take e^{Mh} itself. Throws NumericalFailure on numerical
/// trouble. The events must not depend on p.
void SecondOrderSensitivities(const LinearModel& model, const ParameterLayout& layout, const PreparedSubject& subject,
                              const std::vector<DualVector>& sets, int num_free,
                              const std::vector<std::pair<int, int>>& pairs, bool eigen_coordinates,
                              std::vector<Eigen::VectorXd>* out);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_EXACT_SECOND_ORDER_H_
