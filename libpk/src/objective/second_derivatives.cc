// Objective::SecondDerivatives: ∂²ŷ/∂p_a∂p_b from Φ/Γ (exact/second_order.h) or from the ODE
// propagator's second-order sensitivities (ode/second_order.h).
#include <algorithm>

#include "exact/second_order.h"
#include "numerical_failure.h"
#include "ode/second_order.h"
#include "objective/prediction.h"
#include "pk/objective.h"

namespace pk {

bool Objective::SecondDerivatives(const Eigen::VectorXd& values, const std::vector<int>& free,
                                  const std::vector<std::pair<int, int>>& pairs, std::vector<Eigen::VectorXd>* second,
                                  std::string* why) const {
  const internal::ObjectiveState& d = *impl_;
  // A linear model takes the block-triangular exponential whichever propagator predicts; a
  // nonlinear one the ODE propagator's forward second-order sensitivities (ode/second_order.h).
  const bool ode = d.linear == nullptr;
  const int m = d.model->num_parameters();
  for (const int i : free) {
    if (i < 0 || i >= m) {
      *why = "exact second derivatives are taken in model parameters only (not F, ALAG, R, D or σ)";
      return false;
    }
  }
  for (const int i : free) {
    const std::vector<int>& computed = d.layout.computed_reads();
    if (std::binary_search(computed.begin(), computed.end(), i)) {
      *why = "exact second derivatives do not follow a computed dose modifier (" + d.layout.name(i) +
             " is read by an F, ALAG, R, D or X0 of $PK, or by a zero-order input K0 of d/dt)";
      return false;
    }
  }
  for (const auto& ab : pairs) {
    const int p = static_cast<int>(free.size());
    if (ab.first < 0 || ab.first >= p || ab.second < 0 || ab.second >= p) {
      *why = "a pair names a position outside the free list";
      return false;
    }
  }
  const internal::FreeParameters fp(free, d.L());
  internal::PreparedSubject s = d.prepared;
  internal::RebindParameters(d.layout, values.head(d.L()), &s);
  try {
    if (ode) {
      internal::OdeSecondOrderSensitivities(d.ode, s, internal::DualSets(s, d.layout, fp), fp.num_model(), pairs, second);
    } else {
      internal::SecondOrderSensitivities(*d.linear, d.layout, s, internal::DualSets(s, d.layout, fp), fp.num_model(),
                                         pairs, d.options.modal_propagation, second);
    }
  } catch (const internal::NumericalFailure& e) {
    *why = e.what();
    return false;
  }
  for (const Eigen::VectorXd& v : *second) {
    if (!v.allFinite()) {
      *why = "a second derivative is not finite";
      return false;
    }
  }
  return true;
}

}  // namespace pk
