#include "second_order.h"

#include <map>

#include "../hyper_dual_number.h"
#include "exact_propagator.h"
#include "exact_routes.h"

namespace pk {
namespace internal {
namespace {

using HD = HyperDualNumber;

// [θ; ψ] of one parameter set with θ moving along free parameters k (ε₁) and l (ε₂).
std::vector<HD> Extended(const LinearModel& model, const DualVector& set, int num_free, int k, int l) {
  const int m = model.num_parameters();
  Eigen::VectorXd theta(m), u(m), v(m);
  for (int j = 0; j < m; ++j) {
    const Eigen::VectorXd d = Derivatives(set(j), num_free);
    theta(j) = set(j).value();
    u(j) = d(k);
    v(j) = d(l);
  }
  std::vector<HD> e;
  for (int j = 0; j < m; ++j) e.emplace_back(theta(j), u(j), v(j), 0.0);
  const DerivedCoefficients& derived = model.derived_coefficients();
  if (derived.count > 0) {
    Eigen::VectorXd psi, psi_u, psi_v, psi_uv;
    derived.evaluate_second(theta, u, v, &psi, &psi_u, &psi_v, &psi_uv);
    for (int q = 0; q < derived.count; ++q) e.emplace_back(psi(q), psi_u(q), psi_v(q), psi_uv(q));
  }
  return e;
}

// A matrix with its derivatives along k and l and its mixed second derivative.
struct Parts {
  Eigen::MatrixXd value, dk, dl, dkl;
  Parts(int rows, int cols)
      : value(Eigen::MatrixXd::Zero(rows, cols)), dk(value), dl(value), dkl(value) {}
};

// The sum of `terms` (LinearModel's) on the hyper-dual [θ; ψ]; an output row's terms go to row 0.
Parts Sum(const std::vector<LinearTerm>& terms, const std::vector<HD>& e, int rows, int cols) {
  Parts p(rows, cols);
  const auto theta = [&](int i) { return e[static_cast<size_t>(i)]; };
  for (const LinearTerm& t : terms) {
    const HD x = LinearModel::TermValue<HD>(t, theta);
    const int r = rows == 1 ? 0 : t.row;
    p.value(r, t.col) += x.value();
    p.dk(r, t.col) += x.e1();
    p.dl(r, t.col) += x.e2();
    p.dkl(r, t.col) += x.e12();
  }
  return p;
}

// M of second_order.h over z = [x; s_k; s_l; w].
Eigen::MatrixXd Augmented(const Parts& a) {
  const auto n = a.value.rows();
  Eigen::MatrixXd m = Eigen::MatrixXd::Zero(4 * n, 4 * n);
  for (int b = 0; b < 4; ++b) m.block(b * n, b * n, n, n) = a.value;
  m.block(n, 0, n, n) = a.dk;
  m.block(2 * n, 0, n, n) = a.dl;
  m.block(3 * n, 0, n, n) = a.dkl;
  m.block(3 * n, n, n, n) = a.dl;      // A_l s_k
  m.block(3 * n, 2 * n, n, n) = a.dk;  // A_k s_l
  return m;
}

// The event engine's visitor: z through M, and ∂²ŷ at the samples.
class SecondOrderVisitor {
 public:
  SecondOrderVisitor(const LinearModel& model, const PreparedSubject& s, const std::vector<DualVector>& sets,
                     int num_free, int k, int l, Eigen::VectorXd* out)
      : model_(model), s_(s), n_(model.num_compartments()), extended_(AllExtended(model, sets, num_free, k, l)),
        prop_(Matrices(model, extended_), n_), out_(out) {
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
      it = outputs_.emplace(std::make_pair(set, cmt), Sum(model_.output_terms(cmt), extended_[static_cast<size_t>(set)], 1, n_))
               .first;
    }
    const Parts& c = it->second;
    const Eigen::VectorXd& z = prop_.state();
    (*out_)(k) = c.value.row(0).dot(z.segment(3 * n_, n_)) + c.dk.row(0).dot(z.segment(2 * n_, n_)) +
                 c.dl.row(0).dot(z.segment(n_, n_)) + c.dkl.row(0).dot(z.head(n_));
  }

 private:
  static std::vector<std::vector<HD>> AllExtended(const LinearModel& model, const std::vector<DualVector>& sets,
                                                  int num_free, int k, int l) {
    std::vector<std::vector<HD>> e;
    for (const DualVector& set : sets) e.push_back(Extended(model, set, num_free, k, l));
    return e;
  }
  static std::vector<Eigen::MatrixXd> Matrices(const LinearModel& model, const std::vector<std::vector<HD>>& extended) {
    const int n = model.num_compartments();
    std::vector<Eigen::MatrixXd> m;
    for (const std::vector<HD>& e : extended) m.push_back(Augmented(Sum(model.system_terms(), e, n, n)));
    return m;
  }

  const LinearModel& model_;
  const PreparedSubject& s_;
  const int n_;
  const std::vector<std::vector<HD>> extended_;  // per set: [θ; ψ] along k and l
  ExactPropagator prop_;
  Eigen::VectorXd* out_;
  std::vector<int> sample_;
  std::map<std::pair<int, int>, Parts> outputs_;  // (set, cmt) → C and its derivatives
};

}  // namespace

void SecondOrderSensitivities(const LinearModel& model, const ParameterLayout& layout, const PreparedSubject& subject,
                              const std::vector<DualVector>& sets, int num_free,
                              const std::vector<std::pair<int, int>>& pairs, std::vector<Eigen::VectorXd>* out) {
  out->assign(pairs.size(), Eigen::VectorXd());
  for (size_t i = 0; i < pairs.size(); ++i) {
    SecondOrderVisitor visitor(model, subject, sets, num_free, pairs[i].first, pairs[i].second, &(*out)[i]);
    EventEngine<double, SecondOrderVisitor> engine(subject, layout, subject.sets, &visitor);
    engine.Run();
  }
}

}  // namespace internal
}  // namespace pk
