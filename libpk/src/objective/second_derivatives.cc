// Objective::SecondDerivatives and ThirdDerivatives: ∂²ŷ and ∂³ŷ from Φ/Γ's block-triangular
// exponential (exact/second_order.h, exact/third_order.h) or from the ODE propagator's
// sensitivities of the sensitivity system (ode/second_order.h), plus a linear model's output
// offsets (objective/output_offsets.h).
#include <algorithm>
#include <array>
#include <utility>

#include "exact/moving_events.h"
#include "exact/second_order.h"
#include "exact/third_order.h"
#include "numerical_failure.h"
#include "ode/moving_events.h"
#include "ode/second_order.h"
#include "objective/output_offsets.h"
#include "objective/prediction.h"
#include "pk/objective.h"

namespace pk {
namespace {

// Whether the higher derivatives can be taken in `free` (layout parameters); `why` otherwise.
// (*moves)[a] says whether free[a] moves a dose.
bool HigherOrderApplies(const internal::ObjectiveState& d, const std::vector<int>& free, std::vector<char>* moves,
                        std::string* why) {
  moves->assign(free.size(), 0);
  for (size_t a = 0; a < free.size(); ++a) {
    const int i = free[a];
    if (i < 0 || i >= d.L()) {
      *why = "exact higher derivatives are taken in the model's parameters and dose modifiers only (not σ)";
      return false;
    }
    (*moves)[a] = internal::MovesDoses(d, i) ? 1 : 0;
  }
  return true;
}

// The pairs' (triples') derivatives along which a dose moves: the event engine on jets, on Φ/Γ or
// with the ODEs (exact/ and ode/moving_events.h).
void MovingDoseDerivatives(const internal::ObjectiveState& d, const internal::PreparedSubject& s,
                           const std::vector<internal::DualVector>& sets, int num,
                           const std::vector<std::array<int, 3>>& directions, std::vector<Eigen::VectorXd>* out) {
  if (d.linear == nullptr) {
    internal::OdeMovingEventDerivatives(d.ode, s, sets, num, directions, out);
  } else {
    internal::MovingEventDerivatives(*d.linear, d.layout, s, sets, num, directions, out);
  }
}

std::array<int, 3> Directions(const std::pair<int, int>& pair) { return {pair.first, pair.second, -1}; }
std::array<int, 3> Directions(const std::array<int, 3>& triple) { return triple; }

// Runs `fixed` on the tuples (pairs or triples of free positions) none of whose directions moves a
// dose, the stacked systems' one pass for all of them, and `jets` (exact/moving_events.h, a pass
// each) on the others; *out in the tuples' order.
template <class Tuple, class Fixed, class Jets>
void SplitByMoving(const std::vector<Tuple>& tuples, const std::vector<char>& moves, const Fixed& fixed,
                   const Jets& jets, std::vector<Eigen::VectorXd>* out) {
  std::vector<Tuple> still;
  std::vector<std::array<int, 3>> moving;
  std::vector<long> where;  // ≥ 0: into still's results; < 0: −1 − the index into moving's
  for (const Tuple& t : tuples) {
    const std::array<int, 3> dir = Directions(t);
    bool m = false;
    for (int c : dir) m = m || (c >= 0 && moves[static_cast<size_t>(c)]);
    where.push_back(m ? -1 - static_cast<long>(moving.size()) : static_cast<long>(still.size()));
    if (m) {
      moving.push_back(dir);
    } else {
      still.push_back(t);
    }
  }
  std::vector<Eigen::VectorXd> a, b;
  if (!still.empty()) fixed(still, &a);
  if (!moving.empty()) jets(moving, &b);
  out->clear();
  for (long w : where) out->push_back(w >= 0 ? std::move(a[static_cast<size_t>(w)]) : std::move(b[static_cast<size_t>(-1 - w)]));
}

// The output offsets' part (objective/output_offsets.h), which every route above leaves out.
template <class Tuple>
void AddOffsetPart(const internal::ObjectiveState& d, const internal::PreparedSubject& s,
                   const std::vector<internal::DualVector>& sets, int num, const std::vector<Tuple>& tuples,
                   std::vector<Eigen::VectorXd>* out) {
  if (d.linear == nullptr || !d.linear->has_output_offsets()) return;
  std::vector<std::array<int, 3>> directions;
  for (const Tuple& t : tuples) directions.push_back(Directions(t));
  internal::AddOutputOffsetDerivatives(*d.linear, s, sets, num, directions, out);
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
  std::vector<char> moves;
  if (!HigherOrderApplies(d, free, &moves, why)) return false;
  const int p = static_cast<int>(free.size());
  for (const auto& ab : pairs) {
    if (ab.first < 0 || ab.first >= p || ab.second < 0 || ab.second >= p) {
      *why = "a pair names a position outside the free list";
      return false;
    }
  }
  // A linear model takes the block-triangular exponential whichever propagator predicts, and the
  // event engine on jets for pairs along which a dose moves (exact/moving_events.h); a nonlinear
  // one the ODE propagator's forward second-order sensitivities (ode/second_order.h).
  const auto route = [&](const internal::PreparedSubject& s, const std::vector<internal::DualVector>& sets, int num) {
    const auto fixed = [&](const std::vector<std::pair<int, int>>& still, std::vector<Eigen::VectorXd>* out) {
      if (d.linear == nullptr) {
        internal::OdeSecondOrderSensitivities(d.ode, s, sets, num, still, out);
      } else {
        internal::SecondOrderSensitivities(*d.linear, d.layout, s, sets, num, still, d.options.modal_propagation, out);
      }
    };
    const auto jets = [&](const std::vector<std::array<int, 3>>& moving, std::vector<Eigen::VectorXd>* out) {
      MovingDoseDerivatives(d, s, sets, num, moving, out);
    };
    SplitByMoving(pairs, moves, fixed, jets, second);
    AddOffsetPart(d, s, sets, num, pairs, second);
  };
  return RunHigherOrder(d, values, free, "second", route, *second, why);
}

bool Objective::ThirdDerivatives(const Eigen::VectorXd& values, const std::vector<int>& free,
                                 const std::vector<std::array<int, 3>>& triples, std::vector<Eigen::VectorXd>* third,
                                 std::string* why) const {
  const internal::ObjectiveState& d = *impl_;
  std::vector<char> moves;
  if (!HigherOrderApplies(d, free, &moves, why)) return false;
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
    const auto fixed = [&](const std::vector<std::array<int, 3>>& still, std::vector<Eigen::VectorXd>* out) {
      if (d.linear == nullptr) {
        internal::OdeThirdOrderSensitivities(d.ode, s, sets, num, still, out);
      } else {
        internal::ThirdOrderSensitivities(*d.linear, d.layout, s, sets, num, still, out);
      }
    };
    const auto jets = [&](const std::vector<std::array<int, 3>>& moving, std::vector<Eigen::VectorXd>* out) {
      MovingDoseDerivatives(d, s, sets, num, moving, out);
    };
    SplitByMoving(triples, moves, fixed, jets, third);
    AddOffsetPart(d, s, sets, num, triples, third);
  };
  return RunHigherOrder(d, values, free, "third", route, *third, why);
}

}  // namespace pk
