#include "second_order.h"

#include <algorithm>
#include <cmath>
#include <map>

#include "../hyper_dual_number.h"
#include "exact_propagator.h"
#include "exact_routes.h"
#include "modal.h"
#include "modal_evaluator.h"

namespace pk {
namespace internal {

std::vector<HyperDual> ExtendedSecond(const LinearModel& model, const DualVector& set, int num_free, int k, int l) {
  const int m = model.num_parameters();
  Eigen::VectorXd theta(m), u(m), v(m);
  for (int j = 0; j < m; ++j) {
    const Eigen::VectorXd d = Derivatives(set(j), num_free);
    theta(j) = set(j).value();
    u(j) = d(k);
    v(j) = d(l);
  }
  std::vector<HyperDual> e;
  for (int j = 0; j < m; ++j) e.emplace_back(theta(j), u(j), v(j), 0.0);
  const DerivedCoefficients& derived = model.derived_coefficients();
  if (derived.count > 0) {
    Eigen::VectorXd psi, psi_u, psi_v, psi_uv;
    derived.evaluate_second(theta, u, v, &psi, &psi_u, &psi_v, &psi_uv);
    for (int q = 0; q < derived.count; ++q) e.emplace_back(psi(q), psi_u(q), psi_v(q), psi_uv(q));
  }
  return e;
}

namespace {

using HD = HyperDualNumber;

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
    for (const DualVector& set : sets) e.push_back(ExtendedSecond(model, set, num_free, k, l));
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

// ---------------------------------------------------------------------------
// In eigen-coordinates. When A = VΛW (W = V⁻¹) is real and well conditioned (modal.h), the four
// blocks of e^{Mh} come from the Daleckii–Krein formula one order up: for φ = exp(h·) (Φ) and
// φ = f[·, 0] (Γ), with B_k = W A_k V and the divided differences φ[λ_i, λ_j], φ[λ_i, λ_m, λ_j],
//   ∂φ(A)/∂p_k      = V (φ[λ_i, λ_j] ∘ B_k) W,
//   ∂²φ(A)/∂p_k∂p_l = V (φ[λ_i, λ_j] ∘ B_kl + Σ_m φ[λ_i, λ_m, λ_j] ((B_k)_im (B_l)_mj + (B_l)_im (B_k)_mj)) W.
// The decomposition and the divided differences of each step serve every pair, and a step costs
// O(n³) arithmetic instead of an exponential of M (4n states). Steady states keep the M path.

// Up to 6 states on the stack: a step allocates nothing.
using SVec = modal_detail::SmallVec;
using SMat = modal_detail::SmallMat;
constexpr int kMaxModalStates = 6;

// A decomposition of one set's A and its steps' divided differences, shared by every pair.
struct ModalSet {
  SVec lambda;
  SMat v, w;
  struct Step {
    SVec e, g0;                   // e^{λh}, f[λ, 0]
    SMat d1, g1;                  // f[λ_i, λ_j], f[λ_i, λ_j, 0]
    std::vector<double> d2, g2;   // f[λ_i, λ_m, λ_j], f[λ_i, λ_m, λ_j, 0] at (i·n + m)·n + j
    bool input = false;           // whether g0, g1 and g2 are there
  };
  std::vector<std::pair<double, Step>> steps;

  const Step& Get(double h, bool input) {
    for (auto& s : steps) {
      if (s.first == h && (s.second.input || !input)) return s.second;
    }
    const auto n = lambda.size();
    Step st;
    st.e = (lambda * h).array().exp();
    st.d1.resize(n, n);
    st.d2.resize(static_cast<size_t>(n * n * n));
    for (Eigen::Index i = 0; i < n; ++i) {
      for (Eigen::Index j = 0; j < n; ++j) {
        st.d1(i, j) = DividedExp2(lambda(i), lambda(j), st.e(i), st.e(j), h);
        for (Eigen::Index m = 0; m < n; ++m) {
          st.d2[static_cast<size_t>((i * n + m) * n + j)] = DividedExp3General(lambda(i), lambda(m), lambda(j), h);
        }
      }
    }
    if (input) {
      st.input = true;
      st.g0.resize(n);
      st.g1.resize(n, n);
      st.g2.resize(st.d2.size());
      for (Eigen::Index i = 0; i < n; ++i) {
        st.g0(i) = DividedExp2(lambda(i), 0, st.e(i), 1, h);
        for (Eigen::Index j = 0; j < n; ++j) {
          st.g1(i, j) = DividedExp3(lambda(i), lambda(j), st.e(i), st.e(j), h);
          for (Eigen::Index m = 0; m < n; ++m) {
            st.g2[static_cast<size_t>((i * n + m) * n + j)] = DividedExp4(lambda(i), lambda(m), lambda(j), h);
          }
        }
      }
    }
    // Replace an entry of the same h without the input parts rather than keep both.
    for (auto& s : steps) {
      if (s.first == h) {
        s.second = std::move(st);
        return s.second;
      }
    }
    steps.emplace_back(h, std::move(st));
    return steps.back().second;
  }
};

// (D ∘ B_kl) + Σ_m D2_imj ((B_k)_im (B_l)_mj + (B_l)_im (B_k)_mj): the second-order block.
SMat SecondBlock(const SMat& d1, const std::vector<double>& d2, const SMat& bk, const SMat& bl, const SMat& bkl) {
  const auto n = bk.rows();
  SMat out = d1.cwiseProduct(bkl);
  for (Eigen::Index i = 0; i < n; ++i) {
    for (Eigen::Index j = 0; j < n; ++j) {
      double sum = 0;
      for (Eigen::Index m = 0; m < n; ++m) {
        sum += d2[static_cast<size_t>((i * n + m) * n + j)] * (bk(i, m) * bl(m, j) + bl(i, m) * bk(m, j));
      }
      out(i, j) += sum;
    }
  }
  return out;
}

// The event engine's visitor for every pair at once in eigen-coordinates (no steady states): the
// state is x, the first-order s_j for every free parameter (each pair reads two of them) and w for
// each pair, so one walk of the schedule serves all pairs and each s_j is stepped once. The state
// stays in the model's coordinates (parameter sets may change between steps); a step moves it to
// the set's eigen-coordinates and back.
class ModalSecondOrderVisitor {
 public:
  ModalSecondOrderVisitor(const LinearModel& model, const PreparedSubject& s, const std::vector<DualVector>& sets,
                          int num_free, const std::vector<std::pair<int, int>>& pairs, std::vector<ModalSet>* modal,
                          std::vector<Eigen::VectorXd>* out)
      : model_(model), s_(s), n_(model.num_compartments()), p_(num_free), pairs_(pairs), modal_(modal), out_(out) {
    per_set_.reserve(sets.size());
    for (size_t i = 0; i < sets.size(); ++i) per_set_.push_back(MakeSet(sets[i], (*modal)[i]));
    x_ = SVec::Zero(n_);
    first_.assign(static_cast<size_t>(p_), x_);
    second_.assign(pairs.size(), x_);
    int count = 0;
    sample_ = SampleIndex(s, &count);
    for (Eigen::VectorXd& o : *out) o.setZero(count);
  }
  void Advance(double h, const Eigen::VectorXd& u, int set) {
    const ModalSet& m = (*modal_)[static_cast<size_t>(set)];
    const bool input = !u.isZero(0.0);
    const Blocks& b = GetBlocks(set, h, input);
    const SVec x = m.w * x_;
    first_hat_.resize(first_.size());
    for (size_t j = 0; j < first_.size(); ++j) first_hat_[j] = m.w * first_[j];
    const SVec uh = input ? SVec(m.w * SVec(u.head(n_))) : SVec();
    for (size_t q = 0; q < pairs_.size(); ++q) {
      const auto [k, l] = pairs_[q];
      SVec w = b.e.cwiseProduct(m.w * second_[q]) + b.first[static_cast<size_t>(l)] * first_hat_[static_cast<size_t>(k)] +
               b.first[static_cast<size_t>(k)] * first_hat_[static_cast<size_t>(l)] + b.second[q] * x;
      if (input) w += b.second_input[q] * uh;
      second_[q] = m.v * w;
    }
    for (size_t j = 0; j < first_.size(); ++j) {
      SVec sj = b.e.cwiseProduct(first_hat_[j]) + b.first[j] * x;
      if (input) sj += b.first_input[j] * uh;
      first_[j] = m.v * sj;
    }
    SVec nx = b.e.cwiseProduct(x);
    if (input) nx += b.g0.cwiseProduct(uh);
    x_ = m.v * nx;
  }
  void Bolus(int cmt, double amount, int) { x_(cmt) += amount; }
  void Reset() {
    x_.setZero();
    for (SVec& v : first_) v.setZero();
    for (SVec& v : second_) v.setZero();
  }
  void SteadyState(const SteadyStateCycle<double>&, int, bool) { throw NumericalFailure("steady state"); }
  void SteadyInfusion(const Eigen::VectorXd&, int, bool) { throw NumericalFailure("steady state"); }
  void DoseEntered(double, int) {}
  void RecordDone(int r, int set) {
    const int k = sample_[static_cast<size_t>(r)];
    if (k < 0) return;
    const int cmt = s_.cmt[static_cast<size_t>(r)] + 1;
    PerSet& p = per_set_[static_cast<size_t>(set)];
    auto it = p.outputs.find(cmt);
    if (it == p.outputs.end()) {
      std::vector<Parts> c;
      for (const std::vector<HD>& e : p.extended) c.push_back(Sum(model_.output_terms(cmt), e, 1, n_));
      it = p.outputs.emplace(cmt, std::move(c)).first;
    }
    for (size_t q = 0; q < pairs_.size(); ++q) {
      const Parts& c = it->second[q];
      const auto [a, b] = pairs_[q];
      (*out_)[q](k) = c.value.row(0).dot(second_[q]) + c.dk.row(0).dot(first_[static_cast<size_t>(b)]) +
                      c.dl.row(0).dot(first_[static_cast<size_t>(a)]) + c.dkl.row(0).dot(x_);
    }
  }

 private:
  // One step's blocks in eigen-coordinates: e^{Λh}, D₁∘B_j per parameter, the second-order block per
  // pair, and with input their Γ counterparts.
  struct Blocks {
    double h = 0;
    bool input = false;
    SVec e, g0;
    std::vector<SMat> first, second, first_input, second_input;
  };
  struct PerSet {
    std::vector<std::vector<HD>> extended;  // per pair: [θ; ψ] along its k and l
    std::vector<SMat> b1;                   // per parameter: W A_j V
    std::vector<SMat> b2;                   // per pair: W A_kl V
    std::vector<Blocks> steps;
    std::map<int, std::vector<Parts>> outputs;  // per output compartment, per pair: C and its derivatives
  };

  PerSet MakeSet(const DualVector& set, const ModalSet& m) const {
    PerSet p;
    p.b1.assign(static_cast<size_t>(p_), SMat::Zero(n_, n_));
    p.extended.reserve(pairs_.size());
    p.b2.reserve(pairs_.size());
    for (const auto& [k, l] : pairs_) {
      p.extended.push_back(ExtendedSecond(model_, set, p_, k, l));
      const Parts a = Sum(model_.system_terms(), p.extended.back(), n_, n_);
      p.b1[static_cast<size_t>(k)] = m.w * SMat(a.dk) * m.v;  // the pairs cover every parameter
      p.b1[static_cast<size_t>(l)] = m.w * SMat(a.dl) * m.v;
      p.b2.push_back(m.w * SMat(a.dkl) * m.v);
    }
    return p;
  }

  const Blocks& GetBlocks(int set, double h, bool input) {
    PerSet& p = per_set_[static_cast<size_t>(set)];
    for (const Blocks& b : p.steps) {
      if (b.h == h && (b.input || !input)) return b;
    }
    const ModalSet::Step& st = (*modal_)[static_cast<size_t>(set)].Get(h, input);
    Blocks b;
    b.h = h;
    b.input = input;
    b.e = st.e;
    // Reserved: a subject's few steps are built at every evaluation, and regrowth copies 6×6 blocks.
    b.first.reserve(p.b1.size());
    b.second.reserve(pairs_.size());
    for (const SMat& bj : p.b1) b.first.push_back(st.d1.cwiseProduct(bj));
    for (size_t q = 0; q < pairs_.size(); ++q) {
      const auto [k, l] = pairs_[q];
      b.second.push_back(SecondBlock(st.d1, st.d2, p.b1[static_cast<size_t>(k)], p.b1[static_cast<size_t>(l)], p.b2[q]));
    }
    if (input) {
      b.g0 = st.g0;
      b.first_input.reserve(p.b1.size());
      b.second_input.reserve(pairs_.size());
      for (const SMat& bj : p.b1) b.first_input.push_back(st.g1.cwiseProduct(bj));
      for (size_t q = 0; q < pairs_.size(); ++q) {
        const auto [k, l] = pairs_[q];
        b.second_input.push_back(
            SecondBlock(st.g1, st.g2, p.b1[static_cast<size_t>(k)], p.b1[static_cast<size_t>(l)], p.b2[q]));
      }
    }
    p.steps.push_back(std::move(b));
    return p.steps.back();
  }

  const LinearModel& model_;
  const PreparedSubject& s_;
  const int n_, p_;
  const std::vector<std::pair<int, int>>& pairs_;
  std::vector<ModalSet>* modal_;
  std::vector<Eigen::VectorXd>* out_;
  std::vector<PerSet> per_set_;
  SVec x_;
  std::vector<SVec> first_, second_, first_hat_;
  std::vector<int> sample_;
};

// The sets' decompositions, or false when one is unsuitable, A is larger than the stack matrices,
// or the subject has a steady state.
bool Decompositions(const LinearModel& model, const PreparedSubject& subject, const std::vector<DualVector>& sets,
                    std::vector<ModalSet>* modal) {
  if (model.num_compartments() > kMaxModalStates) return false;
  for (const Record& r : subject.records()) {
    if (r.ss != 0) return false;
  }
  for (const DualVector& set : sets) {
    ModalSet m;
    const SMat a = model.SystemMatrix<double>(Values(set, model.num_parameters()));
    if (!a.allFinite() || !modal_detail::Decompose(a, &m.lambda, &m.v, &m.w)) return false;
    modal->push_back(std::move(m));
  }
  return true;
}

}  // namespace

void SecondOrderSensitivities(const LinearModel& model, const ParameterLayout& layout, const PreparedSubject& subject,
                              const std::vector<DualVector>& sets, int num_free,
                              const std::vector<std::pair<int, int>>& pairs, bool eigen_coordinates,
                              std::vector<Eigen::VectorXd>* out) {
  out->assign(pairs.size(), Eigen::VectorXd());
  std::vector<ModalSet> modal;
  if (eigen_coordinates && Decompositions(model, subject, sets, &modal)) {
    ModalSecondOrderVisitor visitor(model, subject, sets, num_free, pairs, &modal, out);
    EventEngine<double, ModalSecondOrderVisitor> engine(subject, layout, subject.sets, &visitor);
    engine.Run();
    return;
  }
  for (size_t i = 0; i < pairs.size(); ++i) {
    SecondOrderVisitor visitor(model, subject, sets, num_free, pairs[i].first, pairs[i].second, &(*out)[i]);
    EventEngine<double, SecondOrderVisitor> engine(subject, layout, subject.sets, &visitor);
    engine.Run();
  }
}

}  // namespace internal
}  // namespace pk
