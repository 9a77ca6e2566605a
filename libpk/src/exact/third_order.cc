// Third-order sensitivities on Φ/Γ: the state's truncated Taylor series in the free parameters
// (third_order.h) through the event engine, one pass for every triple asked for.
#include "third_order.h"

#include <algorithm>
#include <map>
#include <memory>
#include <set>
#include <utility>

#include "../numerical_failure.h"
#include "exact_propagator.h"
#include "exact_routes.h"
#include "jet_exponential.h"
#include "pk/hyper_dual.h"

namespace pk {
namespace internal {
namespace {

using Monomial = std::vector<int>;  // its variables, sorted, with repeats: {0, 0, 2} is p₀²p₂

// The monomials the requested triples need, with every monomial that divides one of them (the set
// the recursion x_γ' = Σ_{α+β=γ} A_α x_β closes over), and the truncated series' products on them.
// Only those: with 2 η among 8 parameters, 46 monomials instead of the 165 of degree ≤ 3.
struct TaylorAlgebra {
  std::vector<Monomial> monomials;
  std::map<Monomial, int> index;
  std::shared_ptr<JetProducts> products = std::make_shared<JetProducts>();
  std::vector<int> cubes;  // the monomials of degree 3: every other one divides one of them
  std::vector<std::array<int, 3>> cube_entries;  // the products' entries into them (the samples read only these)

  explicit TaylorAlgebra(const std::vector<std::array<int, 3>>& triples) {
    std::set<Monomial> closure;
    for (const auto& triple : triples) {
      Monomial m(triple.begin(), triple.end());
      std::sort(m.begin(), m.end());
      for (int s = 0; s < 8; ++s) {  // its divisors: the sub-multisets
        Monomial d;
        for (int k = 0; k < 3; ++k) {
          if (s & (1 << k)) d.push_back(m[static_cast<size_t>(k)]);
        }
        closure.insert(d);
      }
    }
    std::vector<Monomial> by_degree(closure.begin(), closure.end());
    std::stable_sort(by_degree.begin(), by_degree.end(),
                     [](const Monomial& a, const Monomial& b) { return a.size() < b.size(); });
    for (const Monomial& m : by_degree) Add(m);  // the unit first
    products->parts = static_cast<int>(monomials.size());
    for (size_t a = 0; a < monomials.size(); ++a) {
      for (size_t b = 0; b < monomials.size(); ++b) {
        if (monomials[a].size() + monomials[b].size() > 3) continue;
        Monomial t = monomials[a];
        t.insert(t.end(), monomials[b].begin(), monomials[b].end());
        std::sort(t.begin(), t.end());
        const auto it = index.find(t);
        if (it == index.end()) continue;
        products->entries.push_back({it->second, static_cast<int>(a), static_cast<int>(b)});
        if (t.size() == 3) cube_entries.push_back(products->entries.back());
      }
    }
    for (size_t k = 0; k < monomials.size(); ++k) {
      if (monomials[k].size() == 3) cubes.push_back(static_cast<int>(k));
    }
  }
  void Add(const Monomial& m) {
    index.emplace(m, static_cast<int>(monomials.size()));
    monomials.push_back(m);
  }
  // α! for a monomial: the product of its variables' multiplicities' factorials.
  static double Factorial(const Monomial& m) {
    double f = 1;
    for (size_t i = 0, run = 1; i < m.size(); ++i) {
      run = i > 0 && m[i] == m[i - 1] ? run + 1 : 1;
      f *= static_cast<double>(run);
    }
    return f;
  }
};

// [θ; ψ] of one parameter set on HyperDual3, θ moving along free parameters i, j, k.
std::vector<HyperDual3> Extended(const LinearModel& model, const DualVector& set, int num_free, const Monomial& ijk) {
  std::vector<HyperDual3> theta;
  for (int j = 0; j < model.num_parameters(); ++j) {
    const Eigen::VectorXd d = Derivatives(set(j), num_free);
    HyperDual3 t(set(j).value());
    for (int c = 0; c < 3; ++c) t.part(1 << c) = d(ijk[static_cast<size_t>(c)]);  // θ is linear in p: no mixed parts
    theta.push_back(t);
  }
  return ExtendedThird(model, std::move(theta));
}

// [θ; ψ] of one parameter set along each of the algebra's monomials of degree 3 (`cubes`).
using ExtendedSet = std::vector<std::vector<HyperDual3>>;

ExtendedSet ExtendedAlongCubes(const LinearModel& model, const DualVector& set, int num_free,
                               const TaylorAlgebra& algebra) {
  ExtendedSet e;
  for (int k : algebra.cubes) e.push_back(Extended(model, set, num_free, algebra.monomials[static_cast<size_t>(k)]));
  return e;
}

// The Taylor coefficients ∂^α M/α! of Σ `terms` (LinearModel's) in the free parameters, one matrix
// per monomial; an output row's terms go to row 0. Each monomial of degree 3, {i, j, k}, is one
// evaluation on HyperDual3 along i, j, k (`extended`), whose eight parts are the coefficients of
// every monomial it divides (a monomial met twice gets the same value twice).
std::vector<Eigen::MatrixXd> Coefficients(const std::vector<LinearTerm>& terms, const ExtendedSet& extended,
                                          const TaylorAlgebra& algebra, int rows, int cols) {
  std::vector<Eigen::MatrixXd> c(algebra.monomials.size(), Eigen::MatrixXd::Zero(rows, cols));
  for (size_t q = 0; q < algebra.cubes.size(); ++q) {
    const Monomial& ijk = algebra.monomials[static_cast<size_t>(algebra.cubes[q])];
    const std::vector<HyperDual3>& e = extended[q];
    const auto theta = [&](int i) { return e[static_cast<size_t>(i)]; };
    std::array<Eigen::MatrixXd, 8> parts;
    for (Eigen::MatrixXd& part : parts) part = Eigen::MatrixXd::Zero(rows, cols);
    for (const LinearTerm& t : terms) {
      const HyperDual3 x = LinearModel::TermValue<HyperDual3>(t, theta);
      for (int s = 0; s < 8; ++s) parts[static_cast<size_t>(s)](rows == 1 ? 0 : t.row, t.col) += x.part(s);
    }
    for (int s = 0; s < 8; ++s) {
      Monomial m;
      for (int d = 0; d < 3; ++d) {
        if (s & (1 << d)) m.push_back(ijk[static_cast<size_t>(d)]);
      }
      c[static_cast<size_t>(algebra.index.at(m))] = parts[static_cast<size_t>(s)] / TaylorAlgebra::Factorial(m);
    }
  }
  return c;
}

// M of third_order.h: block (t, b) = A_a for each of the algebra's entries (t, a, b).
Eigen::MatrixXd Stacked(const std::vector<Eigen::MatrixXd>& a, const JetProducts& products) {
  const auto n = a.front().rows();
  const auto size = products.parts * n;
  Eigen::MatrixXd m = Eigen::MatrixXd::Zero(size, size);
  for (const auto& [t, k, b] : products.entries) m.block(t * n, b * n, n, n) = a[static_cast<size_t>(k)];
  return m;
}

// The event engine's visitor: z through M, and ŷ's degree-3 Taylor coefficients at the samples (the
// coefficients of lower degree are left at 0).
class ThirdOrderVisitor {
 public:
  ThirdOrderVisitor(const LinearModel& model, const PreparedSubject& s, const std::vector<DualVector>& sets,
                    int num_free, const TaylorAlgebra& algebra, std::vector<Eigen::VectorXd>* out)
      : model_(model), s_(s), n_(model.num_compartments()), algebra_(algebra),
        extended_(AllExtended(model, sets, num_free, algebra)), prop_(Matrices(), n_, algebra.products), out_(out) {
    int count = 0;
    sample_ = SampleIndex(s, &count);
    out->assign(algebra.monomials.size(), Eigen::VectorXd::Zero(count));
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
      auto c = Coefficients(model_.output_terms(cmt), extended_[static_cast<size_t>(set)], algebra_, 1, n_);
      it = outputs_.emplace(std::make_pair(set, cmt), std::move(c)).first;
    }
    const std::vector<Eigen::MatrixXd>& c = it->second;
    const Eigen::VectorXd& z = prop_.state();
    for (const auto& [t, a, b] : algebra_.cube_entries) {  // y_t = Σ C_a z_b, of degree 3
      (*out_)[static_cast<size_t>(t)](k) += c[static_cast<size_t>(a)].row(0).dot(z.segment(b * n_, n_));
    }
  }

 private:
  static std::vector<ExtendedSet> AllExtended(const LinearModel& model, const std::vector<DualVector>& sets,
                                              int num_free, const TaylorAlgebra& algebra) {
    std::vector<ExtendedSet> e;
    for (const DualVector& set : sets) e.push_back(ExtendedAlongCubes(model, set, num_free, algebra));
    return e;
  }
  std::vector<Eigen::MatrixXd> Matrices() const {
    std::vector<Eigen::MatrixXd> m;
    for (const ExtendedSet& e : extended_) {
      m.push_back(Stacked(Coefficients(model_.system_terms(), e, algebra_, n_, n_), *algebra_.products));
    }
    return m;
  }

  const LinearModel& model_;
  const PreparedSubject& s_;
  const int n_;
  const TaylorAlgebra& algebra_;
  const std::vector<ExtendedSet> extended_;  // per set: [θ; ψ] along each cube, for A and for C
  ExactPropagator prop_;
  std::vector<Eigen::VectorXd>* out_;
  std::vector<int> sample_;
  std::map<std::pair<int, int>, std::vector<Eigen::MatrixXd>> outputs_;  // (set, cmt) → C's coefficients
};

}  // namespace

std::vector<HyperDual3> ExtendedThird(const LinearModel& model, std::vector<HyperDual3> theta) {
  const DerivedCoefficients& derived = model.derived_coefficients();
  if (derived.count == 0) return theta;
  if (!derived.evaluate_third) throw NumericalFailure("the model's derived coefficients have no third order");
  const auto m = static_cast<Eigen::Index>(theta.size());
  Eigen::VectorXd values(m);
  Eigen::MatrixXd directions(m, 3);
  for (Eigen::Index j = 0; j < m; ++j) {
    values(j) = theta[static_cast<size_t>(j)].value();
    for (int c = 0; c < 3; ++c) directions(j, c) = theta[static_cast<size_t>(j)].part(1 << c);
  }
  std::vector<Eigen::VectorXd> parts;
  derived.evaluate_third(values, directions, &parts);
  for (int q = 0; q < derived.count; ++q) {
    HyperDual3 psi;
    for (int s = 0; s < 8; ++s) psi.part(s) = parts[static_cast<size_t>(s)](q);
    theta.push_back(psi);
  }
  return theta;
}

void ThirdOrderSensitivities(const LinearModel& model, const ParameterLayout& layout, const PreparedSubject& subject,
                             const std::vector<DualVector>& sets, int num_free,
                             const std::vector<std::array<int, 3>>& triples, std::vector<Eigen::VectorXd>* out) {
  const TaylorAlgebra algebra(triples);
  std::vector<Eigen::VectorXd> coefficients;
  ThirdOrderVisitor visitor(model, subject, sets, num_free, algebra, &coefficients);
  EventEngine<double, ThirdOrderVisitor> engine(subject, layout, subject.sets, &visitor);
  engine.Run();
  out->clear();
  for (const auto& triple : triples) {  // ∂³ŷ/∂p_i∂p_j∂p_k = γ! times the coefficient of p_i p_j p_k
    Monomial m(triple.begin(), triple.end());
    std::sort(m.begin(), m.end());
    out->push_back(coefficients[static_cast<size_t>(algebra.index.at(m))] * TaylorAlgebra::Factorial(m));
  }
}

}  // namespace internal
}  // namespace pk
