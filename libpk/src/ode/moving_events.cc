// Higher-order sensitivities on the ODE propagator when doses move with p: the event engine and the
// state on HyperDual3 jets (moving_events.h).
#include "moving_events.h"

#include <functional>
#include <limits>

#include <Eigen/LU>

#include "../hyper_dual_sets.h"
#include "../numerical_failure.h"
#include "rk_solver.h"
#include "second_order.h"

namespace pk {
namespace internal {
namespace {

using HD3 = HyperDual3;
using State = Eigen::VectorXd;  // the jet state: part s of compartment c at s·n + c

constexpr long kMaxSteps = 1000000;  // per segment, as second_order.cc

int Order(int part) { return (part & 1) + ((part >> 1) & 1) + ((part >> 2) & 1); }

class MovingOdeVisitor {
 public:
  MovingOdeVisitor(const OdeSubject& o, const std::vector<HyperDual3Vector>& sets, int parts, Eigen::VectorXd* out)
      : o_(o), model_(*o.system->nonlinear()), n_(o.system->n()), parts_(parts), out_(out) {
    const int m = o.system->num_theta();
    for (const HyperDual3Vector& set : sets) theta_.emplace_back(set.data(), set.data() + m);
    out->setZero(o.num_samples);
    z_ = State::Zero(n_ * parts_);
  }

  void Advance(const HD3& h, const HyperDual3Vector& u, int set) { Integrate(h, u, set, &z_); }
  void Bolus(int cmt, const HD3& amount, int) { AddBolus(cmt, amount, &z_); }
  void Reset() { z_.setZero(); }
  void DoseEntered(const HD3&, int) {}
  void SteadyState(const SteadyStateCycle<HD3>& cycle, int set, bool add);
  void SteadyInfusion(const HyperDual3Vector& u, int set, bool add);
  void RecordDone(int r, int set) {
    const int k = o_.sample_of_record[static_cast<size_t>(r)];
    if (k < 0) return;
    Unpack(z_, &xs_);
    const HD3 y = model_.OutputJet(o_.key_of_record[static_cast<size_t>(r)], xs_.data(), Theta(set));
    (*out_)(k) = y.part(parts_ - 1);
  }

 private:
  const HD3* Theta(int set) const { return theta_[static_cast<size_t>(set)].data(); }
  void Unpack(const State& z, std::vector<HD3>* x) const {
    x->assign(static_cast<size_t>(n_), HD3());
    for (int s = 0; s < parts_; ++s) {
      for (int c = 0; c < n_; ++c) (*x)[static_cast<size_t>(c)].part(s) = z(s * n_ + c);
    }
  }
  void AddBolus(int cmt, const HD3& amount, State* z) const {
    for (int s = 0; s < parts_; ++s) (*z)(s * n_ + cmt) += amount.part(s);
  }
  // *f = f(X, Θ) + U on jets.
  void Forcing(const State& z, int set, const HyperDual3Vector& u, std::vector<HD3>* f) const {
    Unpack(z, &xs_);
    f->resize(static_cast<size_t>(n_));
    model_.RhsJet(xs_.data(), Theta(set), f->data());
    for (int c = 0; c < n_; ++c) (*f)[static_cast<size_t>(c)] += u(c);
  }
  void Integrate(const HD3& h, const HyperDual3Vector& u, int set, State* z);
  void RunCycle(const SteadyStateCycle<HD3>& cycle, int set, State* z) {
    AddBolus(cycle.cmt, cycle.bolus, z);
    for (const Segment<HD3>& segment : cycle.period) Integrate(segment.duration, segment.rate, set, z);
  }
  Eigen::VectorXd PeriodicValue(const SteadyStateCycle<HD3>& cycle, int set, Eigen::PartialPivLU<Eigen::MatrixXd>* lu) const;
  void Place(const State& z, bool add) {
    if (add) {
      z_ += z;
    } else {
      z_ = z;
    }
  }

  const OdeSubject& o_;
  const OdeModel& model_;
  const int n_, parts_;
  Eigen::VectorXd* out_;
  std::vector<std::vector<HD3>> theta_;  // per set
  State z_;
  double last_step_ = 0;  // the last step proposal, in t (0: none yet)
  mutable std::vector<HD3> xs_, fs_;
};

// Over τ ∈ [0, 1]: dX/dτ = H (f(X) + U). The step proposal carries over in t, as second_order.cc's.
void MovingOdeVisitor::Integrate(const HD3& h, const HyperDual3Vector& u, int set, State* z) {
  if (IsExactlyZero(h)) return;
  const auto rhs = [&](const Eigen::VectorXd& y, Eigen::VectorXd* dy) {
    Forcing(y, set, u, &fs_);
    dy->resize(y.size());
    for (int c = 0; c < n_; ++c) {
      const HD3 d = h * fs_[static_cast<size_t>(c)];
      for (int s = 0; s < parts_; ++s) (*dy)(s * n_ + c) = d.part(s);
    }
  };
  const double length = h.value();
  double step = length > 0 && last_step_ > 0 ? last_step_ / length : 0;
  DormandPrinceTo(rhs, 1.0, o_.options.absolute_tolerance, o_.options.relative_tolerance, kMaxSteps, z, &step);
  if (length > 0 && step > 0) last_step_ = step * length;
}

// x* = P(x*) for the cycle's values by Newton, P_x from n directions in x₀ integrated with x; *lu
// holds I − P_x at x* on return (one more cycle there, as second_order.cc's PeriodicState).
Eigen::VectorXd MovingOdeVisitor::PeriodicValue(const SteadyStateCycle<HD3>& cycle, int set,
                                                Eigen::PartialPivLU<Eigen::MatrixXd>* lu) const {
  const int m = o_.system->num_theta();
  Eigen::VectorXd theta(m);
  for (int j = 0; j < m; ++j) theta(j) = theta_[static_cast<size_t>(set)][static_cast<size_t>(j)].value();
  const Eigen::MatrixXd in_x = Eigen::MatrixXd::Zero(m, n_);
  Eigen::VectorXd f, x = Eigen::VectorXd::Zero(n_);
  Eigen::MatrixXd df;
  const auto segment = [&](double h, const Eigen::VectorXd& u, State* z) {
    if (h <= 0) return;
    const auto rhs = [&](const Eigen::VectorXd& y, Eigen::VectorXd* dy) {
      model_.RhsDirectional(y.head(n_), theta, Eigen::Map<const Eigen::MatrixXd>(y.data() + n_, n_, n_), in_x, &f, &df);
      dy->resize(y.size());
      dy->head(n_) = f + u;
      Eigen::Map<Eigen::MatrixXd>(dy->data() + n_, n_, n_) = df;
    };
    double step = 0;
    DormandPrinceTo(rhs, h, o_.options.absolute_tolerance, o_.options.relative_tolerance, kMaxSteps, z, &step);
  };
  const auto values = [](const HyperDual3Vector& u) {
    Eigen::VectorXd v(u.size());
    for (Eigen::Index c = 0; c < u.size(); ++c) v(c) = u(c).value();
    return v;
  };
  double last = std::numeric_limits<double>::infinity();
  for (int it = 0, converged = 0;; ++it) {
    State z = State::Zero(n_ * (1 + n_));
    z.head(n_) = x;
    z(cycle.cmt) += cycle.bolus.value();
    Eigen::Map<Eigen::MatrixXd>(z.data() + n_, n_, n_).setIdentity();
    for (const Segment<HD3>& seg : cycle.period) segment(seg.duration.value(), values(seg.rate), &z);
    lu->compute(Eigen::MatrixXd::Identity(n_, n_) - Eigen::Map<const Eigen::MatrixXd>(z.data() + n_, n_, n_));
    if (converged) return x;
    const Eigen::VectorXd dx = lu->solve(Eigen::VectorXd(z.head(n_) - x));
    if (!dx.allFinite()) throw NumericalFailure("no periodic steady state (I − P_x is singular)");
    x += dx;
    const double step = dx.lpNorm<Eigen::Infinity>(), tolerance = NewtonTolerance(o_.options, x);
    converged = it > 0 && (step <= tolerance || NewtonAtNoise(step, last, tolerance, x.lpNorm<Eigen::Infinity>()));
    last = step;
    if (!converged && it >= o_.options.max_newton_iterations) {
      throw NumericalFailure("no periodic steady state for the higher-order sensitivities: Newton did not converge");
    }
  }
}

void MovingOdeVisitor::SteadyState(const SteadyStateCycle<HD3>& cycle, int set, bool add) {
  Eigen::PartialPivLU<Eigen::MatrixXd> lu;  // of I − P_x
  State zs = State::Zero(n_ * parts_);
  zs.head(n_) = PeriodicValue(cycle, set, &lu);
  const int orders = parts_ == 4 ? 2 : 3;
  for (int order = 1; order <= orders; ++order) {  // this order's parts from one cycle with them at 0
    State cycled = zs;
    RunCycle(cycle, set, &cycled);
    for (int s = 1; s < parts_; ++s) {
      if (Order(s) == order) zs.segment(s * n_, n_) = lu.solve(Eigen::VectorXd(cycled.segment(s * n_, n_)));
    }
  }
  AddBolus(cycle.cmt, cycle.bolus, &zs);
  for (const Segment<HD3>& segment : cycle.to_record) Integrate(segment.duration, segment.rate, set, &zs);
  Place(zs, add);
}

void MovingOdeVisitor::SteadyInfusion(const HyperDual3Vector& u, int set, bool add) {
  const int m = o_.system->num_theta();
  Eigen::VectorXd theta(m), u0(n_);
  for (int j = 0; j < m; ++j) theta(j) = theta_[static_cast<size_t>(set)][static_cast<size_t>(j)].value();
  for (int c = 0; c < n_; ++c) u0(c) = u(c).value();
  Eigen::FullPivLU<Eigen::MatrixXd> lu;  // of f_x at x*
  State z = State::Zero(n_ * parts_);
  z.head(n_) = InfusionSteadyState(model_, o_.options, theta, u0, &lu);
  const int orders = parts_ == 4 ? 2 : 3;
  for (int order = 1; order <= orders; ++order) {  // 0 = f_x X_S + (part S of f(X) + U with X_S = 0)
    Forcing(z, set, u, &fs_);
    for (int s = 1; s < parts_; ++s) {
      if (Order(s) != order) continue;
      Eigen::VectorXd forcing(n_);
      for (int c = 0; c < n_; ++c) forcing(c) = fs_[static_cast<size_t>(c)].part(s);
      z.segment(s * n_, n_) = -lu.solve(forcing);
    }
  }
  Place(z, add);
}

}  // namespace

void OdeMovingEventDerivatives(const OdeSubject& o, const PreparedSubject& s, const std::vector<DualVector>& sets,
                               int num_free, const std::vector<std::array<int, 3>>& directions,
                               std::vector<Eigen::VectorXd>* out) {
  CheckHigherOrderRoute(o);
  out->clear();
  for (const std::array<int, 3>& dir : directions) {
    for (int i : dir) {
      if (i >= num_free) throw NumericalFailure("a direction names no free parameter");
    }
    std::vector<HyperDual3Vector> seeded;
    for (const DualVector& set : sets) seeded.push_back(SeedAlong(*o.layout, set, dir));
    Eigen::VectorXd y;
    MovingOdeVisitor visitor(o, seeded, JetParts(dir), &y);
    EventEngine<HD3, MovingOdeVisitor> engine(s, *o.layout, seeded, &visitor);
    engine.Run();
    out->push_back(std::move(y));
  }
}

}  // namespace internal
}  // namespace pk
