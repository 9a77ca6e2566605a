// Exact second- and third-order sensitivities of a linear model whose events move with the free
// parameters p (not installed): a bioavailability F1 = exp(η_F), a lag ALAG1 = TLAG·exp(η_L), a
// modelled rate or duration, computed in $PK or estimated.
//
// Second_order.h and third_order.h stack the derivatives of x into one linear system, which holds
// only while doses do not depend on p. When they do, the amounts, rates and times the event engine
// hands on carry derivatives themselves, and a dose time that moves moves the step lengths on
// either side of it. So the engine runs on pk::HyperDual3 (events.h is a template on its scalar),
// seeded along two or three of the free parameters, and the state is a HyperDual3 vector: a jet
// X = Σ_S X_S ε^S with a part per subset S of the directions (ε_i² = 0). A step of length h under
// input rates u, both jets as A is, is the exponential of a jet matrix,
//
//   [x(t+h); 1] = exp( h · | A  u | ) [x(t); 1],
//                          | 0  0 |
//
// which jet_exponential.h takes in the algebra (the augmented matrix of Van Loan's Γ, with the
// step length inside the exponent so that its parts enter). A bolus adds its jet amount; the
// periodic steady state is the fixed point of the jet map of one dosing interval, solved part by
// part in order of the subsets (x*_S = (I − P_∅)⁻¹ (q_S + Σ_{T ⊊ S} P_{S∖T} x*_T)); a constant
// infusion's steady state solves A x = −u the same way. A sample's ŷ = C x is a jet product, and
// its part of every direction, ε₁ε₂ (or ε₁ε₂ε₃), is ∂²ŷ/∂p_k∂p_l (∂³ŷ/∂p_i∂p_j∂p_k). Repeated
// directions give the pure derivatives (ε₁, ε₂ both along p_k: ∂²/∂p_k²).
//
// One pass per pair or triple: dearer than the stacked systems' one pass for all of them, and only
// taken when the events move. Each pass costs a jet exponential of the (n+1)-square matrix per
// distinct step (steps of one length and input reuse it).
#ifndef PK_SRC_EXACT_MOVING_EVENTS_H_
#define PK_SRC_EXACT_MOVING_EVENTS_H_

#include <array>
#include <vector>

#include <Eigen/Core>

#include "../autodiff.h"
#include "../events.h"
#include "pk/linear_model.h"

namespace pk {
namespace internal {

/// (*out)[i] = ∂ᵏŷ along the free parameters directions[i] (positions among the `num_free`
/// derivatives `sets` carry; k = 2 with directions[i][2] = −1, else 3), over the samples in record
/// order. Throws NumericalFailure on numerical trouble, or when the model's computed modifiers or
/// derived coefficients have no third-order evaluation.
void MovingEventDerivatives(const LinearModel& model, const ParameterLayout& layout, const PreparedSubject& subject,
                            const std::vector<DualVector>& sets, int num_free,
                            const std::vector<std::array<int, 3>>& directions, std::vector<Eigen::VectorXd>* out);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_EXACT_MOVING_EVENTS_H_
