// Exact propagation of linear models (the seed's §5), not installed.
//
// Between event and output times the input is constant, so
//   x(t+h) = Φ(h) x(t) + Γ(h) u,   Φ(h) = e^{Ah},   Γ(h) = ∫₀ʰ e^{As} ds.
// Both come from the eigendecomposition of A or from one exponential of Van
// Loan's augmented matrix exp([[A, I],[0, 0]] h) = [[Φ, Γ],[0, I]] (see
// discretization.h); unlike Γ = A⁻¹(Φ − I), both hold for singular A. With AUC
// tracking the state gains an integral row, d(AUC)/dt = c(θ)ᵀx, so A is
// singular by construction. Φ and Γ are cached per (parameter set, h):
// repeated dosing intervals cost one evaluation, and so do step lengths a few
// ulps apart, through a first-order correction (Discretization::GetNearby).
#ifndef PK_SRC_EXACT_EXACT_PROPAGATOR_H_
#define PK_SRC_EXACT_EXACT_PROPAGATOR_H_

#include <stdexcept>
#include <memory>
#include <vector>

#include <Eigen/Core>

#include "../events.h"
#include "discretization.h"
#include "numerical_failure.h"
#include "pk/linear_model.h"

namespace pk {
namespace internal {

class ExactPropagator {
 public:
  /// `sets` are full ParameterLayout vectors; only the model part is used here.
  ExactPropagator(const LinearModel& model, const std::vector<Eigen::VectorXd>& sets, bool track_auc);
  /// An augmented linear system, given by its matrix per set: rates and doses enter its first
  /// `n_in` states (the model's amounts); a reset clears every state, and a steady state solves for
  /// all of them (the second-order sensitivities of exact/second_order.h propagate this way).
  /// With `jet` each matrix is a stacked jet of that algebra (jet_exponential.h), whose
  /// exponentials are taken part by part.
  ExactPropagator(const std::vector<Eigen::MatrixXd>& matrices, int n_in,
                  std::shared_ptr<const JetProducts> jet = nullptr);

  // The EventEngine visitor interface (see events.h).
  void Advance(double h, const Eigen::VectorXd& rate, int set);
  void Bolus(int cmt, double amount, int set);
  void Reset();
  void SteadyState(const SteadyStateCycle<double>& cycle, int set, bool add);
  void SteadyInfusion(const Eigen::VectorXd& rate, int set, bool add);

  /// Amounts (first n entries) and, with AUC tracking, the AUC last.
  const Eigen::VectorXd& state() const { return x_; }
  double auc() const { return track_auc_ ? x_(n_) : 0.0; }
  /// Exact steps need no clock (the ODE propagator's interface has one).
  void set_time(double) {}

 private:
  // Per parameter set: A (augmented with the AUC row, N = n + 1) and its steps.
  const Discretization::Step& Get(int set, double h, const Eigen::VectorXd& rate) {
    return cache_[set]->Get(h, !rate.isZero(0.0));
  }

  const int n_;  // the states a reset clears and a steady state solves for
  const bool track_auc_;
  std::vector<std::unique_ptr<Discretization>> cache_;
  std::vector<double> auc_offset_;  // per set, with AUC tracking: the central output's offset d(θ)
  Eigen::VectorXd x_;
  Eigen::VectorXd scratch_;  // Advance's product, swapped with x_
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_EXACT_EXACT_PROPAGATOR_H_
