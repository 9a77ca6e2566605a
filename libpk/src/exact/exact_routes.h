// The two Φ/Γ gradient routes for linear models (not installed).
//
// Both run the PREDPP event engine on dual numbers (so event times, amounts
// and rates carry ∂/∂p) and produce the predictions ŷ_k of the samples
// (records with IsSample()) in record order: their amounts' part C x, to which the
// objective adds an output's offset d(θ) (objective/output_offsets.h).
//
//  (a) Forward: propagates the state sensitivity S = ∂x/∂p alongside x,
//        S ← Φ S + Γ ∂u/∂p + Σ_j (∂Φ/∂θ_j x + ∂Γ/∂θ_j u) ∂θ_j/∂p + (A x⁺ + u) ∂h/∂p,
//      and returns the full Jacobian ∂ŷ/∂p (N×P).
//  (b) Discrete adjoint: records the step sequence, then sweeps backwards with
//        λ_k = Φ_kᵀ λ_{k+1} + Σ samples at k of cᵀ ∂ℓ/∂ŷ,
//      and returns Σ_k ∂ℓ/∂ŷ_k ∂ŷ_k/∂p for given ∂ℓ/∂ŷ. The θ part costs one
//      Fréchet exponential per distinct interval, whatever P is.
// Steady states are differentiated implicitly through their fixed point
// (I − M) x* = M b + w; see docs/gradients.md.
#ifndef PK_SRC_EXACT_EXACT_ROUTES_H_
#define PK_SRC_EXACT_EXACT_ROUTES_H_

#include <memory>
#include <vector>

#include <Eigen/Core>

#include "../autodiff.h"
#include "../events.h"
#include "pk/linear_model.h"

namespace pk {
namespace internal {

/// Route (a). Throws NumericalFailure on numerical trouble. When no estimated
/// parameter moves an event (no free F, ALAG, R or D), `events_depend_on_p` is
/// false and the event engine runs on plain doubles.
void ForwardSensitivities(const LinearModel& model, const ParameterLayout& layout, const PreparedSubject& subject,
                          const std::vector<DualVector>& sets, int num_free, bool events_depend_on_p,
                          Eigen::VectorXd* yhat, Eigen::MatrixXd* jacobian);

/// Route (b): Forward() computes ŷ and records the steps; Gradient() sweeps back.
class DiscreteAdjoint {
 public:
  DiscreteAdjoint(const LinearModel& model, const ParameterLayout& layout, const PreparedSubject& subject,
                  const std::vector<DualVector>& sets, int num_free, bool events_depend_on_p);
  ~DiscreteAdjoint();
  void Forward(Eigen::VectorXd* yhat);
  Eigen::VectorXd Gradient(const Eigen::VectorXd& dl_dyhat);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Predictions only (no derivatives), from the plain exact propagator.
void Predict(const LinearModel& model, const ParameterLayout& layout, const PreparedSubject& subject,
             Eigen::VectorXd* yhat);

/// The sample index of each record (-1 for records that are not samples), and the count.
std::vector<int> SampleIndex(const PreparedSubject& subject, int* count);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_EXACT_EXACT_ROUTES_H_
