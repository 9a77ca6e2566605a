// libpk: options of the ODE propagator (CVODES, BDF with the dense AD Jacobian).
#ifndef PK_ODE_OPTIONS_H_
#define PK_ODE_OPTIONS_H_

#include <string>

namespace pk {

struct OdeOptions {
  double relative_tolerance = 1e-8;
  /// Absolute tolerance on the amounts (and on sensitivities and adjoints).
  double absolute_tolerance = 1e-10;
  /// Step limit per integration between two events; beyond it the evaluation
  /// fails with "too much work" instead of running on.
  long max_steps = 100000;
  /// Adjoint route: integration steps between two CVODES checkpoints. Fewer
  /// steps store less and recompute more (the seed's §4 trade of time for storage).
  int checkpoint_steps = 100;
  /// Steady states of nonlinear models: Newton iterations on x = P(x) allowed.
  int max_newton_iterations = 50;

  bool IsValid(std::string* error) const;
};

}  // namespace pk

#endif  // PK_ODE_OPTIONS_H_
