// Third-order sensitivities on Φ/Γ: the stacked system of third_order.h through the event engine.
#include "third_order.h"

#include <map>
#include <utility>

#include "../numerical_failure.h"
#include "exact_propagator.h"
#include "exact_routes.h"
#include "pk/hyper_dual.h"

namespace pk {
namespace internal {
namespace {

constexpr int kParts = 8;  // the subsets of three directions

// [θ; ψ] of one parameter set on HyperDual3, θ moving along the free parameters of `triple`.
std::vector<HyperDual3> Extended(const LinearModel& model, const DualVector& set, int num_free,
                                 const std::array<int, 3>& triple) {
  const int m = model.num_parameters();
  Eigen::VectorXd theta(m);
  Eigen::MatrixXd directions(m, 3);
  for (int j = 0; j < m; ++j) {
    const Eigen::VectorXd d = Derivatives(set(j), num_free);
    theta(j) = set(j).value();
    for (int c = 0; c < 3; ++c) directions(j, c) = d(triple[static_cast<size_t>(c)]);
  }
  std::vector<HyperDual3> e;
  for (int j = 0; j < m; ++j) {
    HyperDual3 t(theta(j));
    for (int c = 0; c < 3; ++c) t.part(1 << c) = directions(j, c);  // θ is linear in p: no mixed parts
    e.push_back(t);
  }
  const DerivedCoefficients& derived = model.derived_coefficients();
  if (derived.count > 0) {
    if (!derived.evaluate_third) throw NumericalFailure("the model's derived coefficients have no third order");
    std::vector<Eigen::VectorXd> parts;
    derived.evaluate_third(theta, directions, &parts);
    for (int q = 0; q < derived.count; ++q) {
      HyperDual3 psi;
      for (int s = 0; s < kParts; ++s) psi.part(s) = parts[static_cast<size_t>(s)](q);
      e.push_back(psi);
    }
  }
  return e;
}

// A matrix's parts: its mixed derivative along each subset of the three directions.
using Parts = std::array<Eigen::MatrixXd, kParts>;

// The sum of `terms` (LinearModel's) on the extended [θ; ψ]; an output row's terms go to row 0.
Parts Sum(const std::vector<LinearTerm>& terms, const std::vector<HyperDual3>& e, int rows, int cols) {
  Parts p;
  for (Eigen::MatrixXd& m : p) m = Eigen::MatrixXd::Zero(rows, cols);
  const auto theta = [&](int i) { return e[static_cast<size_t>(i)]; };
  for (const LinearTerm& t : terms) {
    const HyperDual3 x = LinearModel::TermValue<HyperDual3>(t, theta);
    const int r = rows == 1 ? 0 : t.row;
    for (int s = 0; s < kParts; ++s) p[static_cast<size_t>(s)](r, t.col) += x.part(s);
  }
  return p;
}

// M of third_order.h over z = [x_0; …; x_7]: block (S, T) = A_{S∖T} for T ⊆ S.
Eigen::MatrixXd Augmented(const Parts& a) {
  const auto n = a[0].rows();
  Eigen::MatrixXd m = Eigen::MatrixXd::Zero(kParts * n, kParts * n);
  for (int s = 0; s < kParts; ++s) {
    for (int t = s;; t = (t - 1) & s) {
      m.block(s * n, t * n, n, n) = a[static_cast<size_t>(s & ~t)];
      if (t == 0) break;
    }
  }
  return m;
}

// The event engine's visitor: z through M, and ∂³ŷ at the samples. M's exponentials are the jet's
// (jet_exponential.h) from two states up; for one state the dense 8×8 exponential costs less than
// the jet's bookkeeping (phenobarbital's Laplace fit: 87 against 97 ms; theophylline's, two states:
// 161 against 236 ms the other way).
class ThirdOrderVisitor {
 public:
  ThirdOrderVisitor(const LinearModel& model, const PreparedSubject& s, const std::vector<DualVector>& sets,
                    int num_free, const std::array<int, 3>& triple, Eigen::VectorXd* out)
      : model_(model), s_(s), n_(model.num_compartments()), extended_(AllExtended(model, sets, num_free, triple)),
        prop_(Matrices(model, extended_), n_, n_ >= 2 ? kParts : 0), out_(out) {
    int count = 0;
    sample_ = SampleIndex(s, &count);
    out->setZero(count);
  }
  void Advance(double h, const Eigen::VectorXd& u, int set) { prop_.Advance(h, u, set); }
  void Bolus(int cmt, double amount, int set) { prop_.Bolus(cmt, amount, set); }
  void Reset() { prop_.Reset(); }
  void SteadyState(const SteadyStateCycle<double>& c, int set, bool add) { prop_.SteadyState(c, set, add); }
  void SteadyInfusion(const Eigen::VectorXd& u, int set, bool add) { prop_.SteadyInfusion(u, set, add); }
  void DoseEntered(double, int) {}
  void RecordDone(int r, int set) {
    const int k = sample_[static_cast<size_t>(r)];
    if (k < 0) return;
    const int cmt = s_.cmt[static_cast<size_t>(r)] + 1;
    auto it = outputs_.find({set, cmt});
    if (it == outputs_.end()) {
      const Parts c = Sum(model_.output_terms(cmt), extended_[static_cast<size_t>(set)], 1, n_);
      it = outputs_.emplace(std::make_pair(set, cmt), c).first;
    }
    const Parts& c = it->second;
    const Eigen::VectorXd& z = prop_.state();
    double y = 0;
    for (int t = kParts - 1;; t = (t - 1) & (kParts - 1)) {
      y += c[static_cast<size_t>((kParts - 1) & ~t)].row(0).dot(z.segment(t * n_, n_));
      if (t == 0) break;
    }
    (*out_)(k) = y;
  }

 private:
  static std::vector<std::vector<HyperDual3>> AllExtended(const LinearModel& model, const std::vector<DualVector>& sets,
                                                          int num_free, const std::array<int, 3>& triple) {
    std::vector<std::vector<HyperDual3>> e;
    for (const DualVector& set : sets) e.push_back(Extended(model, set, num_free, triple));
    return e;
  }
  static std::vector<Eigen::MatrixXd> Matrices(const LinearModel& model,
                                               const std::vector<std::vector<HyperDual3>>& extended) {
    const int n = model.num_compartments();
    std::vector<Eigen::MatrixXd> m;
    for (const std::vector<HyperDual3>& e : extended) m.push_back(Augmented(Sum(model.system_terms(), e, n, n)));
    return m;
  }

  const LinearModel& model_;
  const PreparedSubject& s_;
  const int n_;
  const std::vector<std::vector<HyperDual3>> extended_;  // per set: [θ; ψ] along the triple
  ExactPropagator prop_;
  Eigen::VectorXd* out_;
  std::vector<int> sample_;
  std::map<std::pair<int, int>, Parts> outputs_;  // (set, cmt) → C and its parts
};

}  // namespace

void ThirdOrderSensitivities(const LinearModel& model, const ParameterLayout& layout, const PreparedSubject& subject,
                             const std::vector<DualVector>& sets, int num_free,
                             const std::vector<std::array<int, 3>>& triples, std::vector<Eigen::VectorXd>* out) {
  out->assign(triples.size(), Eigen::VectorXd());
  for (size_t i = 0; i < triples.size(); ++i) {
    ThirdOrderVisitor visitor(model, subject, sets, num_free, triples[i], &(*out)[i]);
    EventEngine<double, ThirdOrderVisitor> engine(subject, layout, subject.sets, &visitor);
    engine.Run();
  }
}

}  // namespace internal
}  // namespace pk
