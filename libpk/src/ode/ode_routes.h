// The ODE gradient routes (not installed), the seed's §4 with CVODES:
//
//  (a) Forward sensitivities: S = ∂x/∂p integrated alongside x (ode_propagator.h);
//      ∂ŷ_k/∂p = g_x S + g_θ ∂θ/∂p at every sample, the full Jacobian.
//  (b) The adjoint: a forward pass records the steps; the sweep runs backward
//      with λ(T) = 0,
//        at a sample        λ ← λ + g_xᵀ ∂ℓ_k/∂y          (the seed's 4.7: a jump of F)
//        over a segment     dλ/dt = −f_xᵀλ − g_xᵀ(dF/dt)(y − y_m),  ∇ += ∫ λᵀ(f_θ θ_p + u_p) ds
//                           plus λ(t⁺)ᵀ(f(x⁺) + u) ∂h/∂p for a moving segment end
//        at a bolus         ∇ += λ[c] ∂(F·AMT)/∂p           (λ is continuous)
//        at a reset         λ ← 0
//        at a steady state  ∇ += μᵀ ∂P/∂p, (I − P_x)ᵀ μ = λ, one backward pass over the cycle
//      whose cost is one backward system whatever the number of parameters.
// Both also give the continuous records' loss ½∫ w (y − y_m)² and its gradient.
#ifndef PK_SRC_ODE_ODE_ROUTES_H_
#define PK_SRC_ODE_ODE_ROUTES_H_

#include <memory>
#include <vector>

#include <Eigen/Core>

#include "../autodiff.h"
#include "../events.h"
#include "ode_propagator.h"
#include "ode_system.h"

namespace pk {
namespace internal {

/// What the routes need besides the parameters: the output key of each record
/// and the continuous records. Samples are the records with IsSample() that
/// are not part of a continuous record.
struct OdeSubject {
  const OdeSystem* system = nullptr;
  const ParameterLayout* layout = nullptr;
  OdeOptions options;
  Propagator integrator = Propagator::kOde;  ///< kOde (CVODES) or kRungeKutta
  std::vector<int> key_of_record;
  std::vector<int> sample_of_record;  ///< -1 when the record is not a (discrete) sample
  int num_samples = 0;
  ContinuousRecords continuous;
};

/// Predictions (and the continuous loss), no derivatives.
void OdePredict(const OdeSubject& o, const PreparedSubject& s, Eigen::VectorXd* yhat, double* continuous_loss,
                OdeStatistics* stats = nullptr);

/// Route (a): ŷ, ∂ŷ/∂p (N×P), the continuous loss and its gradient (1×P).
void OdeForwardSensitivities(const OdeSubject& o, const PreparedSubject& s, const std::vector<DualVector>& sets,
                             int p, Eigen::VectorXd* yhat, Eigen::MatrixXd* jacobian, double* continuous_loss,
                             Eigen::RowVectorXd* continuous_gradient, OdeStatistics* stats = nullptr);

/// Route (b): Forward() computes ŷ and the continuous loss and records the
/// steps; Gradient() sweeps back and returns Σ ∂ℓ/∂ŷ_k ∂ŷ_k/∂p plus the
/// continuous loss's gradient.
class OdeAdjoint {
 public:
  OdeAdjoint(const OdeSubject& o, const PreparedSubject& s, const std::vector<DualVector>& sets, int p);
  ~OdeAdjoint();
  void Forward(Eigen::VectorXd* yhat, double* continuous_loss);
  Eigen::VectorXd Gradient(const Eigen::VectorXd& dl_dyhat);
  const OdeStatistics& statistics() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_ODE_ODE_ROUTES_H_
