// Second- and third-order sensitivities of a nonlinear model when doses move with the free
// parameters p (not installed): the ODE propagator's counterpart of exact/moving_events.h, for a
// bioavailability, lag, rate or duration computed from η in $PK (or estimated) in a model that is
// not linear.
//
// The event engine runs on pk::HyperDual3 seeded along a pair (triple) of free parameters, so dose
// amounts, rates and times carry their derivatives, and the state is the jet X = Σ_S X_S ε^S, a part
// per subset S of the directions (ε_i² = 0). Over a stretch of jet length H under jet rates U, in
// τ = (t − t₀)/h ∈ [0, 1],
//
//   dX/dτ = H · (f(X, Θ) + U),
//
// f evaluated on HyperDual3 by the model's own program (every part at once) and the product that of
// the jet algebra. The length inside the right-hand side is how a moving dose time enters: part by
// part it gives ∂x(t₀+h)/∂h = f + u and its derivatives, to the third order. Dormand–Prince 5(4)
// integrates every part under one error control (rk_solver.h), as second_order.h does its stacked
// blocks. A bolus adds its jet amount.
//
// Steady states, part by part in order of |S|. Periodic: x* by Newton on x = P(x) with P_x from n
// directions; the cycle's map is affine in X_S with the matrix P_x once the parts below S are fixed,
// so one jet cycle started with the parts of order |S| at 0 gives b_S, and X*_S = (I − P_x)⁻¹ b_S.
// A constant infusion's: f(x*) + u = 0, then X*_S = −f_x⁻¹ (part S of f(X) + U with X_S = 0).
// At a sample, the part of every direction of g(X, Θ) is ∂²ŷ (∂³ŷ).
//
// One pass per pair or triple (SecondDerivatives and ThirdDerivatives send only those along which
// a dose moves; the others keep second_order.h's one pass).
#ifndef PK_SRC_ODE_MOVING_EVENTS_H_
#define PK_SRC_ODE_MOVING_EVENTS_H_

#include <array>
#include <vector>

#include <Eigen/Core>

#include "../autodiff.h"
#include "../events.h"
#include "ode_routes.h"

namespace pk {
namespace internal {

/// (*out)[i] = ∂ᵏŷ over the samples (o.sample_of_record's order) along the free parameters
/// directions[i] (k = 2 with directions[i][2] = −1, else 3). Throws NumericalFailure where the route
/// does not apply (a continuous record, a linear system) or fails.
void OdeMovingEventDerivatives(const OdeSubject& o, const PreparedSubject& s, const std::vector<DualVector>& sets,
                               int num_free, const std::vector<std::array<int, 3>>& directions,
                               std::vector<Eigen::VectorXd>* out);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_ODE_MOVING_EVENTS_H_
