// Exact propagation of linear models (the seed's §5), not installed.
//
// Between event and output times the input is constant, so
//   x(t+h) = Φ(h) x(t) + Γ(h) u,   Φ(h) = e^{Ah},   Γ(h) = ∫₀ʰ e^{As} ds.
// Both come from one exponential of Van Loan's augmented matrix
//   exp([[A, I],[0, 0]] h) = [[Φ, Γ],[0, I]],
// which, unlike Γ = A⁻¹(Φ − I), also holds for singular A. With AUC tracking
// the state gains an integral row, d(AUC)/dt = c(θ)ᵀx, so A is singular by
// construction. Φ and Γ are cached per (parameter set, h): repeated dosing
// intervals cost one exponential.
#ifndef PK_SRC_EXACT_EXACT_PROPAGATOR_H_
#define PK_SRC_EXACT_EXACT_PROPAGATOR_H_

#include <stdexcept>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

#include "../events.h"
#include "pk/linear_model.h"

namespace pk {
namespace internal {

/// A numerical failure of one evaluation (reported, never a crash).
class NumericalFailure : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class ExactPropagator {
 public:
  /// `sets` are full ParameterLayout vectors; only the model part is used here.
  ExactPropagator(const LinearModel& model, const std::vector<Eigen::VectorXd>& sets, bool track_auc);

  // The EventEngine visitor interface (see events.h).
  void Advance(double h, const Eigen::VectorXd& rate, int set);
  void Bolus(int cmt, double amount, int set);
  void Reset();
  void SteadyState(const SteadyStateCycle<double>& cycle, int set, bool add);
  void SteadyInfusion(const Eigen::VectorXd& rate, int set, bool add);

  /// Amounts (first n entries) and, with AUC tracking, the AUC last.
  const Eigen::VectorXd& state() const { return x_; }
  double auc() const { return track_auc_ ? x_(n_) : 0.0; }
  /// Number of matrix exponentials computed so far (cache misses).
  long exponentials() const { return exponentials_; }

 private:
  struct Discretization {
    Eigen::MatrixXd phi;    // N×N, N = n (+1 with AUC)
    Eigen::MatrixXd gamma;  // N×n
  };
  struct SetCache {
    Eigen::MatrixXd a;  // N×N, augmented with the AUC row
    std::unordered_map<double, Discretization> by_h;
  };
  const Discretization& Get(int set, double h);

  const LinearModel& model_;
  const int n_;
  const bool track_auc_;
  std::vector<SetCache> cache_;
  Eigen::VectorXd x_;
  long exponentials_ = 0;
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_EXACT_EXACT_PROPAGATOR_H_
