// libpk: how a model is propagated between events.
//
//   exact  the Φ/Γ recursion (linear models only): x ← Φ(h)x + Γ(h)u, exact
//   ode    CVODES (BDF, dense AD Jacobian) with its tolerances (pk/ode_options.h);
//          every model, linear or not
//   rk     a one-step Runge–Kutta method, Dormand–Prince 5(4) with error control and dense
//          output, with the same tolerances: restarts at doses cost one step, not a multistep
//          start-up. A stiff stretch (h·‖f_x‖∞ > 1000) is handed to RODAS4, an L-stable Rosenbrock method. Gradients by
//          forward sensitivities or by the discrete adjoint of its steps (continuous records:
//          forward sensitivities)
//   auto   exact for linear models, rk otherwise
#ifndef PK_PROPAGATOR_H_
#define PK_PROPAGATOR_H_

#include "pk/model.h"

namespace pk {

enum class Propagator { kAuto, kExact, kOde, kRungeKutta };

const char* ToString(Propagator p);
/// "auto", "exact", "ode" or "rk"; throws pk::InputError otherwise.
Propagator ParsePropagator(const std::string& text);

/// The propagator `requested` resolves to for `model`. Throws pk::InputError
/// when `exact` is asked of a nonlinear model.
Propagator ResolvePropagator(const Model& model, Propagator requested);

/// Whether `p` integrates the model's ODEs (ode or rk), as opposed to the exact recursion.
bool IntegratesOde(Propagator p);

}  // namespace pk

#endif  // PK_PROPAGATOR_H_
