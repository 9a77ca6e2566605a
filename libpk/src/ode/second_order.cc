// Second-order sensitivities on the ODE propagator: the stacked system of second_order.h, stepped
// by Dormand–Prince 5(4) (rk_solver.h's DormandPrinceTo) between the event engine's events.
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

constexpr long kMaxSteps = 1000000;  // per segment: a stiff segment takes many explicit steps, not this many

// The event engine's visitor: z = [x; s_1 … s_p; w_1 … w_P] (each block n long) through the events,
// and ∂²ŷ at the samples.
class SecondOrderVisitor {
 public:
  SecondOrderVisitor(const OdeSubject& o, const std::vector<DualVector>& sets, int num_free,
                     const std::vector<std::pair<int, int>>& pairs, std::vector<Eigen::VectorXd>* out)
      : o_(o),
        model_(*o.system->nonlinear()),
        n_(o.system->n()),
        m_(o.system->num_theta()),
        p_(num_free),
        pairs_(pairs),
        out_(out),
        z_(State::Zero(n_ * (1 + p_ + static_cast<int>(pairs.size())))) {
    for (const DualVector& set : sets) {
      theta_.push_back(Values(set, m_));
      dtheta_.push_back(DerivativeMatrix(set, p_, m_));
    }
    out->assign(pairs.size(), Eigen::VectorXd::Zero(o.num_samples));
  }

  void Advance(double h, const Eigen::VectorXd& u, int set) {
    Integrate(h, u, Stack{theta_[static_cast<size_t>(set)], dtheta_[static_cast<size_t>(set)], pairs_}, &z_,
              &last_step_);
  }
  void Bolus(int cmt, double amount, int) { z_(cmt) += amount; }  // s and w do not jump: amounts are free of p
  void Reset() { z_.setZero(); }
  void SteadyState(const SteadyStateCycle<double>& cycle, int set, bool add);
  void SteadyInfusion(const Eigen::VectorXd& u, int set, bool add);
  void DoseEntered(double, int) {}
  void RecordDone(int r, int set) {
    const int k = o_.sample_of_record[static_cast<size_t>(r)];
    if (k < 0) return;
    const int key = o_.key_of_record[static_cast<size_t>(r)];
    const Eigen::VectorXd& theta = theta_[static_cast<size_t>(set)];
    const Stack stack{theta, dtheta_[static_cast<size_t>(set)], pairs_};
    const Eigen::VectorXd x = z_.head(n_);
    for (size_t i = 0; i < pairs_.size(); ++i) {
      (*out_)[i](k) = model_.OutputSecondDirectional(key, x, theta, Directions(z_, stack, i));
    }
  }

 private:
  // What a stacked state carries: c = dtheta.cols() first-order directions, each s_k seeded in θ by
  // column k of dtheta (zero for a direction in x0 alone), and the second-order pairs of them.
  struct Stack {
    const Eigen::VectorXd& theta;
    const Eigen::MatrixXd& dtheta;
    const std::vector<std::pair<int, int>>& pairs;
    int cols() const { return static_cast<int>(dtheta.cols()); }
    Eigen::Index size(int n) const { return n * (1 + cols() + static_cast<Eigen::Index>(pairs.size())); }
  };

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

  double Tolerance(const Eigen::VectorXd& x) const {
    return o_.options.relative_tolerance * x.lpNorm<Eigen::Infinity>() + o_.options.absolute_tolerance;
  }

  // z_ = (or +=) z, as the first-order propagator places a steady state (SS=1 replaces, SS=2 adds).
  void Place(const State& z, bool add) {
    if (add) {
      z_ += z;
    } else {
      z_ = z;
    }
  }

  // Pair i's directions in z, stacked as `stack` says.
  SecondDirections Directions(const State& z, const Stack& stack, size_t i) const {
    const auto [k, l] = stack.pairs[i];
    SecondDirections d;
    d.dx1 = z.data() + n_ * (1 + k);
    d.dx2 = z.data() + n_ * (1 + l);
    d.dtheta1 = stack.dtheta.col(k).data();
    d.dtheta2 = stack.dtheta.col(l).data();
    d.dx12 = z.data() + n_ * (1 + stack.cols() + static_cast<int>(i));
    return d;
  }

  // dz/dt: x' = f + u, s' = f_x s + f_θ θ_p (one tape sweep), w_kl' = f_x w_kl + f''[d_k, d_l].
  void Derivative(const State& z, const Stack& stack, const Eigen::VectorXd& u, State* dz) const {
    const int c = stack.cols();
    dz->resize(z.size());
    x_ = z.head(n_);
    s_ = Eigen::Map<const Eigen::MatrixXd>(z.data() + n_, n_, c);
    model_.RhsDirectional(x_, stack.theta, s_, stack.dtheta, &f_, &df_);
    dz->head(n_) = f_ + u;
    Eigen::Map<Eigen::MatrixXd>(dz->data() + n_, n_, c) = df_;
    for (size_t i = 0; i < stack.pairs.size(); ++i) {
      model_.RhsSecondDirectional(x_, stack.theta, Directions(z, stack, i), &f12_);
      dz->segment(n_ * (1 + c + static_cast<int>(i)), n_) = f12_;
    }
  }

  const OdeSubject& o_;
  const OdeModel& model_;
  const int n_, m_, p_;
  const std::vector<std::pair<int, int>>& pairs_;
  std::vector<Eigen::VectorXd>* out_;
  State z_;
  double last_step_ = 0;  // the last proposal of a step not cut short by a segment's end (0: none yet)
  std::vector<Eigen::VectorXd> theta_;   // per parameter set
  std::vector<Eigen::MatrixXd> dtheta_;  // ∂θ/∂p per set (m×p)
  const std::vector<std::pair<int, int>> no_pairs_;
  mutable Eigen::VectorXd x_, f_, f12_;  // scratch of Derivative
  mutable Eigen::MatrixXd s_, df_;
};


// The periodic steady state of the stacked system. The cycle's map P is nonlinear in x but, once x
// is at its fixed point x*, affine in s and in w with the same matrix P_x:
//   s(T) = P_x s(0) + b_s,   w(T) = P_x w(0) + b_w(s(0)),
// so s* = (I − P_x)⁻¹ b_s and w* = (I − P_x)⁻¹ b_w(s*). x* comes from Newton on x = P(x), P_x from
// n directions in x0 (zero in θ) integrated with x; b_s from the parameter directions started at 0.
// Then, as the first-order propagator does, the bolus and `to_record` carry [x*; s*; w*] to the
// record time.
void SecondOrderVisitor::SteadyState(const SteadyStateCycle<double>& cycle, int set, bool add) {
  const Eigen::VectorXd& theta = theta_[static_cast<size_t>(set)];
  const Eigen::MatrixXd& dtheta = dtheta_[static_cast<size_t>(set)];
  Eigen::MatrixXd both = Eigen::MatrixXd::Zero(m_, n_ + p_);  // [x0 directions | parameter directions]
  both.rightCols(p_) = dtheta;
  const Stack first{theta, both, no_pairs_};
  Eigen::VectorXd x = Eigen::VectorXd::Zero(n_);
  State z;
  Eigen::PartialPivLU<Eigen::MatrixXd> lu;  // of I − P_x
  // Newton stops at a step of the integration's tolerance and then runs one more cycle, at the x it
  // landed on, so that P_x and b_s belong to x* itself.
  double last = INFINITY;  // the previous Newton step
  for (int it = 0, converged = 0;; ++it) {
    z = State::Zero(first.size(n_));
    z.head(n_) = x;
    Eigen::Map<Eigen::MatrixXd>(z.data() + n_, n_, n_).setIdentity();
    RunCycle(cycle, first, &z);
    lu.compute(Eigen::MatrixXd::Identity(n_, n_) - Eigen::Map<const Eigen::MatrixXd>(z.data() + n_, n_, n_));
    if (converged) break;
    const Eigen::VectorXd dx = lu.solve(Eigen::VectorXd(z.head(n_) - x));
    if (!dx.allFinite()) throw NumericalFailure("no periodic steady state (I − P_x is singular)");
    x += dx;
    // At a step of the tolerance, or (as the first-order propagator judges) at the integration's
    // noise: a small step that fails to halve the one before.
    const double step = dx.lpNorm<Eigen::Infinity>();
    converged = it > 0 && (step <= Tolerance(x) ||
                           (step >= 0.5 * last && step <= std::sqrt(Tolerance(x) * x.lpNorm<Eigen::Infinity>())));
    last = step;
    if (!converged && it >= o_.options.max_newton_iterations) {
      throw NumericalFailure("no periodic steady state for the second-order sensitivities: Newton did not converge");
    }
  }
  const Stack stack{theta, dtheta, pairs_};
  State zs = State::Zero(stack.size(n_));
  zs.head(n_) = x;
  Eigen::Map<Eigen::MatrixXd>(zs.data() + n_, n_, p_) = lu.solve(Eigen::Map<const Eigen::MatrixXd>(z.data() + n_ * (1 + n_), n_, p_));
  State w = zs;  // w(0) = 0: one cycle gives b_w(s*) in the w blocks (and s* again in the s blocks)
  RunCycle(cycle, stack, &w);
  const Eigen::Index tail = n_ * static_cast<Eigen::Index>(pairs_.size());
  const auto np = static_cast<Eigen::Index>(pairs_.size());
  Eigen::Map<Eigen::MatrixXd>(zs.data() + zs.size() - tail, n_, np) =
      lu.solve(Eigen::Map<const Eigen::MatrixXd>(w.data() + w.size() - tail, n_, np));
  zs(cycle.cmt) += cycle.bolus;
  double last_step = 0;
  for (const Segment<double>& seg : cycle.to_record) Integrate(seg.duration, seg.rate, stack, &zs, &last_step);
  Place(zs, add);
}

// The steady state of constant rates u: f(x*) + u = 0 by Newton, then from 0 = f_x s + f_θ θ_p and
// 0 = f_x w + f''[d_k, d_l], s* = −f_x⁻¹ f_θ θ_p and w* = −f_x⁻¹ f''[d_k, d_l].
void SecondOrderVisitor::SteadyInfusion(const Eigen::VectorXd& u, int set, bool add) {
  const Eigen::VectorXd& theta = theta_[static_cast<size_t>(set)];
  const Eigen::MatrixXd& dtheta = dtheta_[static_cast<size_t>(set)];
  const Eigen::MatrixXd identity = Eigen::MatrixXd::Identity(n_, n_), in_x = Eigen::MatrixXd::Zero(m_, n_);
  Eigen::VectorXd x = Eigen::VectorXd::Zero(n_), f;
  Eigen::MatrixXd fx;
  Eigen::FullPivLU<Eigen::MatrixXd> lu;
  for (int it = 0;; ++it) {
    model_.RhsDirectional(x, theta, identity, in_x, &f, &fx);
    lu.compute(fx);
    if (!lu.isInvertible()) throw NumericalFailure("no steady state for the constant infusion (f_x is singular)");
    const Eigen::VectorXd dx = lu.solve(Eigen::VectorXd(f + u));
    x -= dx;
    if (!x.allFinite()) throw NumericalFailure("no steady state for the constant infusion");
    if (dx.lpNorm<Eigen::Infinity>() <= Tolerance(x)) break;
    if (it >= o_.options.max_newton_iterations) {
      throw NumericalFailure("no steady state for the constant infusion: Newton did not converge");
    }
  }
  model_.RhsDirectional(x, theta, identity, in_x, &f, &fx);
  lu.compute(fx);
  const Stack stack{theta, dtheta, pairs_};
  State z = State::Zero(stack.size(n_));
  z.head(n_) = x;
  Eigen::MatrixXd forcing;
  model_.RhsDirectional(x, theta, Eigen::MatrixXd::Zero(n_, p_), dtheta, &f, &forcing);
  Eigen::Map<Eigen::MatrixXd>(z.data() + n_, n_, p_) = -lu.solve(forcing);
  for (size_t i = 0; i < pairs_.size(); ++i) {  // w = 0 in z: RhsSecondDirectional gives f''[d_k, d_l]
    model_.RhsSecondDirectional(x, theta, Directions(z, stack, i), &f12_);
    z.segment(n_ * (1 + p_ + static_cast<Eigen::Index>(i)), n_) = -lu.solve(f12_);
  }
  Place(z, add);
}

}  // namespace

void OdeSecondOrderSensitivities(const OdeSubject& o, const PreparedSubject& s, const std::vector<DualVector>& sets,
                                 int num_free, const std::vector<std::pair<int, int>>& pairs,
                                 std::vector<Eigen::VectorXd>* out) {
  if (o.system->nonlinear() == nullptr) {
    throw NumericalFailure("second-order sensitivities on the ODE propagator serve nonlinear models");
  }
  if (!o.continuous.series.empty()) {
    throw NumericalFailure("second-order sensitivities do not cover continuous records (CONT=1)");
  }
  for (const auto& [k, l] : pairs) {
    if (k < 0 || k >= num_free || l < 0 || l >= num_free) throw NumericalFailure("a pair names no free parameter");
  }
  SecondOrderVisitor visitor(o, sets, num_free, pairs, out);
  EventEngine<double, SecondOrderVisitor> engine(s, *o.layout, s.sets, &visitor);
  engine.Run();
}

}  // namespace internal
}  // namespace pk
