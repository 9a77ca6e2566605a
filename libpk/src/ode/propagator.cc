#include "pk/propagator.h"

#include "pk/error.h"
#include "pk/ode_options.h"

namespace pk {

const char* ToString(Propagator p) {
  switch (p) {
    case Propagator::kAuto: return "auto";
    case Propagator::kExact: return "exact";
    case Propagator::kOde: return "ode";
    case Propagator::kRungeKutta: return "rk";
  }
  return "?";
}

Propagator ParsePropagator(const std::string& text) {
  for (Propagator p : {Propagator::kAuto, Propagator::kExact, Propagator::kOde, Propagator::kRungeKutta}) {
    if (text == ToString(p)) return p;
  }
  throw InputError("expected auto, exact, ode or rk, got '" + text + "'");
}

Propagator ResolvePropagator(const Model& model, Propagator requested) {
  if (requested == Propagator::kExact && !model.is_linear()) {
    throw InputError("model " + model.name() +
                                   " is nonlinear: the exact (Φ/Γ) propagator needs a linear model; use "
                                   "--propagator ode");
  }
  if (requested == Propagator::kAuto) return model.is_linear() ? Propagator::kExact : Propagator::kRungeKutta;
  return requested;
}

bool IntegratesOde(Propagator p) { return p == Propagator::kOde || p == Propagator::kRungeKutta; }

bool OdeOptions::IsValid(std::string* error) const {
  auto fail = [&](const char* why) {
    if (error) *error = why;
    return false;
  };
  if (!(relative_tolerance > 0 && relative_tolerance < 1)) return fail("the ODE relative tolerance must be in (0, 1)");
  if (!(absolute_tolerance > 0)) return fail("the ODE absolute tolerance must be > 0");
  if (max_steps < 1) return fail("the ODE step limit must be >= 1");
  if (checkpoint_steps < 1) return fail("the checkpoint interval must be >= 1 step");
  if (adjoint_kept_stage_bytes < 0) return fail("the adjoint's budget of kept stages must be >= 0 bytes");
  if (max_newton_iterations < 1) return fail("the steady-state Newton limit must be >= 1");
  return true;
}

}  // namespace pk
