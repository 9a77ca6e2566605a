// libpk: how a model is propagated between events.
//
//   exact  the Φ/Γ recursion (linear models only): x ← Φ(h)x + Γ(h)u, exact
//   ode    CVODES (BDF, dense AD Jacobian) with its tolerances (pk/ode_options.h);
//          every model, linear or not
//   auto   exact for linear models, ode otherwise
#ifndef PK_PROPAGATOR_H_
#define PK_PROPAGATOR_H_

#include "pk/model.h"

namespace pk {

enum class Propagator { kAuto, kExact, kOde };

const char* ToString(Propagator p);
/// "auto", "exact" or "ode"; throws pk::InputError otherwise.
Propagator ParsePropagator(const std::string& text);

/// The propagator `requested` resolves to for `model`. Throws pk::InputError
/// when `exact` is asked of a nonlinear model.
Propagator ResolvePropagator(const Model& model, Propagator requested);

}  // namespace pk

#endif  // PK_PROPAGATOR_H_
