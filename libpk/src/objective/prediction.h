// The prediction stage of an evaluation (not installed): ŷ at the samples and, by the chosen
// gradient route, either ∂ŷ/∂p (forward, companion, finite differences) or a recording that
// pulls ∂ℓ/∂ŷ back to ∂V/∂p (the adjoints). The per-sample loss (sample_loss.h) then needs
// nothing of the route (docs/gradients.md).
#ifndef PK_SRC_OBJECTIVE_PREDICTION_H_
#define PK_SRC_OBJECTIVE_PREDICTION_H_

#include <memory>
#include <vector>

#include <Eigen/Core>

#include "exact/exact_routes.h"
#include "objective/objective_state.h"
#include "ode/ode_routes.h"
#include "pk/objective.h"

namespace pk {
namespace internal {

/// The free parameters of an evaluation split into the layout's (model parameters and dose
/// modifiers, which get dual-number seeds) and the error model's σ (handled analytically).
class FreeParameters {
 public:
  FreeParameters(const std::vector<int>& free, int layout_size);
  /// Layout indices of the free layout parameters, in the order of `free`.
  const std::vector<int>& model() const { return all_model_ ? *free_ : subset_; }
  int num_model() const { return static_cast<int>(model().size()); }
  /// Position in `free` of model()[a].
  int Position(int a) const { return all_model_ ? a : position_[static_cast<size_t>(a)]; }
  bool all_model() const { return all_model_; }

 private:
  const std::vector<int>* free_;
  bool all_model_ = true;
  std::vector<int> subset_, position_;
};

struct Prediction {
  Eigen::MatrixXd jacobian;  ///< N × (free model parameters): ∂ŷ/∂p, on the Jacobian routes
  std::unique_ptr<DiscreteAdjoint> adjoint;  ///< exact propagator, Padé path
  ModalLease modal_lease;                    ///< holds the modal evaluator and its schedule
  ModalEvaluator* modal = nullptr;           ///< the adjoint in eigen-coordinates
  std::unique_ptr<OdeAdjoint> ode_adjoint;   ///< CVODES adjoint
  double continuous_loss = 0;                ///< ½∫ w (y − y_m)² of the continuous records
  Eigen::RowVectorXd continuous_gradient;    ///< its gradient (ODE forward route)
  /// ∂d/∂p of the output offsets (output_offsets.h), for the adjoint routes; the Jacobian routes
  /// carry it in `jacobian`. Empty when there are none.
  Eigen::MatrixXd offset_jacobian;

  /// Storage for ∂ℓ/∂ŷ, kept with the modal evaluator between evaluations.
  Eigen::VectorXd* LossGradientStorage(Eigen::VectorXd* fallback);
  /// ∂V/∂p over the free model parameters: Σ_k ∂ℓ/∂ŷ_k ∂ŷ_k/∂p plus the continuous records'
  /// term. False with ev->message when the adjoint's backward pass fails.
  bool ModelGradient(const Eigen::VectorXd& dl_dy, int num_model, Eigen::VectorXd* gradient,
                     Objective::Evaluation* ev);
};

/// Each parameter set with the free model parameters seeded as pk::Dual derivatives (those a
/// data column supplies stay constant), and the modifiers the model computes computed from them.
/// Whether layout parameter i moves dose amounts, rates or times: a dose modifier itself, or a
/// model parameter that a computed modifier (F1 = … in $PK) reads.
bool MovesDoses(const ObjectiveState& d, int i);

std::vector<DualVector> DualSets(const PreparedSubject& s, const ParameterLayout& layout, const FreeParameters& free);

/// ŷ into ev->predictions (emptied on failure, with ev->ok false and the message), and what
/// `route` needs for derivatives into `out`. Sets ev->modal and ev->ode_statistics.
bool Predict(const ObjectiveState& d, const Eigen::VectorXd& values, const FreeParameters& free,
             Objective::Need need, GradientRoute route, Prediction* out, Objective::Evaluation* ev);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_OBJECTIVE_PREDICTION_H_
