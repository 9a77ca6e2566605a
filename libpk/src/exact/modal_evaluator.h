// The modal evaluator (see modal.h), a class template over the number of
// states. modal.cc instantiates it for sizes known only at run time and
// modal_fixed.cc for 2 to 4 states, in separate translation units so that the
// two compile in parallel.
#ifndef PK_SRC_EXACT_MODAL_EVALUATOR_H_
#define PK_SRC_EXACT_MODAL_EVALUATOR_H_

#include <algorithm>
#include <cmath>
#include <memory>
#include <type_traits>
#include <vector>

#include <Eigen/Core>
#include <unsupported/Eigen/AutoDiff>

#include "modal.h"
#include "numerical_failure.h"

namespace pk {
namespace internal {

// ---------------------------------------------------------------------------
// The evaluator.

namespace modal_detail {

using Ad1 = Eigen::AutoDiffScalar<Eigen::Matrix<double, 1, 1>>;

// ∂(term)/∂θ_j by automatic differentiation of the term.
inline double TermPartial(const LinearTerm& t, const std::vector<double>& theta, int j) {
  const auto seeded = [&](int i) { return Ad1(theta[i], Eigen::Matrix<double, 1, 1>::Constant(i == j ? 1.0 : 0.0)); };
  return LinearModel::TermValue<Ad1>(t, seeded).derivatives()(0);
}

// Up to 6 states on the stack.
using SmallMat = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, 6, 6>;
using SmallVec = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, 6, 1>;

// A = V diag(λ) W by compartment structure (modal.h): depots are peeled off,
// the reversible remainder is symmetrised and diagonalised by Jacobi rotations
// (up to 4 states) or Eigen's symmetric solver, anything else by Eigen's real
// solver. False for complex eigenvalues or ‖|V||W|‖_∞ > 1e3. Compiled once, in
// modal.cc, for every instance of Modal.
bool Decompose(const SmallMat& a, SmallVec* lambda, SmallMat* v, SmallMat* w);
bool Decompose(const Eigen::MatrixXd& a, Eigen::VectorXd* lambda, Eigen::MatrixXd* v, Eigen::MatrixXd* w);

// The same decomposition at sizes fixed at compile time, for the structure of
// most PK models: depots feeding a reversible block of one to three states
// (1cmt_oral, 2cmt_iv, 2cmt_oral, 3cmt_iv, 3cmt_oral). The block is symmetrised
// as in Decompose; a 2×2 block is diagonalised by one Jacobi rotation (exact),
// a 3×3 one by cyclic Jacobi rotations. kOther: `a` has another
// structure (call Decompose); kUnsuitable: as Decompose's false. Instantiated
// in modal.cc for N = 2, 3, 4.
enum class SmallDecomposition { kDone, kUnsuitable, kOther };
template <int N>
SmallDecomposition DecomposeSmall(const Eigen::Matrix<double, N, N>& a, Eigen::Matrix<double, N, 1>* lambda,
                                  Eigen::Matrix<double, N, N>* v, Eigen::Matrix<double, N, N>* w);

// N: the number of states when fixed at compile time (small models: loops
// unroll and nothing is allocated), or Eigen::Dynamic with at most MaxN.
template <int N, int MaxN>
class Modal final : public ModalEvaluator {
 public:
  using Mat = Eigen::Matrix<double, N, N, 0, MaxN, MaxN>;
  using Vec = Eigen::Matrix<double, N, 1, 0, MaxN, 1>;
  using RowVec = Eigen::Matrix<double, 1, N, Eigen::RowMajor, 1, MaxN>;

  explicit Modal(const LinearModel& model) : model_(model), n_(model.num_compartments()) {}

  // The number of states, a compile-time constant when N is fixed.
  int n() const { return N == Eigen::Dynamic ? n_ : N; }

  // Builds every set's decomposition; false when one is unsuitable.
  bool Reset(const EventSchedule& schedule, const Eigen::VectorXd& values, const PreparedSubject& subject,
             const std::vector<int>& free) override {
    sched_ = &schedule;
    p_ = static_cast<int>(free.size());
    const size_t num_sets = subject.sets.size();
    const int m = model_.num_parameters();
    simple_ = num_sets == 1 && schedule.simple;
    sets_.resize(num_sets);
    for (size_t k = 0; k < num_sets; ++k) {
      Set& s = sets_[k];
      // What the previous use left: cleared, capacity kept.
      s.ahat.clear();
      for (Output& o : s.outputs) {
        o.cmt = -1;
        o.dc.clear();
      }
      const std::vector<char>& from_data = subject.from_data[k];
      s.theta.resize(m);
      bool finite = true;
      for (int i = 0; i < m; ++i) {
        s.theta[i] = from_data[i] ? subject.sets[k](i) : values(i);
        finite = finite && std::isfinite(s.theta[i]);
      }
      if (!finite || !Extend(&s)) return false;
      s.active.resize(free.size());
      size_t num_active = 0;
      for (size_t a = 0; a < free.size(); ++a) {
        if (!from_data[free[a]]) s.active[num_active++] = {free[a], static_cast<int>(a)};
      }
      s.active.resize(num_active);
      Mat a = Mat::Zero(n(), n());
      const auto value = [&](int i) { return s.theta[i]; };
      for (const LinearTerm& t : model_.system_terms()) a(t.row, t.col) += LinearModel::TermValue<double>(t, value);
      if (!a.allFinite() || !Decompose(a, &s)) return false;
      // ∂A/∂θ_j entry by entry. Which entries there are depends on the active list alone (an optimiser keeps
      // it), so the list is rebuilt only when that changes, in one pass over the terms (each depends on at
      // most two θ); otherwise only the values are.
      const std::vector<LinearTerm>& terms = model_.system_terms();
      if (s.da_active != s.active) {
        s.da.clear();
        act_of_.assign(s.theta.size(), -1);
        for (size_t act = 0; act < s.active.size(); ++act) act_of_[s.active[act].first] = static_cast<int>(act);
        for (size_t ti = 0; ti < terms.size(); ++ti) {
          const LinearTerm& t = terms[ti];
          if (t.numerator == t.denominator) continue;  // θ_j/θ_j is constant
          for (const int j : TermReads(t)) {
            if (act_of_[j] < 0) continue;
            s.da.push_back({t.row, t.col, act_of_[j], 0.0, s.active[act_of_[j]].second, static_cast<int>(ti), j});
          }
        }
        s.da_active = s.active;
      }
      for (DTerm& d : s.da) d.d = TermDerivative(s, terms[d.term], d.j);
      s.uhat.resize(sched_->inputs.size());
      s.uhat_ready.assign(sched_->inputs.size(), 0);
      s.steps.resize(sched_->steps.size());
    }
    if (++generation_ == 0) {  // invalidates every step cache; after 2^32 Resets, by hand
      for (Set& s : sets_) {
        for (StepCache& c : s.steps) c.have_e = c.have_g = c.have_df = c.have_dg = 0;
      }
      generation_ = 1;
    }
    return true;
  }

  void Predict(Eigen::VectorXd* yhat) override {
    yhat->setZero(sched_->num_samples);
    if (simple_) {
      RunPlain(yhat, nullptr);
    } else {
      Run(yhat, nullptr, nullptr);
    }
  }

  void Jacobian(Eigen::VectorXd* yhat, Eigen::MatrixXd* jacobian) override {
    yhat->setZero(sched_->num_samples);
    jacobian->setZero(sched_->num_samples, p_);
    for (Set& s : sets_) {
      if (!s.ahat.empty() || s.active.empty()) continue;
      // Â_j = V⁻¹ (∂A/∂θ_j) V, one rank-one term per entry of ∂A/∂θ_j.
      s.ahat.assign(s.active.size(), Mat::Zero(n(), n()));
      for (const DTerm& d : s.da) s.ahat[d.act].noalias() += d.d * s.w.col(d.row) * s.v.row(d.col);
    }
    Run(yhat, jacobian, nullptr);
  }

  void AdjointForward(Eigen::VectorXd* yhat) override {
    yhat->setZero(sched_->num_samples);
    // One n-vector per step and per sample; steady states add their cycles (Push grows it).
    tape_used_ = 0;
    const size_t size = n() * (sched_->ops.size() + 4 * sched_->cycles.size());
    if (tape_.size() < size) tape_.resize(size);
    if (simple_) {
      RunPlain(yhat, tape_.data());
    } else {
      Run(yhat, nullptr, &tape_);
    }
  }

  Eigen::VectorXd AdjointGradient(const Eigen::VectorXd& dl_dy) override {
    for (Set& s : sets_) {
      s.z = Mat::Zero(n(), n());
      for (Output& o : s.outputs) o.xacc = Vec::Zero(n());
    }
    if (simple_) {
      SweepPlain(dl_dy);
      return Contract();
    }
    size_t cursor = tape_used_;
    const auto pop = [&](Vec* v) {
      cursor -= n();
      *v = Eigen::Map<const Eigen::VectorXd>(tape_.data() + cursor, n());
    };
    Vec mu = Vec::Zero(n()), z(n());  // z: a sample's state
    const std::vector<ScheduleOp>& ops = sched_->ops;
    const auto back_step = [&](Set& s, int step, int input, Vec* m) {
      cursor -= n();
      BackStep(s, step, input, tape_.data() + cursor, m);
    };
    for (int i = static_cast<int>(ops.size()) - 1; i >= 0; --i) {
      const ScheduleOp& op = ops[i];
      Set& s = sets_[op.set];
      switch (op.kind) {
        case ScheduleOp::kSample: {
          pop(&z);
          const double g = dl_dy(op.index);
          if (g == 0) break;
          Output& o = GetOutput(s, op.cmt);
          mu += g * o.chat;
          o.xacc += g * z;
          break;
        }
        case ScheduleOp::kAdvance:
          back_step(s, op.step, op.index, &mu);
          break;
        case ScheduleOp::kBolus:
          break;
        case ScheduleOp::kReset:
          mu.setZero();
          break;
        case ScheduleOp::kSteadyInfusion: {
          // z = −Λ⁻¹û: μᵀ ∂z/∂θ_j = ⟨−(μ̂/λ) ẑᵀ, Â_j⟩.
          const Vec zs = -Uhat(s, op.index).cwiseQuotient(s.lambda);
          s.z.noalias() -= mu.cwiseQuotient(s.lambda) * zs.transpose();
          if (!op.add) mu.setZero();
          break;
        }
        case ScheduleOp::kSteadyState: {
          const ScheduleCycle& cycle = sched_->cycles[op.index];
          Vec m(n());
          pop(&m);
          Vec rho = mu;
          for (auto it = cycle.to_record.rbegin(); it != cycle.to_record.rend(); ++it) {
            back_step(s, it->step, it->input, &rho);
          }
          // Implicit function theorem on z* = m ∘ z* + r: ρ̂ = μ̂ / (1 − m), then back through one period.
          rho = rho.cwiseQuotient((Vec::Ones(n()) - m));
          for (auto it = cycle.period.rbegin(); it != cycle.period.rend(); ++it) {
            back_step(s, it->step, it->input, &rho);
          }
          if (!op.add) mu.setZero();
          break;
        }
      }
      // The forward pass changed coordinates before op i: z_i = W_i V_{i−1} z_{i−1}.
      if (i > 0 && ops[i - 1].set != op.set) {
        mu = sets_[ops[i - 1].set].v.transpose() * (s.w.transpose() * mu);
      }
    }
    return Contract();
  }

 private:
  // ⟨V⁻ᵀ Z Vᵀ, ∂A/∂θ_j⟩ and the output rows' ∂c/∂θ_j · x: the gradient from the sweep's sums.
  Eigen::VectorXd Contract() {
    // Summed in kept storage and then copied: GCC turns a fresh vector's allocation and zeroing into calloc,
    // which bypasses glibc's per-thread cache and costs more than the rest of the sums.
    Eigen::VectorXd& grad = grad_;
    grad.setZero(p_);
    for (const Set& s : sets_) {
      if (!s.da.empty()) {
        const Mat g = s.w.transpose() * s.z * s.v.transpose();
        for (const DTerm& d : s.da) grad(d.pos) += g(d.row, d.col) * d.d;
      }
      for (const Output& o : s.outputs) {
        if (o.dc.empty()) continue;
        const Vec x = s.v * o.xacc;
        for (const DTerm& d : o.dc) grad(d.pos) += d.d * x(d.col);
      }
    }
    return Eigen::VectorXd(grad);
  }

  // AdjointGradient's backward sweep over a simple schedule (RunPlain's tape):
  // Z and the outputs' Σ ∂ℓ/∂ŷ_k z_k, with μ̂ as in the general sweep.
  void SweepPlain(const Eigen::VectorXd& dl_dy) {
    Set& s = sets_[0];
    Vec mu = Vec::Zero(n());
    const double* zt = tape_.data() + tape_used_;
    Output* out = nullptr;
    const std::vector<ScheduleOp>& ops = sched_->ops;
    for (auto it = ops.rbegin(); it != ops.rend(); ++it) {
      const ScheduleOp& op = *it;
      switch (op.kind) {
        case ScheduleOp::kSample: {
          zt -= n();
          const double g = dl_dy(op.index);
          if (g == 0) break;
          if (out == nullptr || out->cmt != op.cmt) out = &GetOutput(s, op.cmt);
          mu += g * out->chat;
          out->xacc += g * Eigen::Map<const Vec>(zt, n());
          break;
        }
        case ScheduleOp::kAdvance:
          zt -= n();
          BackStep(s, op.step, op.index, zt, &mu);
          break;
        case ScheduleOp::kReset:
          mu.setZero();
          break;
        case ScheduleOp::kBolus:
        case ScheduleOp::kSteadyState:
        case ScheduleOp::kSteadyInfusion:
          break;
      }
    }
  }

  struct DTerm {
    int row, col, act;
    double d;
    int pos;       // the free position of active parameter `act` (the gradient's entry)
    int term = 0;  // Set::da: d = ∂(system term `term`)/∂θ_j
    int j = 0;
  };
  struct Output {
    int cmt = -1;  // -1: unused (kept for its storage)
    Vec chat;               // (C V)ᵀ
    std::vector<DTerm> dc;  // ∂C/∂θ_j entries (row unused)
    Vec xacc;               // Σ ∂ℓ/∂ŷ_k z_k, for the ∂C terms
  };
  // What a step of length h needs, computed on first use per set.
  struct StepCache {
    // The Reset (generation_) each member was last filled for.
    unsigned have_e = 0, have_g = 0, have_df = 0, have_dg = 0;
    Vec e, g;    // e^{λh}; the input's weight f[λ, 0] = (e^{λh} − 1)/λ
    Mat df, dg;  // f[λ_i, λ_k] and f[λ_i, λ_k, 0], the Daleckii–Krein weights
  };
  struct Set {
    std::vector<double> theta;  // [θ; ψ] (linear_model.h)
    Eigen::MatrixXd jac;        // ∂ψ/∂θ
    std::vector<std::pair<int, int>> active;
    Vec lambda;
    Mat v, w;
    std::vector<DTerm> da;
    std::vector<std::pair<int, int>> da_active;  // the active list `da` was built for
    std::vector<Output> outputs;
    std::vector<Vec> uhat;        // W u per schedule input, when uhat_ready
    std::vector<char> uhat_ready;
    std::vector<Mat> ahat;
    Mat z;
    std::vector<StepCache> steps;  // per EventSchedule::steps entry
    size_t last_output = 0;        // GetOutput's last answer
  };

  // s.theta = [θ; ψ(θ)] and s.jac = ∂ψ/∂θ when the terms read derived coefficients (linear_model.h).
  bool Extend(Set* s) const {
    const DerivedCoefficients& derived = model_.derived_coefficients();
    if (derived.count == 0) return true;
    const int m = model_.num_parameters();
    const Eigen::Map<const Eigen::VectorXd> theta(s->theta.data(), m);
    Eigen::VectorXd psi;
    derived.evaluate(theta, &psi, &s->jac);
    if (!psi.allFinite() || !s->jac.allFinite()) return false;
    s->theta.insert(s->theta.end(), psi.data(), psi.data() + psi.size());
    return true;
  }

  // The parameters a term depends on: its θ, or what its ψ reads (no repeats).
  std::vector<int> TermReads(const LinearTerm& t) const {
    const int m = model_.num_parameters();
    std::vector<int> reads;
    for (const int i : {t.numerator, t.denominator}) {
      if (i < 0) continue;
      if (i < m) {
        reads.push_back(i);
      } else {
        const std::vector<int>& r = model_.derived_coefficients().reads[static_cast<size_t>(i - m)];
        reads.insert(reads.end(), r.begin(), r.end());
      }
    }
    std::sort(reads.begin(), reads.end());
    reads.erase(std::unique(reads.begin(), reads.end()), reads.end());
    return reads;
  }

  // ∂(term)/∂θ_j, through ψ by the chain rule when the term reads it.
  double TermDerivative(const Set& s, const LinearTerm& t, int j) const {
    const int m = model_.num_parameters();
    if (t.numerator < m && t.denominator < m) return TermPartial(t, s.theta, j);
    double d = 0;
    for (const int i : {t.numerator, t.denominator}) {
      if (i < 0) continue;
      const double di = i < m ? (i == j ? 1.0 : 0.0) : s.jac(i - m, j);
      if (di != 0) d += TermPartial(t, s.theta, i) * di;
    }
    return d;
  }

  // Eigendecomposition by compartment structure (modal_detail::Decompose).
  bool Decompose(const Mat& a, Set* s) const {
    if constexpr (N != Eigen::Dynamic) {
      switch (DecomposeSmall<N>(a, &s->lambda, &s->v, &s->w)) {
        case SmallDecomposition::kDone: return true;
        case SmallDecomposition::kUnsuitable: return false;
        case SmallDecomposition::kOther: break;
      }
    }
    using Full = std::conditional_t<MaxN == Eigen::Dynamic, Eigen::MatrixXd, SmallMat>;
    using FullVec = std::conditional_t<MaxN == Eigen::Dynamic, Eigen::VectorXd, SmallVec>;
    Full v, w;
    FullVec lambda;
    if (!modal_detail::Decompose(Full(a), &lambda, &v, &w)) return false;
    s->lambda = lambda;
    s->v = v;
    s->w = w;
    return true;
  }

  const Vec& Uhat(Set& s, int input) {
    Vec& u = s.uhat[input];
    if (!s.uhat_ready[input]) {
      s.uhat_ready[input] = 1;
      const Eigen::VectorXd& in = sched_->inputs[input];
      u = Vec::Zero(n());
      for (int c = 0; c < n(); ++c) {
        if (in(c) != 0) u += in(c) * s.w.col(c);
      }
    }
    return u;
  }

  Output& GetOutput(Set& s, int cmt) {
    // Samples of one output follow each other: try the last one first.
    if (s.last_output < s.outputs.size() && s.outputs[s.last_output].cmt == cmt) return s.outputs[s.last_output];
    return FindOutput(s, cmt);
  }

  __attribute__((noinline)) Output& FindOutput(Set& s, int cmt) {
    size_t unused = s.outputs.size();  // an entry kept for its storage, else a new one
    for (size_t i = 0; i < s.outputs.size(); ++i) {
      if (s.outputs[i].cmt == cmt) {
        s.last_output = i;
        return s.outputs[i];
      }
      if (s.outputs[i].cmt < 0 && unused == s.outputs.size()) unused = i;
    }
    if (unused == s.outputs.size()) s.outputs.emplace_back();
    s.last_output = unused;
    Output& o = s.outputs[unused];
    o.cmt = cmt;
    RowVec c = RowVec::Zero(n());
    const auto value = [&](int i) { return s.theta[i]; };
    for (const LinearTerm& t : model_.output_terms(cmt)) {
      c(t.col) += LinearModel::TermValue<double>(t, value);
      const std::vector<int> reads = TermReads(t);
      for (size_t act = 0; act < s.active.size(); ++act) {
        const int j = s.active[act].first;
        if (std::find(reads.begin(), reads.end(), j) != reads.end()) {
          o.dc.push_back({0, t.col, static_cast<int>(act), TermDerivative(s, t, j), s.active[act].second});
        }
      }
    }
    o.chat = (c * s.v).transpose();
    o.xacc = Vec::Zero(n());
    return o;
  }

  static double DividedF(const Set& s, int i, int k, const Vec& e, double h) {
    return i == k ? h * e(i) : DividedExp2(s.lambda(i), s.lambda(k), e(i), e(k), h);
  }

  void Push(const Vec& v) {
    if (tape_used_ + n() > tape_.size()) tape_.resize(2 * (tape_used_ + n()));
    std::copy(v.data(), v.data() + n(), tape_.data() + tape_used_);
    tape_used_ += n();
  }

  // e^{Λh} for schedule step `step`, with the input weights and the divided
  // differences when asked. Both f[λ_i, λ_k] and f[λ_i, λ_k, 0] are symmetric.
  const StepCache& Cached(Set& s, int step, bool input, bool derivatives) {
    const StepCache& c = s.steps[step];
    const unsigned now = generation_;
    if (c.have_e == now && (!input || c.have_g == now) &&
        (!derivatives || (c.have_df == now && (!input || c.have_dg == now)))) {
      return c;
    }
    return Fill(s, step, input, derivatives);
  }

  __attribute__((noinline)) const StepCache& Fill(Set& s, int step, bool input, bool derivatives) {
    StepCache& c = s.steps[step];
    const double h = sched_->steps[step];
    const unsigned now = generation_;
    if (c.have_e != now) {
      const EventSchedule::StepPower& sp = sched_->step_powers[step];
      if (sp.base >= 0) {
        // h = power · h_base exactly: e^{λh} = (e^{λ h_base})^power.
        const Vec& eb = Cached(s, sp.base, false, false).e;
        c.e = eb.cwiseProduct(eb);
        if (sp.power == 3) c.e = c.e.cwiseProduct(eb);
        if (sp.power == 4) c.e = c.e.cwiseProduct(c.e);
      } else {
        c.e.resize(n());
        for (int r = 0; r < n(); ++r) c.e(r) = std::exp(s.lambda(r) * h);
      }
      c.have_e = now;
    }
    if (input && c.have_g != now) {
      c.g.resize(n());
      for (int r = 0; r < n(); ++r) c.g(r) = DividedExp2(s.lambda(r), 0, c.e(r), 1, h);
      c.have_g = now;
    }
    if (derivatives && c.have_df != now) {
      c.df.resize(n(), n());
      for (int i = 0; i < n(); ++i) {
        for (int k = 0; k <= i; ++k) c.df(i, k) = c.df(k, i) = DividedF(s, i, k, c.e, h);
      }
      c.have_df = now;
    }
    if (derivatives && input && c.have_dg != now) {
      c.dg.resize(n(), n());
      for (int i = 0; i < n(); ++i) {
        for (int k = 0; k <= i; ++k) {
          c.dg(i, k) = c.dg(k, i) = DividedExp3(s.lambda(i), s.lambda(k), c.e(i), c.e(k), h);
        }
      }
      c.have_dg = now;
    }
    return c;
  }

  // One step (schedule step `step`) with input `input` (-1: none), with the
  // sensitivities (route a) or the tape (route b) when asked.
  void Step(Set& s, int step, int input, Vec* z, Eigen::MatrixXd* sens, std::vector<double>* tape) {
    if (sens) {
      StepWithSensitivities(s, step, input, z, sens, tape);
      return;
    }
    const StepCache& c = Cached(s, step, input >= 0, false);
    if (tape) Push(*z);
    Propagate(s, c, input, z);
  }

  // z⁺ = e^{Λh} z + g(Λ) û for a step whose cache `c` is filled.
  void Propagate(Set& s, const StepCache& c, int input, Vec* z) {
    *z = z->cwiseProduct(c.e);
    if (input >= 0) *z += c.g.cwiseProduct(Uhat(s, input));
  }

  __attribute__((noinline)) void StepWithSensitivities(Set& s, int step, int input, Vec* z, Eigen::MatrixXd* sens,
                                                       std::vector<double>* tape) {
    const StepCache& c = Cached(s, step, input >= 0, true);
    if (tape) Push(*z);
    // Ŝ⁺ = e ∘ Ŝ + Σ_j ((D_f ∘ Â_j) z + (D_g ∘ Â_j) û) ∂θ_j/∂p. With W = D_f diag(z) + D_g diag(û),
    // formed once per step, the column of each active θ_j gains the row sums of W ∘ Â_j.
    Mat& w = step_weights_;
    w.resize(n(), n());
    for (int k = 0; k < n(); ++k) w.col(k) = c.df.col(k) * (*z)(k);
    if (input >= 0) {
      const Vec& u = Uhat(s, input);
      for (int k = 0; k < n(); ++k) w.col(k) += c.dg.col(k) * u(k);
    }
    // Plain loops: at 2 to 4 states they unroll, where Eigen's partial reductions do not.
    for (Eigen::Index col = 0; col < sens->cols(); ++col) {
      double* out = sens->col(col).data();
      for (int i = 0; i < n(); ++i) out[i] *= c.e(i);
    }
    for (size_t act = 0; act < s.active.size(); ++act) {
      const Mat& ah = s.ahat[act];
      double* out = sens->col(s.active[act].second).data();
      for (int i = 0; i < n(); ++i) {
        double t = 0;
        for (int k = 0; k < n(); ++k) t += w(i, k) * ah(i, k);
        out[i] += t;
      }
    }
    Propagate(s, c, input, z);
  }

  // Back through one step z⁺ = e ∘ z + g ∘ û from state z (`zt`, off the tape):
  // Z += D_f ∘ (μ̂ zᵀ) + D_g ∘ (μ̂ ûᵀ), then μ̂ ← e ∘ μ̂. Forced inline: called from
  // two loops, GCC keeps it out of line, which costs the lean sweep about 300 instructions.
  __attribute__((always_inline)) void BackStep(Set& s, int step, int input, const double* zt, Vec* mu) {
    const StepCache& c = Cached(s, step, input >= 0, true);
    if (input >= 0) {
      const Vec& u = Uhat(s, input);
      for (int k = 0; k < n(); ++k) s.z.col(k) += mu->cwiseProduct(c.df.col(k) * zt[k] + c.dg.col(k) * u(k));
    } else {
      for (int k = 0; k < n(); ++k) s.z.col(k) += (zt[k] * *mu).cwiseProduct(c.df.col(k));
    }
    *mu = mu->cwiseProduct(c.e);
  }

  // Run without sensitivities over a simple schedule (one parameter set, no
  // steady states): the loss's and route (b)'s forward pass, with nothing in the
  // loop but the recursion. `tape` (route b) has room for n values per op.
  void RunPlain(Eigen::VectorXd* yhat, double* tape) {
    Set& s = sets_[0];
    Vec z = Vec::Zero(n());
    const Output* out = nullptr;
    double* const tape_start = tape;
    for (const ScheduleOp& op : sched_->ops) {
      switch (op.kind) {
        case ScheduleOp::kAdvance: {
          const StepCache& c = Cached(s, op.step, op.index >= 0, false);
          if (tape) tape = std::copy(z.data(), z.data() + n(), tape);
          Propagate(s, c, op.index, &z);
          break;
        }
        case ScheduleOp::kBolus:
          z += op.value * s.w.col(op.cmt);
          break;
        case ScheduleOp::kReset:
          z.setZero();
          break;
        case ScheduleOp::kSample:
          if (out == nullptr || out->cmt != op.cmt) out = &GetOutput(s, op.cmt);
          (*yhat)(op.index) = out->chat.dot(z);
          if (tape) tape = std::copy(z.data(), z.data() + n(), tape);
          break;
        case ScheduleOp::kSteadyState:
        case ScheduleOp::kSteadyInfusion:
          break;  // not in a simple schedule
      }
    }
    if (tape) tape_used_ = static_cast<size_t>(tape - tape_start);
  }

  void Run(Eigen::VectorXd* yhat, Eigen::MatrixXd* jac, std::vector<double>* tape) {
    const std::vector<ScheduleOp>& ops = sched_->ops;
    Vec z = Vec::Zero(n());
    Eigen::MatrixXd& sens = sens_;  // kept between runs for its storage
    if (jac) sens.setZero(n(), p_);
    for (size_t i = 0; i < ops.size(); ++i) {
      const ScheduleOp& op = ops[i];
      Set& s = sets_[op.set];
      if (i > 0 && ops[i - 1].set != op.set) {
        const Set& from = sets_[ops[i - 1].set];
        z = s.w * (from.v * z);
        if (jac) sens = s.w * (from.v * sens);
      }
      switch (op.kind) {
        case ScheduleOp::kAdvance:
          Step(s, op.step, op.index, &z, jac ? &sens : nullptr, tape);
          break;
        case ScheduleOp::kBolus:
          z += op.value * s.w.col(op.cmt);
          break;
        case ScheduleOp::kReset:
          z.setZero();
          if (jac) sens.setZero();
          break;
        case ScheduleOp::kSample: {
          const Output& o = GetOutput(s, op.cmt);
          (*yhat)(op.index) = o.chat.dot(z);
          if (tape) Push(z);
          if (jac) {
            for (int j = 0; j < p_; ++j) (*jac)(op.index, j) = o.chat.dot(sens.col(j));
            if (!o.dc.empty()) {
              const Vec x = s.v * z;
              for (const DTerm& d : o.dc) (*jac)(op.index, d.pos) += d.d * x(d.col);
            }
          }
          break;
        }
        case ScheduleOp::kSteadyInfusion: {
          const Vec& u = Uhat(s, op.index);
          const double scale = s.lambda.cwiseAbs().maxCoeff();
          if (!(s.lambda.cwiseAbs().minCoeff() > 1e-13 * scale)) {
            throw NumericalFailure("no steady state for a constant infusion");
          }
          const Vec zs = -u.cwiseQuotient(s.lambda);
          Eigen::MatrixXd ss;
          if (jac) {
            // ∂z = −A⁻¹ Σ_j ∂A/∂θ_j z ∂θ_j/∂p, i.e. −Λ⁻¹ Â_j ẑ in modal coordinates.
            ss = Eigen::MatrixXd::Zero(n(), p_);
            for (size_t act = 0; act < s.active.size(); ++act) {
              ss.col(s.active[act].second) -= (s.ahat[act] * zs).cwiseQuotient(s.lambda);
            }
          }
          SetOrAdd(zs, ss, op.add, &z, jac ? &sens : nullptr);
          break;
        }
        case ScheduleOp::kSteadyState:
          SteadyState(s, sched_->cycles[op.index], op.add, &z, jac ? &sens : nullptr, tape);
          break;
      }
    }
  }

  static void SetOrAdd(const Vec& z, const Eigen::MatrixXd& sz, bool add, Vec* state, Eigen::MatrixXd* sens) {
    if (add) {
      *state += z;
      if (sens) *sens += sz;
    } else {
      *state = z;
      if (sens) *sens = sz;
    }
  }

  // One period maps z to m ∘ (z + b̂) + w; its fixed point is z* = (m ∘ b̂ + w) / (1 − m).
  void SteadyState(Set& s, const ScheduleCycle& cycle, bool add, Vec* state, Eigen::MatrixXd* sens,
                   std::vector<double>* tape) {
    const Vec b = cycle.bolus * s.w.col(cycle.cmt);
    Vec r = b, m = Vec::Ones(n());
    for (const ScheduleSegment& seg : cycle.period) {
      Step(s, seg.step, seg.input, &r, nullptr, nullptr);
      m = m.cwiseProduct(s.steps[seg.step].e);
    }
    if (!((Vec::Ones(n()) - m).minCoeff() > 1e-13)) {
      throw NumericalFailure(
          "no steady state: the dosing-interval map has an eigenvalue at 1 (is drug eliminated from every "
          "compartment it reaches?)");
    }
    const Vec x_star = r.cwiseQuotient(Vec::Ones(n()) - m);
    Eigen::MatrixXd s_star;
    if (sens || tape) {
      // ∂_p P at z* (route a) or the period's tape (route b), from z* + b̂.
      Vec x = x_star + b;
      if (sens) s_star = Eigen::MatrixXd::Zero(n(), p_);
      for (const ScheduleSegment& seg : cycle.period) Step(s, seg.step, seg.input, &x, sens ? &s_star : nullptr, tape);
      // Implicit function theorem: Ŝ* = (I − m)⁻¹ ∂_p P.
      if (sens) s_star = (s_star.array().colwise() / (Vec::Ones(n()) - m).array()).matrix();
    }
    Vec z = x_star + b;
    for (const ScheduleSegment& seg : cycle.to_record) Step(s, seg.step, seg.input, &z, sens ? &s_star : nullptr, tape);
    if (tape) Push(m);
    SetOrAdd(z, s_star, add, state, sens);
  }

  const LinearModel& model_;
  const EventSchedule* sched_ = nullptr;
  const int n_;
  int p_ = 0;
  std::vector<Set> sets_;
  bool simple_ = false;       // one parameter set, no steady states (RunPlain)
  unsigned generation_ = 0;   // Resets so far (StepCache's marks; a fresh cache's 0 is never current)
  std::vector<int> act_of_;   // Reset's scratch: the active index of each θ_j (-1: fixed)
  std::vector<double> tape_;  // route (b)'s record of the forward pass: tape_used_ entries
  size_t tape_used_ = 0;
  Eigen::MatrixXd sens_;      // route (a)'s Ŝ during Run
  Mat step_weights_;          // StepWithSensitivities' W (kept for its storage)
  Eigen::VectorXd grad_;      // Contract's sums (kept for its storage)
};

}  // namespace modal_detail

/// A modal evaluator with its size fixed at compile time, for 2 to 4 states
/// (modal_fixed.cc); null for other sizes.
std::unique_ptr<ModalEvaluator> NewFixedSizeModal(const LinearModel& model);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_EXACT_MODAL_EVALUATOR_H_
