// The Φ/Γ recursion in eigen-coordinates (the modal form), not installed.
//
// When A = V Λ V⁻¹ with real eigenvalues and a well-conditioned V, the exact
// discretisation of a step of length h with constant input u is diagonal in
// z = V⁻¹x:
//
//   z⁺ = e^{Λh} z + g(Λ) V⁻¹u,   g(λ) = (e^{λh} − 1)/λ = f[λ, 0],  f(λ) = e^{λh},
//
// which is Φ = V e^{Λh} V⁻¹ and Γ = V g(Λ) V⁻¹ (seed §5) at n exponentials and
// O(n) work per step. Derivatives come from the Daleckii–Krein formula: for any
// analytic φ, ∂φ(A)/∂θ_j = V (D_φ ∘ Â_j) V⁻¹ with Â_j = V⁻¹ (∂A/∂θ_j) V and
// D_φ the matrix of divided differences φ[λ_i, λ_k]. With D_f = f[λ_i, λ_k] and
// D_g = f[λ_i, λ_k, 0]:
//
//  (a) forward: Ŝ = V⁻¹ ∂x/∂p evolves as
//        Ŝ⁺ = e^{Λh} Ŝ + Σ_j ((D_f ∘ Â_j) z + (D_g ∘ Â_j) û) ∂θ_j/∂p,   û = V⁻¹u;
//  (b) adjoint: μ̂ = Vᵀμ evolves as μ̂ ← e^{Λh} μ̂⁺, and the θ terms of all steps
//        Σ μ⁺ᵀ(∂Φ/∂θ_j x + ∂Γ/∂θ_j u) = ⟨V⁻ᵀ Z Vᵀ, ∂A/∂θ_j⟩,
//        Z = Σ D_f ∘ (μ̂⁺ zᵀ) + D_g ∘ (μ̂⁺ ûᵀ),
//      one n×n matrix per parameter set whatever the number of θ_j.
// Steady states are diagonal too: the dosing-interval map is z ↦ m ∘ z + r with
// m = Π e^{λh}, so z* = r / (1 − m), and the implicit-function adjoint is μ̂ / (1 − m).
//
// The decomposition exploits compartment structure: depots (states with no
// inflow) are one-state source blocks whose eigenvalue is their diagonal, and
// the remaining block is symmetrisable when exchange is reversible (clearance
// flows), so a symmetric eigensolver applies (discretization.h). Anything else
// uses the general real eigensolver. The modal form is used only when
// ‖|V||V⁻¹|‖_∞ ≤ 1e3 (a condition number of the modal sum that does not depend
// on how eigenvectors are scaled); callers fall back to the Padé path
// otherwise. It is normwise accurate (as closed-form sums of exponentials are), which suits a loss and its
// derivatives; simulations keep the Padé path for element-wise accuracy.
//
// It runs over an EventSchedule: the event engine's calls for fixed dose
// modifiers, recorded once and replayed for every θ (modifiers that are
// estimated move the schedule, and those evaluations take the general path).
#ifndef PK_SRC_EXACT_MODAL_H_
#define PK_SRC_EXACT_MODAL_H_

#include <cmath>
#include <memory>
#include <vector>

#include <Eigen/Core>

#include "../events.h"
#include "pk/linear_model.h"
#include "pk/parameters.h"

namespace pk {
namespace internal {

/// One visitor call of the event engine, in state coordinates of parameter set `set`.
struct ScheduleOp {
  enum Kind : unsigned char { kAdvance, kBolus, kReset, kSteadyState, kSteadyInfusion, kSample };
  Kind kind = kAdvance;
  bool add = false;  ///< steady states: SS=2 adds to the state
  int set = 0;       ///< the parameter set in force (for kReset: that of the previous op)
  int index = -1;    ///< kAdvance, kSteadyInfusion: input vector (-1: none); kSteadyState: cycle; kSample: sample
  int cmt = 0;       ///< kBolus: 0-based compartment; kSample: 1-based output compartment
  int step = -1;     ///< kAdvance: index of h in EventSchedule::steps
  double value = 0;  ///< kBolus: amount
};

struct ScheduleSegment {
  int step = -1;   ///< index of the duration in EventSchedule::steps
  int input = -1;  ///< input vector (-1: none)
};

struct ScheduleCycle {
  int cmt = 0;
  double bolus = 0;
  std::vector<ScheduleSegment> period, to_record;
};

struct EventSchedule {
  std::vector<ScheduleOp> ops;
  /// The distinct step lengths. e^{Λh} and its divided differences depend on h
  /// alone, so each is computed once per parameter set and step length, not
  /// once per step (sampling designs repeat a few intervals).
  std::vector<double> steps;
  /// For each step, a shorter one it is an exact multiple of: e^{Λh} = (e^{Λh'})^power
  /// at `power` − 1 products instead of n exponentials (sampling times such as 0.5,
  /// 1, 2, 4, 8, 12, 24 h make most steps multiples of others). base is -1 where
  /// there is none. Along a chain of bases the powers multiply to at most
  /// kMaxStepPower: a power k multiplies the relative rounding of its factor by k
  /// (and adds half an ulp), so a derived e^{λh} stays within about 8 ulps of the
  /// exponential's.
  struct StepPower {
    int base = -1;
    int power = 1;
  };
  std::vector<StepPower> step_powers;
  static constexpr int kMaxStepPower = 8;
  std::vector<Eigen::VectorXd> inputs;
  std::vector<ScheduleCycle> cycles;
  int num_samples = 0;
  /// Only advances, boluses, samples and resets (no steady states).
  bool simple = true;
  Eigen::VectorXd key;  ///< what it was recorded at (ObjectiveState::ScheduleKey: the modifiers, and what a computed one reads)
};

/// Runs the event engine once on `subject` (already bound to its values).
EventSchedule RecordSchedule(const ParameterLayout& layout, const PreparedSubject& subject);

/// Evaluates ŷ, and ∂ŷ/∂p or the adjoint gradient, by modal propagation.
class ModalEvaluator {
 public:
  virtual ~ModalEvaluator() = default;
  /// Prepares the evaluator for `schedule` at layout values `values` bound to
  /// `subject`: set k's model parameters are θ_k(i) = subject.sets[k](i) where
  /// subject.from_data[k][i], else values(i). Derivatives are taken with respect
  /// to the layout entries `free` (model parameters only; position a in `free`
  /// is entry a of the gradient and column a of the Jacobian), except in sets
  /// where a data column supplies one. False when some set's A is unsuitable
  /// (see above) or a parameter is not finite: the caller then takes the Padé
  /// path. Storage is kept from the previous use, so an evaluator reused across
  /// evaluations allocates little.
  virtual bool Reset(const EventSchedule& schedule, const Eigen::VectorXd& values, const PreparedSubject& subject,
                     const std::vector<int>& free) = 0;
  /// ŷ only.
  virtual void Predict(Eigen::VectorXd* yhat) = 0;
  /// ŷ and the N×P Jacobian ∂ŷ/∂p (route (a)).
  virtual void Jacobian(Eigen::VectorXd* yhat, Eigen::MatrixXd* jacobian) = 0;
  /// ŷ, keeping what the backward sweep needs (route (b)) ...
  virtual void AdjointForward(Eigen::VectorXd* yhat) = 0;
  /// ... and Σ_k ∂ℓ/∂ŷ_k ∂ŷ_k/∂p.
  virtual Eigen::VectorXd AdjointGradient(const Eigen::VectorXd& dl_dyhat) = 0;
};

/// An evaluator for `model`, to be Reset before use. Steady states without one
/// throw NumericalFailure when it runs.
std::unique_ptr<ModalEvaluator> NewModalEvaluator(const LinearModel& model);

/// The divided differences of f(λ) = e^{λh} used above, exposed for tests:
/// f[a, b] from e^{ah} and e^{bh}, and f[a, b, 0].
double DividedExp2Close(double a, double b, double ea, double eb, double h);
inline double DividedExp2(double a, double b, double ea, double eb, double h) {
  // Differences lose about ε/|(a − b)h| relative: closer points take the sinh form (modal.cc).
  const double d = a - b;
  return std::fabs(d) * h >= 0.1 ? (ea - eb) / d : DividedExp2Close(a, b, ea, eb, h);
}
double DividedExp3(double a, double b, double ea, double eb, double h);
/// f[a, b, c] and f[a, b, c, 0], for the second-order sensitivities in eigen-coordinates
/// (second_order.cc).
double DividedExp3General(double a, double b, double c, double h);
double DividedExp4(double a, double b, double c, double h);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_EXACT_MODAL_H_
