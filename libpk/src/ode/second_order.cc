// Second- and third-order sensitivities on the ODE propagator: the stacked systems of
// second_order.h, stepped by Dormand–Prince 5(4) (rk_solver.h's DormandPrinceTo) between the
// event engine's events.
#include "second_order.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <string>

#include <Eigen/LU>

#include "../numerical_failure.h"
#include "rk_solver.h"

namespace pk {
namespace internal {
namespace {

using State = Eigen::VectorXd;
using Pair = std::pair<int, int>;
using Triple = std::array<int, 3>;

constexpr long kMaxSteps = 1000000;  // per segment: a stiff segment takes many explicit steps, not this many

// What a stacked state z = [x; s_1 … s_c; w_1 … w_P; z_1 … z_T] carries (each block n long): c
// first-order directions, s_k seeded in θ by column k of dtheta (zero for a direction in x0 alone),
// second-order pairs of them, and third-order triples, each triple's pairs (ij, ik, jk) at the
// positions `triple_pairs` gives in `pairs`.
struct Stack {
  const Eigen::VectorXd& theta;
  const Eigen::MatrixXd& dtheta;
  const std::vector<Pair>& pairs;
  const std::vector<Triple>& triples;
  const std::vector<Triple>& triple_pairs;
  int cols() const { return static_cast<int>(dtheta.cols()); }
  Eigen::Index pair_at(int n, size_t i) const { return n * (1 + cols() + static_cast<Eigen::Index>(i)); }
  Eigen::Index triple_at(int n, size_t t) const { return pair_at(n, pairs.size() + t); }
  Eigen::Index size(int n) const { return triple_at(n, triples.size()); }
};

// The event engine's visitor: the stacked state through the events, and ∂²ŷ (pairs) and ∂³ŷ
// (triples) at the samples.
class HigherOrderVisitor {
 public:
  HigherOrderVisitor(const OdeSubject& o, const std::vector<DualVector>& sets, int num_free,
                     const std::vector<Pair>& pairs, const std::vector<Triple>& triples,
                     const std::vector<Triple>& triple_pairs, std::vector<Eigen::VectorXd>* second,
                     std::vector<Eigen::VectorXd>* third)
      : o_(o),
        model_(*o.system->nonlinear()),
        n_(o.system->n()),
        m_(o.system->num_theta()),
        p_(num_free),
        pairs_(pairs),
        triples_(triples),
        triple_pairs_(triple_pairs),
        second_(second),
        third_(third) {
    for (const DualVector& set : sets) {
      theta_.push_back(Values(set, m_));
      dtheta_.push_back(DerivativeMatrix(set, p_, m_));
    }
    z_ = State::Zero(n_ * (1 + p_ + static_cast<Eigen::Index>(pairs.size() + triples.size())));
    if (second) second->assign(pairs.size(), Eigen::VectorXd::Zero(o.num_samples));
    if (third) third->assign(triples.size(), Eigen::VectorXd::Zero(o.num_samples));
  }

  void Advance(double h, const Eigen::VectorXd& u, int set) { Integrate(h, u, Full(set), &z_, &last_step_); }
  void Bolus(int cmt, double amount, int) { z_(cmt) += amount; }  // s, w, z do not jump: amounts are free of p
  void Reset() { z_.setZero(); }
  void SteadyState(const SteadyStateCycle<double>& cycle, int set, bool add);
  void SteadyInfusion(const Eigen::VectorXd& u, int set, bool add);
  void DoseEntered(double, int) {}
  void RecordDone(int r, int set) {
    const int k = o_.sample_of_record[static_cast<size_t>(r)];
    if (k < 0) return;
    const int key = o_.key_of_record[static_cast<size_t>(r)];
    const Stack stack = Full(set);
    const Eigen::VectorXd x = z_.head(n_);
    for (size_t i = 0; second_ && i < pairs_.size(); ++i) {
      (*second_)[i](k) = model_.OutputSecondDirectional(key, x, stack.theta, PairDirections(z_, stack, i));
    }
    for (size_t t = 0; third_ && t < triples_.size(); ++t) {
      (*third_)[t](k) = model_.OutputThirdDirectional(key, x, stack.theta, TripleDirections(z_, stack, t));
    }
  }

 private:
  Stack Full(int set) const {
    return Stack{theta_[static_cast<size_t>(set)], dtheta_[static_cast<size_t>(set)], pairs_, triples_, triple_pairs_};
  }

  void Integrate(double h, const Eigen::VectorXd& u, const Stack& stack, State* z, double* last_step) const {
    if (h <= 0) return;
    const auto rhs = [&](const Eigen::VectorXd& y, Eigen::VectorXd* dy) { Derivative(y, stack, u, dy); };
    DormandPrinceTo(rhs, h, o_.options.absolute_tolerance, o_.options.relative_tolerance, kMaxSteps, z, last_step);
  }

  // One dosing cycle of the stacked state: the bolus (into x alone), then the period's segments.
  void RunCycle(const SteadyStateCycle<double>& cycle, const Stack& stack, State* z) const {
    (*z)(cycle.cmt) += cycle.bolus;
    double last_step = 0;
    for (const Segment<double>& seg : cycle.period) Integrate(seg.duration, seg.rate, stack, z, &last_step);
  }

  // z_ = (or +=) z, as the first-order propagator places a steady state (SS=1 replaces, SS=2 adds).
  void Place(const State& z, bool add) {
    if (add) {
      z_ += z;
    } else {
      z_ = z;
    }
  }

  Eigen::VectorXd PeriodicState(const SteadyStateCycle<double>& cycle, const Eigen::VectorXd& theta,
                                const Eigen::MatrixXd& dtheta, Eigen::PartialPivLU<Eigen::MatrixXd>* lu,
                                State* z) const;

  // Pair i's directions in z.
  SecondDirections PairDirections(const State& z, const Stack& stack, size_t i) const {
    const auto [k, l] = stack.pairs[i];
    SecondDirections d;
    d.dx1 = z.data() + n_ * (1 + k);
    d.dx2 = z.data() + n_ * (1 + l);
    d.dtheta1 = stack.dtheta.col(k).data();
    d.dtheta2 = stack.dtheta.col(l).data();
    d.dx12 = z.data() + stack.pair_at(n_, i);
    return d;
  }

  // Triple t's directions in z, by HyperDual3's masks.
  ThirdDirections TripleDirections(const State& z, const Stack& stack, size_t t) const {
    const Triple& ijk = stack.triples[t];
    const Triple& pairs = stack.triple_pairs[t];
    ThirdDirections d;
    for (int c = 0; c < 3; ++c) {
      d.dx[1 << c] = z.data() + n_ * (1 + ijk[static_cast<size_t>(c)]);
      d.dtheta[1 << c] = stack.dtheta.col(ijk[static_cast<size_t>(c)]).data();
    }
    d.dx[3] = z.data() + stack.pair_at(n_, static_cast<size_t>(pairs[0]));
    d.dx[5] = z.data() + stack.pair_at(n_, static_cast<size_t>(pairs[1]));
    d.dx[6] = z.data() + stack.pair_at(n_, static_cast<size_t>(pairs[2]));
    d.dx[7] = z.data() + stack.triple_at(n_, t);
    return d;
  }

  // dz/dt: x' = f + u, s' = f_x s + f_θ θ_p (one tape sweep), w_kl' = f_x w_kl + f''[d_k, d_l], and
  // a triple's the ε₁ε₂ε₃ part of f on the third-order hyper-dual state.
  void Derivative(const State& z, const Stack& stack, const Eigen::VectorXd& u, State* dz) const {
    const int c = stack.cols();
    dz->resize(z.size());
    x_ = z.head(n_);
    s_ = Eigen::Map<const Eigen::MatrixXd>(z.data() + n_, n_, c);
    model_.RhsDirectional(x_, stack.theta, s_, stack.dtheta, &f_, &df_);
    dz->head(n_) = f_ + u;
    Eigen::Map<Eigen::MatrixXd>(dz->data() + n_, n_, c) = df_;
    for (size_t i = 0; i < stack.pairs.size(); ++i) {
      model_.RhsSecondDirectional(x_, stack.theta, PairDirections(z, stack, i), &f12_);
      dz->segment(stack.pair_at(n_, i), n_) = f12_;
    }
    for (size_t t = 0; t < stack.triples.size(); ++t) {
      model_.RhsThirdDirectional(x_, stack.theta, TripleDirections(z, stack, t), &f12_);
      dz->segment(stack.triple_at(n_, t), n_) = f12_;
    }
  }

  const OdeSubject& o_;
  const OdeModel& model_;
  const int n_, m_, p_;
  const std::vector<Pair>& pairs_;
  const std::vector<Triple>& triples_;
  const std::vector<Triple>& triple_pairs_;
  std::vector<Eigen::VectorXd>* second_;
  std::vector<Eigen::VectorXd>* third_;
  State z_;
  double last_step_ = 0;  // the last proposal of a step not cut short by a segment's end (0: none yet)
  std::vector<Eigen::VectorXd> theta_;   // per parameter set
  std::vector<Eigen::MatrixXd> dtheta_;  // ∂θ/∂p per set (m×p)
  const std::vector<Pair> no_pairs_;
  const std::vector<Triple> no_triples_;
  mutable Eigen::VectorXd x_, f_, f12_;  // scratch of Derivative
  mutable Eigen::MatrixXd s_, df_;
};

// x* = P(x*) by Newton, with P_x from n directions in x0 (zero in θ) integrated with x and the
// parameter directions started at 0 beside them: on return *lu holds I − P_x at x* and *z the
// cycle from [x*; [I 0]], whose parameter columns are b_s. Newton stops at a step of the
// integration's tolerance, or at the integration's noise (NewtonAtNoise, as the first-order
// propagator judges it); one more cycle then runs at the x it landed on, so
// that P_x and b_s belong to x* itself.
Eigen::VectorXd HigherOrderVisitor::PeriodicState(const SteadyStateCycle<double>& cycle, const Eigen::VectorXd& theta,
                                                  const Eigen::MatrixXd& dtheta,
                                                  Eigen::PartialPivLU<Eigen::MatrixXd>* lu, State* z) const {
  Eigen::MatrixXd both = Eigen::MatrixXd::Zero(m_, n_ + p_);  // [x0 directions | parameter directions]
  both.rightCols(p_) = dtheta;
  const Stack first{theta, both, no_pairs_, no_triples_, no_triples_};
  Eigen::VectorXd x = Eigen::VectorXd::Zero(n_);
  double last = INFINITY;  // the previous Newton step
  for (int it = 0, converged = 0;; ++it) {
    *z = State::Zero(first.size(n_));
    z->head(n_) = x;
    Eigen::Map<Eigen::MatrixXd>(z->data() + n_, n_, n_).setIdentity();
    RunCycle(cycle, first, z);
    lu->compute(Eigen::MatrixXd::Identity(n_, n_) - Eigen::Map<const Eigen::MatrixXd>(z->data() + n_, n_, n_));
    if (converged) return x;
    const Eigen::VectorXd dx = lu->solve(Eigen::VectorXd(z->head(n_) - x));
    if (!dx.allFinite()) throw NumericalFailure("no periodic steady state (I − P_x is singular)");
    x += dx;
    const double step = dx.lpNorm<Eigen::Infinity>();
    const double tolerance = NewtonTolerance(o_.options, x);
    converged = it > 0 && (step <= tolerance || NewtonAtNoise(step, last, tolerance, x.lpNorm<Eigen::Infinity>()));
    last = step;
    if (!converged && it >= o_.options.max_newton_iterations) {
      throw NumericalFailure("no periodic steady state for the higher-order sensitivities: Newton did not converge");
    }
  }
}

// The periodic steady state of the stacked system. The cycle's map P is nonlinear in x but, once x
// is at its fixed point x*, affine in each higher block with the one matrix P_x:
//   s(T) = P_x s(0) + b_s,   w(T) = P_x w(0) + b_w(s(0)),   z(T) = P_x z(0) + b_z(s(0), w(0)),
// so s* = (I − P_x)⁻¹ b_s, w* = (I − P_x)⁻¹ b_w(s*) and z* = (I − P_x)⁻¹ b_z(s*, w*): one cycle per
// order after Newton's. Then, as the first-order propagator does, the bolus and `to_record` carry
// the stacked state from the fixed point to the record time.
void HigherOrderVisitor::SteadyState(const SteadyStateCycle<double>& cycle, int set, bool add) {
  const Stack stack = Full(set);
  Eigen::PartialPivLU<Eigen::MatrixXd> lu;  // of I − P_x
  State first;
  State zs = State::Zero(stack.size(n_));
  zs.head(n_) = PeriodicState(cycle, stack.theta, stack.dtheta, &lu, &first);
  Eigen::Map<Eigen::MatrixXd>(zs.data() + n_, n_, p_) =
      lu.solve(Eigen::Map<const Eigen::MatrixXd>(first.data() + n_ * (1 + n_), n_, p_));
  // Each order's block from one cycle started with it at 0 and the lower orders at their fixed points.
  const auto solve_block = [&](Eigen::Index at, Eigen::Index count) {
    if (count == 0) return;
    State cycled = zs;
    RunCycle(cycle, stack, &cycled);
    Eigen::Map<Eigen::MatrixXd>(zs.data() + at, n_, count) =
        lu.solve(Eigen::Map<const Eigen::MatrixXd>(cycled.data() + at, n_, count));
  };
  solve_block(stack.pair_at(n_, 0), static_cast<Eigen::Index>(pairs_.size()));
  solve_block(stack.triple_at(n_, 0), static_cast<Eigen::Index>(triples_.size()));
  zs(cycle.cmt) += cycle.bolus;
  double last_step = 0;
  for (const Segment<double>& seg : cycle.to_record) Integrate(seg.duration, seg.rate, stack, &zs, &last_step);
  Place(zs, add);
}

// The steady state of constant rates u: f(x*) + u = 0 by Newton, then from 0 = f_x s + f_θ θ_p,
// 0 = f_x w + f''[d_k, d_l] and 0 = f_x z + (z's forcing), each block is −f_x⁻¹ times its forcing:
// its derivative with the block itself at 0 and the lower orders at their steady states.
void HigherOrderVisitor::SteadyInfusion(const Eigen::VectorXd& u, int set, bool add) {
  const Stack stack = Full(set);
  Eigen::FullPivLU<Eigen::MatrixXd> lu;
  const Eigen::VectorXd x = InfusionSteadyState(model_, o_.options, stack.theta, u, &lu);
  Eigen::VectorXd f;
  State z = State::Zero(stack.size(n_));
  z.head(n_) = x;
  Eigen::MatrixXd forcing;
  model_.RhsDirectional(x, stack.theta, Eigen::MatrixXd::Zero(n_, p_), stack.dtheta, &f, &forcing);
  Eigen::Map<Eigen::MatrixXd>(z.data() + n_, n_, p_) = -lu.solve(forcing);
  for (size_t i = 0; i < pairs_.size(); ++i) {
    model_.RhsSecondDirectional(x, stack.theta, PairDirections(z, stack, i), &f12_);
    z.segment(stack.pair_at(n_, i), n_) = -lu.solve(f12_);
  }
  for (size_t t = 0; t < triples_.size(); ++t) {
    model_.RhsThirdDirectional(x, stack.theta, TripleDirections(z, stack, t), &f12_);
    z.segment(stack.triple_at(n_, t), n_) = -lu.solve(f12_);
  }
  Place(z, add);
}

}  // namespace

Eigen::VectorXd InfusionSteadyState(const OdeModel& model, const OdeOptions& options, const Eigen::VectorXd& theta,
                                    const Eigen::VectorXd& u, Eigen::FullPivLU<Eigen::MatrixXd>* lu) {
  const int n = model.num_compartments();
  const Eigen::MatrixXd identity = Eigen::MatrixXd::Identity(n, n), in_x = Eigen::MatrixXd::Zero(theta.size(), n);
  Eigen::VectorXd x = Eigen::VectorXd::Zero(n), f;
  Eigen::MatrixXd fx;
  for (int it = 0;; ++it) {
    model.RhsDirectional(x, theta, identity, in_x, &f, &fx);
    lu->compute(fx);
    if (!lu->isInvertible()) throw NumericalFailure("no steady state for the constant infusion (f_x is singular)");
    const Eigen::VectorXd dx = lu->solve(Eigen::VectorXd(f + u));
    x -= dx;
    if (!x.allFinite()) throw NumericalFailure("no steady state for the constant infusion");
    if (dx.lpNorm<Eigen::Infinity>() <= NewtonTolerance(options, x)) break;
    if (it >= options.max_newton_iterations) {
      throw NumericalFailure("no steady state for the constant infusion: Newton did not converge");
    }
  }
  model.RhsDirectional(x, theta, identity, in_x, &f, &fx);
  lu->compute(fx);
  return x;
}

void CheckHigherOrderRoute(const OdeSubject& o) {
  if (o.system->nonlinear() == nullptr) {
    throw NumericalFailure("higher-order sensitivities on the ODE propagator serve nonlinear models");
  }
  if (!o.continuous.series.empty()) {
    throw NumericalFailure("higher-order sensitivities do not cover continuous records (CONT=1)");
  }
}

void OdeSecondOrderSensitivities(const OdeSubject& o, const PreparedSubject& s, const std::vector<DualVector>& sets,
                                 int num_free, const std::vector<std::pair<int, int>>& pairs,
                                 std::vector<Eigen::VectorXd>* out) {
  CheckHigherOrderRoute(o);
  for (const auto& [k, l] : pairs) {
    if (k < 0 || k >= num_free || l < 0 || l >= num_free) throw NumericalFailure("a pair names no free parameter");
  }
  const std::vector<Triple> none;
  HigherOrderVisitor visitor(o, sets, num_free, pairs, none, none, out, nullptr);
  EventEngine<double, HigherOrderVisitor> engine(s, *o.layout, s.sets, &visitor);
  engine.Run();
}

void OdeThirdOrderSensitivities(const OdeSubject& o, const PreparedSubject& s, const std::vector<DualVector>& sets,
                                int num_free, const std::vector<std::array<int, 3>>& triples,
                                std::vector<Eigen::VectorXd>* out) {
  CheckHigherOrderRoute(o);
  // The pairs within the triples, each once, and where each triple finds its three.
  std::vector<Pair> pairs;
  std::vector<Triple> triple_pairs;
  const auto index = [&](int a, int b) {
    const Pair ab{std::min(a, b), std::max(a, b)};
    const auto it = std::find(pairs.begin(), pairs.end(), ab);
    if (it != pairs.end()) return static_cast<int>(it - pairs.begin());
    pairs.push_back(ab);
    return static_cast<int>(pairs.size()) - 1;
  };
  for (const Triple& t : triples) {
    for (int i : t) {
      if (i < 0 || i >= num_free) throw NumericalFailure("a triple names no free parameter");
    }
    triple_pairs.push_back({index(t[0], t[1]), index(t[0], t[2]), index(t[1], t[2])});
  }
  HigherOrderVisitor visitor(o, sets, num_free, pairs, triples, triple_pairs, nullptr, out);
  EventEngine<double, HigherOrderVisitor> engine(s, *o.layout, s.sets, &visitor);
  engine.Run();
}

}  // namespace internal
}  // namespace pk
