// Objective::SecondDerivatives and ThirdDerivatives: ∂²ŷ and ∂³ŷ from Φ/Γ's block-triangular
// exponential (exact/second_order.h, exact/third_order.h) or from the ODE propagator's
// sensitivities of the sensitivity system (ode/second_order.h).
#include <algorithm>

#include "exact/moving_events.h"
#include "exact/second_order.h"
#include "exact/third_order.h"
#include "numerical_failure.h"
#include "ode/second_order.h"
#include "objective/prediction.h"
#include "pk/objective.h"

namespace pk {
namespace {

// Whether a free parameter moves an event: a dose modifier itself, or a parameter a computed
// modifier reads.
bool MovesEvents(const internal::ObjectiveState& d, int i) {
  const std::vector<int>& computed = d.layout.computed_reads();
  return i >= d.model->num_parameters() || std::binary_search(computed.begin(), computed.end(), i);
}

// Whether the higher derivatives can be taken in `free` (layout parameters; on the ODE propagator,
// none that moves an event); `why` otherwise. *moving says whether some free parameter moves one.
bool HigherOrderApplies(const internal::ObjectiveState& d, const std::vector<int>& free, bool* moving,
                        std::string* why) {
  *moving = false;
  for (const int i : free) {
    if (i < 0 || i >= d.L()) {
      *why = "exact higher derivatives are taken in the model's parameters and dose modifiers only (not σ)";
      return false;
    }
    if (!MovesEvents(d, i)) continue;
    *moving = true;
    if (d.linear == nullptr) {
      *why = "exact higher derivatives on the ODE propagator do not follow a moving dose (" + d.layout.name(i) +
             (i < d.model->num_parameters()
                  ? " is read by a computed dose modifier: an F, ALAG, R, D or X0 of $PK, or a zero-order input K0 of d/dt)"
                  : " is a dose modifier)");
      return false;
    }
  }
  return true;
}

bool AllFinite(const std::vector<Eigen::VectorXd>& out, const char* order, std::string* why) {
  for (const Eigen::VectorXd& v : out) {
    if (!v.allFinite()) {
      *why = std::string("a ") + order + " derivative is not finite";
      return false;
    }
  }
  return true;
}

// Binds `values` to the subject, runs `route(subject, sets, num_model)` (which fills *out) and checks
// what it wrote: false with `why` on a numerical failure or a value that is not finite.
template <class Route>
bool RunHigherOrder(const internal::ObjectiveState& d, const Eigen::VectorXd& values, const std::vector<int>& free,
                    const char* order, const Route& route, const std::vector<Eigen::VectorXd>& out, std::string* why) {
  const internal::FreeParameters fp(free, d.L());
  internal::PreparedSubject s = d.prepared;
  internal::RebindParameters(d.layout, values.head(d.L()), &s);
  try {
    route(s, internal::DualSets(s, d.layout, fp), fp.num_model());
  } catch (const internal::NumericalFailure& e) {
    *why = e.what();
    return false;
  }
  return AllFinite(out, order, why);
}

}  // namespace

bool Objective::SecondDerivatives(const Eigen::VectorXd& values, const std::vector<int>& free,
                                  const std::vector<std::pair<int, int>>& pairs, std::vector<Eigen::VectorXd>* second,
                                  std::string* why) const {
  const internal::ObjectiveState& d = *impl_;
  bool moving = false;
  if (!HigherOrderApplies(d, free, &moving, why)) return false;
  const int p = static_cast<int>(free.size());
  for (const auto& ab : pairs) {
    if (ab.first < 0 || ab.first >= p || ab.second < 0 || ab.second >= p) {
      *why = "a pair names a position outside the free list";
      return false;
    }
  }
  // A linear model takes the block-triangular exponential whichever propagator predicts, or the
  // event engine on jets when a dose moves (exact/moving_events.h); a nonlinear one the ODE
  // propagator's forward second-order sensitivities (ode/second_order.h).
  const auto route = [&](const internal::PreparedSubject& s, const std::vector<internal::DualVector>& sets, int num) {
    if (d.linear == nullptr) {
      internal::OdeSecondOrderSensitivities(d.ode, s, sets, num, pairs, second);
    } else if (moving) {
      std::vector<std::array<int, 3>> directions;
      for (const auto& [k, l] : pairs) directions.push_back({k, l, -1});
      internal::MovingEventDerivatives(*d.linear, d.layout, s, sets, num, directions, second);
    } else {
      internal::SecondOrderSensitivities(*d.linear, d.layout, s, sets, num, pairs, d.options.modal_propagation, second);
    }
  };
  return RunHigherOrder(d, values, free, "second", route, *second, why);
}

bool Objective::ThirdDerivatives(const Eigen::VectorXd& values, const std::vector<int>& free,
                                 const std::vector<std::array<int, 3>>& triples, std::vector<Eigen::VectorXd>* third,
                                 std::string* why) const {
  const internal::ObjectiveState& d = *impl_;
  bool moving = false;
  if (!HigherOrderApplies(d, free, &moving, why)) return false;
  const int p = static_cast<int>(free.size());
  for (const auto& t : triples) {
    for (int i : t) {
      if (i < 0 || i >= p) {
        *why = "a triple names a position outside the free list";
        return false;
      }
    }
  }
  const auto route = [&](const internal::PreparedSubject& s, const std::vector<internal::DualVector>& sets, int num) {
    if (d.linear == nullptr) {
      internal::OdeThirdOrderSensitivities(d.ode, s, sets, num, triples, third);
    } else if (moving) {
      internal::MovingEventDerivatives(*d.linear, d.layout, s, sets, num, triples, third);
    } else {
      internal::ThirdOrderSensitivities(*d.linear, d.layout, s, sets, num, triples, third);
    }
  };
  return RunHigherOrder(d, values, free, "third", route, *third, why);
}

}  // namespace pk
