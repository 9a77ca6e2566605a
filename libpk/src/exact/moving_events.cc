// Higher-order sensitivities when the events move with p: the event engine and the state on
// HyperDual3 jets (moving_events.h).
#include "moving_events.h"

#include <map>
#include <utility>

#include <Eigen/LU>

#include "../hyper_dual_sets.h"
#include "../numerical_failure.h"
#include "exact_routes.h"
#include "jet_exponential.h"
#include "third_order.h"
#include "pk/hyper_dual.h"

namespace pk {
namespace internal {
namespace {

using HD3 = HyperDual3;
using HD3Vector = HyperDual3Vector;

// HyperDual3's product on the subsets of its first `d` directions: e_S e_T = e_{S∪T} when S and T
// are disjoint, 0 otherwise.
JetProducts SubsetAlgebra(int d) {
  JetProducts algebra;
  algebra.parts = 1 << d;
  for (int s = 0; s < algebra.parts; ++s) {
    for (int t = 0; t < algebra.parts; ++t) {
      if ((s & t) == 0) algebra.entries.push_back({s | t, s, t});
    }
  }
  return algebra;
}

// [θ; ψ] of one set: the model parameters and the derived coefficients the terms read.
std::vector<HD3> Extended(const LinearModel& model, const HD3Vector& set) {
  return ExtendedThird(model, std::vector<HD3>(set.data(), set.data() + model.num_parameters()));
}

// Σ `terms` as a jet of rows × cols parts; an output row's terms go to row 0.
Jet TermsJet(const std::vector<LinearTerm>& terms, const std::vector<HD3>& e, int parts, int rows, int cols) {
  Jet j(static_cast<size_t>(parts), Eigen::MatrixXd::Zero(rows, cols));
  for (const LinearTerm& t : terms) {
    const HD3 x = LinearModel::TermValue<HD3>(t, [&](int i) { return e[static_cast<size_t>(i)]; });
    for (int s = 0; s < parts; ++s) j[static_cast<size_t>(s)](rows == 1 ? 0 : t.row, t.col) += x.part(s);
  }
  return j;
}

// The jet product XY.
Jet Product(const JetProducts& algebra, const Jet& x, const Jet& y) {
  Jet z(x.size(), Eigen::MatrixXd::Zero(x[0].rows(), y[0].cols()));
  for (const auto& [t, a, b] : algebra.entries) {
    z[static_cast<size_t>(t)].noalias() += x[static_cast<size_t>(a)] * y[static_cast<size_t>(b)];
  }
  return z;
}

// The event engine's visitor: the state as a jet, n × parts (column S the part of ε^S).
class MovingEventVisitor {
 public:
  MovingEventVisitor(const LinearModel& model, const PreparedSubject& s, const std::vector<HD3Vector>& sets,
                     const JetProducts& algebra, Eigen::VectorXd* out)
      : model_(model), s_(s), n_(model.num_compartments()), algebra_(algebra), out_(out) {
    for (const HD3Vector& set : sets) {
      extended_.push_back(Extended(model, set));
      a_.push_back(TermsJet(model.system_terms(), extended_.back(), algebra.parts, n_, n_));
    }
    int count = 0;
    sample_ = SampleIndex(s, &count);
    out->setZero(count);
    x_.setZero(n_, algebra.parts);
    cache_.reserve(kCacheCapacity);
  }

  void Advance(const HD3& h, const HD3Vector& u, int set) {
    Apply(Step(h, u, set), x_, &next_);
    x_.swap(next_);
  }
  void Bolus(int cmt, const HD3& amount, int) {
    for (int s = 0; s < algebra_.parts; ++s) x_(cmt, s) += amount.part(s);
  }
  void Reset() { x_.setZero(); }
  void DoseEntered(const HD3&, int) {}
  void SteadyState(const SteadyStateCycle<HD3>& cycle, int set, bool add);
  void SteadyInfusion(const HD3Vector& u, int set, bool add);
  void RecordDone(int r, int set);

 private:
  // *next = E [x; 1] for the jet [x; 1] (the 1 has the unit's part only).
  void Apply(const Jet& e, const Eigen::MatrixXd& x, Eigen::MatrixXd* next) const {
    next->resize(n_, algebra_.parts);
    for (int t = 0; t < algebra_.parts; ++t) next->col(t) = e[static_cast<size_t>(t)].topRightCorner(n_, 1);
    for (const auto& [t, a, b] : algebra_.entries) {
      next->col(t).noalias() += e[static_cast<size_t>(a)].topLeftCorner(n_, n_) * x.col(b);
    }
  }
  // The augmented map of a bolus into `cmt`: [x; 1] ↦ [x + b e_cmt; 1].
  Jet BolusMap(int cmt, const HD3& bolus) const {
    Jet j(static_cast<size_t>(algebra_.parts), Eigen::MatrixXd::Zero(n_ + 1, n_ + 1));
    j[0].setIdentity();
    for (int s = 0; s < algebra_.parts; ++s) j[static_cast<size_t>(s)](cmt, n_) += bolus.part(s);
    return j;
  }
  const Jet& Step(const HD3& h, const HD3Vector& u, int set);
  // Solves L x_S = r_S − Σ_{T ⊊ S} K_{S∖T} x_T for every part S, K the jet with its unit part L.
  Eigen::MatrixXd SolveInParts(const Jet& k, const Eigen::MatrixXd& r, const Eigen::MatrixXd& l,
                               const char* singular) const;

  static constexpr size_t kCacheCapacity = 32;
  struct CachedStep {
    Eigen::VectorXd key;  // the set, h's parts and u's parts
    Jet e;
  };

  const LinearModel& model_;
  const PreparedSubject& s_;
  const int n_;
  const JetProducts& algebra_;
  Eigen::VectorXd* out_;
  std::vector<std::vector<HD3>> extended_;  // per set
  std::vector<Jet> a_;                      // per set: A as a jet
  std::vector<int> sample_;
  std::map<std::pair<int, int>, Jet> outputs_;  // (set, cmt) → C as a jet
  std::vector<CachedStep> cache_;
  size_t next_evicted_ = 0;
  Eigen::VectorXd key_;  // Step's scratch: the key sought, and the augmented matrix
  Jet m_;
  Eigen::MatrixXd x_, next_;
};

// exp(h [[A, u], [0, 0]]) in the algebra, cached by exact (set, h, u): the steps between samples
// of one subject mostly repeat.
const Jet& MovingEventVisitor::Step(const HD3& h, const HD3Vector& u, int set) {
  const int parts = algebra_.parts;
  key_.resize(1 + parts * (1 + n_));
  key_(0) = set;
  for (int s = 0; s < parts; ++s) {
    key_(1 + s) = h.part(s);
    for (int c = 0; c < n_; ++c) key_(1 + parts + s * n_ + c) = u(c).part(s);
  }
  for (const CachedStep& c : cache_) {
    if (c.key.size() == key_.size() && (c.key.array() == key_.array()).all()) return c.e;
  }
  CachedStep* slot = nullptr;
  if (cache_.size() < kCacheCapacity) {
    cache_.emplace_back();  // reserved: the references handed out stay valid
    slot = &cache_.back();
  } else {
    slot = &cache_[next_evicted_];
    next_evicted_ = (next_evicted_ + 1) % kCacheCapacity;
  }
  slot->key.resize(0);  // no key until its exponential is in place (JetExponential may throw)
  m_.resize(static_cast<size_t>(parts));
  Jet& e = slot->e;
  e.resize(static_cast<size_t>(parts));
  for (int s = 0; s < parts; ++s) {
    Eigen::MatrixXd& m = m_[static_cast<size_t>(s)];
    m.setZero(n_ + 1, n_ + 1);
    m.topLeftCorner(n_, n_) = a_[static_cast<size_t>(set)][static_cast<size_t>(s)];
    for (int c = 0; c < n_; ++c) m(c, n_) = u(c).part(s);
    e[static_cast<size_t>(s)].setZero(n_ + 1, n_ + 1);
  }
  for (const auto& [t, a, b] : algebra_.entries) {
    if (h.part(b) != 0) e[static_cast<size_t>(t)] += m_[static_cast<size_t>(a)] * h.part(b);
  }
  JetExponential(algebra_, &e);
  slot->key = key_;
  return e;
}

Eigen::MatrixXd MovingEventVisitor::SolveInParts(const Jet& k, const Eigen::MatrixXd& r, const Eigen::MatrixXd& l,
                                                 const char* singular) const {
  const Eigen::PartialPivLU<Eigen::MatrixXd> lu(l);
  if (!(lu.rcond() > 1e-13)) throw NumericalFailure(singular);
  Eigen::MatrixXd x(n_, algebra_.parts);
  // A part's terms read parts of fewer directions only, so ascending masks have them ready.
  for (int s = 0; s < algebra_.parts; ++s) {
    Eigen::VectorXd rhs = r.col(s);
    for (const auto& [t, a, b] : algebra_.entries) {
      if (t == s && a != 0) rhs -= k[static_cast<size_t>(a)].topLeftCorner(n_, n_) * x.col(b);
    }
    x.col(s) = lu.solve(rhs);
  }
  return x;
}

void MovingEventVisitor::SteadyState(const SteadyStateCycle<HD3>& cycle, int set, bool add) {
  // One dosing interval, [x; 1] ↦ P [x; 1]: the bolus, then the period's segments.
  Jet p = BolusMap(cycle.cmt, cycle.bolus);
  for (const Segment<HD3>& segment : cycle.period) p = Product(algebra_, Step(segment.duration, segment.rate, set), p);
  // x* = P_xx x* + P_x1, i.e. (I − P_xx) x* = P_x1, solved part by part with K = −P_xx off the unit.
  Jet k(p.size());
  Eigen::MatrixXd r(n_, algebra_.parts);
  for (int s = 0; s < algebra_.parts; ++s) {
    k[static_cast<size_t>(s)] = -p[static_cast<size_t>(s)];
    r.col(s) = p[static_cast<size_t>(s)].topRightCorner(n_, 1);
  }
  const Eigen::MatrixXd l = Eigen::MatrixXd::Identity(n_, n_) - p[0].topLeftCorner(n_, n_);
  const Eigen::MatrixXd x_star = SolveInParts(k, r, l,
                                              "no steady state: the dosing-interval map has an eigenvalue at 1 (is "
                                              "drug eliminated from every compartment it reaches?)");
  Jet to_record = BolusMap(cycle.cmt, cycle.bolus);
  for (const Segment<HD3>& segment : cycle.to_record) {
    to_record = Product(algebra_, Step(segment.duration, segment.rate, set), to_record);
  }
  Apply(to_record, x_star, &next_);
  x_ = add ? Eigen::MatrixXd(x_ + next_) : next_;
}

void MovingEventVisitor::SteadyInfusion(const HD3Vector& u, int set, bool add) {
  // 0 = A x + u, part by part.
  const Jet& a = a_[static_cast<size_t>(set)];
  Eigen::MatrixXd r(n_, algebra_.parts);
  for (int s = 0; s < algebra_.parts; ++s) {
    for (int c = 0; c < n_; ++c) r(c, s) = -u(c).part(s);
  }
  const Eigen::MatrixXd x =
      SolveInParts(a, r, a[0], "no steady state for a constant infusion: some compartment has no elimination");
  x_ = add ? Eigen::MatrixXd(x_ + x) : x;
}

void MovingEventVisitor::RecordDone(int r, int set) {
  const int k = sample_[static_cast<size_t>(r)];
  if (k < 0) return;
  const int cmt = s_.cmt[static_cast<size_t>(r)] + 1;
  auto it = outputs_.find({set, cmt});
  if (it == outputs_.end()) {
    Jet c = TermsJet(model_.output_terms(cmt), extended_[static_cast<size_t>(set)], algebra_.parts, 1, n_);
    it = outputs_.emplace(std::make_pair(set, cmt), std::move(c)).first;
  }
  const int all = algebra_.parts - 1;  // every direction's part: the mixed derivative
  double y = 0;
  for (const auto& [t, a, b] : algebra_.entries) {
    if (t == all) y += it->second[static_cast<size_t>(a)].row(0).dot(x_.col(b));
  }
  (*out_)(k) = y;
}

}  // namespace

void MovingEventDerivatives(const LinearModel& model, const ParameterLayout& layout, const PreparedSubject& subject,
                            const std::vector<DualVector>& sets, int num_free,
                            const std::vector<std::array<int, 3>>& directions, std::vector<Eigen::VectorXd>* out) {
  const JetProducts pairs = SubsetAlgebra(2), triples = SubsetAlgebra(3);
  out->clear();
  for (const std::array<int, 3>& dir : directions) {
    for (int i : dir) {
      if (i >= num_free) throw NumericalFailure("a direction names no free parameter");
    }
    std::vector<HD3Vector> seeded;
    for (const DualVector& set : sets) seeded.push_back(SeedAlong(layout, set, dir));
    Eigen::VectorXd y;
    MovingEventVisitor visitor(model, subject, seeded, JetParts(dir) == 4 ? pairs : triples, &y);
    EventEngine<HD3, MovingEventVisitor> engine(subject, layout, seeded, &visitor);
    engine.Run();
    out->push_back(std::move(y));
  }
}

}  // namespace internal
}  // namespace pk
