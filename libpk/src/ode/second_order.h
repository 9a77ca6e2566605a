// Second-order sensitivities of a nonlinear model's predictions on the ODE propagator (not
// installed): the population's outer gradient (FOCE, FOCEI) needs ∂²ŷ/∂p_k∂p_l, and the issue's
// rule is forward sensitivities of the sensitivity system, not differences.
//
// For model parameters p that move f and g but no event (no free F, ALAG, R or D, no modifier
// computed from p: moving_events.h takes those), with d_k = (s_k, ∂θ/∂p_k), s_k = ∂x/∂p_k and w_kl = ∂²x/∂p_k∂p_l,
//
//   s_k'  = f_x s_k + f_θ ∂θ/∂p_k,
//   w_kl' = f_x w_kl + f''[d_k, d_l]                   (θ is linear in p: ∂²θ/∂p_k∂p_l = 0),
//
// from s = w = 0; doses and resets move x alone, since their amounts do not depend on p. At a
// sample of output g,  ∂²ŷ/∂p_k∂p_l = g_x w_kl + g''[d_k, d_l].
//
// f_x w_kl + f''[d_k, d_l] is one evaluation of f on pk::HyperDual seeded with x + s_k ε₁ + s_l ε₂ +
// w_kl ε₁ε₂ and θ + θ_k ε₁ + θ_l ε₂, so the model's own program supplies it exactly. The stacked state
// [x; s; w] is integrated by Dormand–Prince 5(4) (Boost.Odeint) under one error control, so w is
// controlled as x and s are; the result is the derivative of the exact solution to the requested
// tolerance (not the discrete derivative of the computed ŷ: at rtol 1e-8 they differ by about that).
// Stiff segments are stepped by the same explicit method, which costs steps but not accuracy.
//
// Steady states. A dosing cycle's map P is nonlinear in x but, at its fixed point x*, affine in s
// and w with the one matrix P_x: s(T) = P_x s(0) + b_s and w(T) = P_x w(0) + b_w(s(0)). So
// s* = (I − P_x)⁻¹ b_s and w* = (I − P_x)⁻¹ b_w(s*), with x* by Newton on x = P(x) and P_x from n
// directions in x₀ integrated with it. A constant infusion's: f(x*) + u = 0, s* = −f_x⁻¹ f_θ θ_p,
// w* = −f_x⁻¹ f''[d_k, d_l]. Continuous records are not covered (NumericalFailure).
#ifndef PK_SRC_ODE_SECOND_ORDER_H_
#define PK_SRC_ODE_SECOND_ORDER_H_

#include <array>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <Eigen/LU>

#include "../autodiff.h"
#include "../events.h"
#include "ode_routes.h"

namespace pk {
namespace internal {

/// (*out)[i] = ∂²ŷ/∂p_k∂p_l over the samples (o.sample_of_record's order) for pairs[i] = (k, l),
/// indices into the `num_free` parameters that `sets` seed. Throws NumericalFailure where the
/// route does not apply (a continuous record, a linear system) or fails.
void OdeSecondOrderSensitivities(const OdeSubject& o, const PreparedSubject& s, const std::vector<DualVector>& sets,
                                 int num_free, const std::vector<std::pair<int, int>>& pairs,
                                 std::vector<Eigen::VectorXd>* out);

/// (*out)[t] = ∂³ŷ/∂p_i∂p_j∂p_k over the samples for triples[t] = {i, j, k}: the stacked state
/// carries the pairs within the triples and, for each triple, z_ijk with z' = f_x z + (the rest of
/// f's ε₁ε₂ε₃ part on pk::HyperDual3), the same construction one order up. Throws as above.
void OdeThirdOrderSensitivities(const OdeSubject& o, const PreparedSubject& s, const std::vector<DualVector>& sets,
                                int num_free, const std::vector<std::array<int, 3>>& triples,
                                std::vector<Eigen::VectorXd>* out);

/// Throws NumericalFailure where the higher orders do not apply: a linear system (Φ/Γ serves it), or
/// continuous records.
void CheckHigherOrderRoute(const OdeSubject& o);

/// A steady-state Newton step's tolerance at x: rtol‖x‖∞ + atol.
inline double NewtonTolerance(const OdeOptions& options, const Eigen::VectorXd& x) {
  return options.relative_tolerance * x.lpNorm<Eigen::Infinity>() + options.absolute_tolerance;
}

/// x* with f(x*, θ) + u = 0, by Newton from 0 to the options' tolerances, and *lu of f_x at x*: the
/// higher orders' steady state of a constant infusion. Throws NumericalFailure.
Eigen::VectorXd InfusionSteadyState(const OdeModel& model, const OdeOptions& options, const Eigen::VectorXd& theta,
                                    const Eigen::VectorXd& u, Eigen::FullPivLU<Eigen::MatrixXd>* lu);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_ODE_SECOND_ORDER_H_
