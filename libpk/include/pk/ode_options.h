// libpk: options of the ODE propagator (CVODES, BDF with the dense AD Jacobian).
#ifndef PK_ODE_OPTIONS_H_
#define PK_ODE_OPTIONS_H_

#include <string>

namespace pk {

struct OdeOptions {
  double relative_tolerance = 1e-8;
  /// Absolute tolerance on the amounts and their sensitivities. The adjoint λ
  /// (loss per amount) uses rtol·‖λ‖_∞ at the start of each backward segment
  /// instead, never less than this.
  double absolute_tolerance = 1e-10;
  /// Step limit per integration between two events; beyond it the evaluation
  /// fails with "too much work" instead of running on.
  long max_steps = 100000;
  /// Adjoint route: at most this many integration steps between two CVODES
  /// checkpoints. Fewer steps store less and recompute more (the seed's §4
  /// trade of time for storage). A trajectory of fewer steps is held in one
  /// piece, in storage for the steps it takes; results do not depend on how
  /// much it could have held.
  int checkpoint_steps = 10000;
  /// Adjoint route: keep every inter-event segment's trajectory from the one
  /// forward pass (true), or keep only the segment being swept and integrate
  /// each one forward a second time during the sweep (false: about one more
  /// forward solve, storage of one segment instead of all).
  bool adjoint_store_all_segments = true;
  /// Adjoint of the one-step method (Propagator::kRungeKutta): take wᵀf_x and wᵀf_θ at each stage from
  /// a compressed sparse Jacobian (f evaluated once on a few forward-mode lanes) when f's pattern
  /// compresses into at most 8 lanes and f never looks at a value; otherwise, or when false, from a
  /// recording of f swept backward. Both are exact; they differ by rounding (docs/ode_routes.md). The
  /// one-step method's stiffness checks and the adjoint's step bound also take ‖f_x‖∞ from the
  /// compressed Jacobian (one evaluation on the lanes instead of n directions).
  bool compressed_jacobians = true;
  /// With compressed Jacobians, the one-step method's adjoint evaluates f on the lanes already in its
  /// forward pass and keeps every stage's lanes, so the backward pass sweeps them without evaluating f
  /// again: about a sixth less work for 6·(W+1) numbers a state and step kept instead of 1 (W ≤ 8
  /// lanes). False: the forward pass keeps each step's start, and the backward pass evaluates the stages
  /// again. The same gradient either way, to the last bit.
  bool adjoint_keeps_stages = true;
  /// Bytes of kept stages (adjoint_keeps_stages) one evaluation of one subject may hold on its thread.
  /// A step keeps 6·n·(W+1)·8 bytes (n states, W ≤ 8 lanes), and the first step of a run of kept steps
  /// one slot more; steps keep their stages while the next step's fit, and the steps after that keep
  /// only their start (n + 1 numbers, not counted here), their stages evaluated again in the backward
  /// pass. A budget below 7·n·(W+1)·8 bytes keeps nothing. Kept stages pay only while the backward pass
  /// finds them in cache: on a machine whose memory is slow against its arithmetic, sweeping stages that
  /// had to come back from memory cost more than evaluating them again (docs/performance.md §9). 0 (the
  /// default): half of the processor's second-level cache as the system reports it, 512 KiB when it
  /// does not. The same gradient, to the last bit, whatever the budget.
  long adjoint_kept_stage_bytes = 0;
  /// Steady states of nonlinear models: Newton iterations on x = P(x) allowed.
  int max_newton_iterations = 50;

  bool IsValid(std::string* error) const;
};

/// What the ODE propagator did in one evaluation (for the time/storage trade-off).
struct OdeStatistics {
  long steps = 0;                 ///< forward integration steps (all passes)
  long rhs_evaluations = 0;       ///< f and the adjoint right-hand side
  long jacobian_evaluations = 0;
  long backward_steps = 0;        ///< adjoint steps
  long stiff_steps = 0;           ///< of `steps`, those of the rk propagator's stiff method (RODAS4)
  /// Largest adjoint storage held at once: CVODES's Hermite data (y and ẏ per
  /// step, at most checkpoint_steps steps) plus its checkpoints (a Nordsieck array each).
  long peak_adjoint_bytes = 0;
};

}  // namespace pk

#endif  // PK_ODE_OPTIONS_H_
