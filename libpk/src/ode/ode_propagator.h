// The ODE propagator (not installed): the EventEngine visitor that integrates
// between events with a SegmentSolver (CVODES, or Dormand–Prince), for either
// scalar type of the engine.
//
// On T = double it propagates x only. On T = Dual (P directions, the free
// parameters) it can also propagate the forward sensitivity S = ∂x/∂p
// (route (a), the seed's dx_θ/dt = f_x x_θ + f_θ):
//   within a segment   dS/dt = f_x S + f_θ ∂θ/∂p + ∂u/∂p        (CVODES)
//   at a bolus         S[c] += ∂(F·AMT)/∂p                      (a jump)
//   after a segment    S += (f(x⁺) + u) ∂h/∂p                   (moving event times)
// The last line is the lag term: a dose time τ that moves with p lengthens the
// segment before it and shortens the one after, which together give the
// seed's (f⁻ − f⁺)∂τ/∂p because f is autonomous between events.
//
// With `tape` on, it records every step for the adjoint sweep (ode_routes.h).
//
// A steady state is the periodic fixed point x* = P(x*) of the dosing-cycle
// map, found by Newton's method with P_x from n sensitivity directions, and
// differentiated by the implicit function theorem:
//   (I − P_x) ∂x*/∂p = ∂P/∂p.
// A steady constant infusion solves f(x*, θ) + u = 0, with
//   f_x ∂x*/∂p = −(f_θ ∂θ/∂p + ∂u/∂p).
#ifndef PK_SRC_ODE_ODE_PROPAGATOR_H_
#define PK_SRC_ODE_ODE_PROPAGATOR_H_

#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Dense>

#include "../autodiff.h"
#include "../events.h"
#include "numerical_failure.h"
#include "segment_solver.h"
#include "ode_system.h"

namespace pk {
namespace internal {

/// Whether Newton on a steady state has reached the integration's own noise: a step inside the
/// region of quadratic convergence (below √(tolerance·|x|)) that fails to halve the one before
/// (CVODES at rtol 1e-12 moves x* by about 10⁻¹⁰ from one cycle to the next, ten tolerances, and
/// Newton would wander there until its limit).
inline bool NewtonAtNoise(double step, double previous, double tolerance, double x_norm) {
  return step >= 0.5 * previous && step <= std::sqrt(tolerance * x_norm);
}

/// Continuous records (CONT=1 samples) of one subject: per output key, the
/// record times, values and weights per unit time, linearly interpolated.
struct ContinuousRecords {
  struct Series {
    int key = 1;
    std::vector<double> t, y, w;
  };
  std::vector<Series> series;

  bool empty() const { return series.empty(); }
  /// The terms active on [t0, t0 + h] (each segment lies between two records).
  std::vector<ContinuousTerm> Terms(double t0, double h) const;
};

/// One step of the forward pass, for the adjoint sweep.
struct TapeStep {
  enum Kind { kAdvance, kBolus, kReset, kSteadyState, kSteadyInfusion, kSample } kind = kReset;
  SegmentInput segment;       // kAdvance: with ∂θ/∂p and ∂u/∂p (P columns)
  Eigen::VectorXd x0, x1;     // kAdvance: state at the start and end; kSteady*: x*
  Eigen::RowVectorXd dh;      // kAdvance: ∂h/∂p
  int cmt = 0;                // kBolus
  Eigen::RowVectorXd damount; // kBolus: ∂(F·AMT)/∂p
  bool add = false;           // kSteady*: SS=2
  Eigen::MatrixXd jacobian;   // kSteadyState: P_x; kSteadyInfusion: f_x
  Eigen::MatrixXd forcing;    // kSteadyInfusion: f_θ ∂θ/∂p + ∂u/∂p (n×P)
  std::vector<TapeStep> cycle;      // kSteadyState: the cycle from x* (bolus, then segments)
  std::vector<TapeStep> to_record;  // kSteadyState: from x* to the record time
  int sample = -1, key = 0, set = 0;  // kSample
  int handle = -1;            // kAdvance: the solver's stored trajectory, or -1 (recompute)
};

template <typename T>
class OdePropagator {
 public:
  /// `integrator`: Propagator::kOde (CVODES) or kRungeKutta (Dormand–Prince).
  OdePropagator(const OdeSystem& sys, const std::vector<Vec<T>>& sets, int p, const OdeOptions& options,
                bool sensitivities, bool tape, bool track_auc, const ContinuousRecords* continuous = nullptr,
                Propagator integrator = Propagator::kOde)
      : sys_(sys),
        sets_(sets),
        set_values_(sets.size()),
        p_(p),
        n_(sys.n()),
        solver_(MakeSegmentSolver(sys, options, integrator, tape)),
        options_(options),
        sens_(sensitivities),
        tape_on_(tape),
        track_auc_(track_auc),
        continuous_(continuous != nullptr && !continuous->empty() ? continuous : nullptr) {
    x_ = Eigen::VectorXd::Zero(n_);
    s_ = Eigen::MatrixXd::Zero(n_, sens_ ? p_ : 0);
    dloss_ = Eigen::RowVectorXd::Zero(sens_ ? p_ : 0);
    dloss_time_ = Eigen::RowVectorXd::Zero(p_);
    dt_ = Eigen::RowVectorXd::Zero(p_);
  }

  // ---- EventEngine visitor interface ----
  void Advance(const T& h, const Vec<T>& u, int set) {
    SegmentInput seg = MakeSegment(h, u, set);
    const ContinuousRecords* cont = continuous_;
    const bool auc = track_auc_;
    if (cont) seg.continuous = cont->Terms(t_, seg.h);
    if (auc) seg.auc_key = sys_.central_key();
    TapeStep step;
    if (tape_on_) step.x0 = x_;
    const Eigen::RowVectorXd dh = Derivatives(h, p_).transpose();
    double loss_time = 0;
    if (sens_) {
      solver_->AdvanceSensitivity(seg, &x_, &s_, cont ? &loss_ : nullptr, &dloss_, &loss_time);
      s_ += FlowAtEnd(seg) * dh;
    } else if (tape_on_ && (options_.adjoint_store_all_segments || solver_->stores_every_segment()) &&
               seg.continuous.empty() && !auc) {
      step.handle = solver_->StoreSegment(seg, &x_);
    } else {
      solver_->Advance(seg, &x_, cont ? &loss_ : nullptr, auc ? &auc_ : nullptr, &loss_time);
    }
    if (!seg.continuous.empty() && p_ > 0) {
      // The loss integral ∫_{t0}^{t0+h} L(t, x) dt in the segment's own frame
      // misses what moving its ends does: L(t0+h)·∂h/∂p + ∂t0/∂p·∫L_t ds (the
      // state's part is already in S or in the adjoint's forcing).
      const double l_end = ContinuousLoss(sys_, seg, seg.h, x_);
      dloss_time_ += l_end * dh + loss_time * dt_;
    }
    t_ += seg.h;
    dt_ += dh;
    if (tape_on_) {
      step.kind = TapeStep::kAdvance;
      step.x1 = x_;
      step.dh = Derivatives(h, p_).transpose();
      step.segment = std::move(seg);
      tape_.push_back(std::move(step));
    }
  }

  void Bolus(int cmt, const T& amount, int /*set*/) {
    x_(cmt) += Value(amount);
    if (sens_) s_.row(cmt) += Derivatives(amount, p_).transpose();
    if (tape_on_) {
      TapeStep step;
      step.kind = TapeStep::kBolus;
      step.cmt = cmt;
      step.damount = Derivatives(amount, p_).transpose();
      tape_.push_back(std::move(step));
    }
  }

  void Reset() {
    x_.setZero();
    s_.setZero();
    if (tape_on_) {
      TapeStep step;
      step.kind = TapeStep::kReset;
      tape_.push_back(std::move(step));
    }
  }

  void SteadyInfusion(const Vec<T>& u, int set, bool add) {
    const Eigen::VectorXd theta = Values(sets_[set], sys_.num_theta());
    const Eigen::VectorXd uv = Values(u);
    Eigen::VectorXd x = Eigen::VectorXd::Zero(n_);
    Eigen::MatrixXd fx;
    for (int it = 0;; ++it) {
      Eigen::VectorXd f;
      sys_.Rhs(x, theta, &f);
      f += uv;
      fx = sys_.StateJacobian(x, theta);
      Eigen::FullPivLU<Eigen::MatrixXd> lu(fx);
      if (!lu.isInvertible()) throw NumericalFailure("no steady state for the constant infusion (f_x is singular: is the rate above the "
                               "elimination capacity, or is nothing eliminated?)");
      const Eigen::VectorXd dx = lu.solve(f);
      x -= dx;
      if (!x.allFinite()) throw NumericalFailure("no steady state for the constant infusion");
      if (dx.lpNorm<Eigen::Infinity>() <= Tolerance(x)) {
        fx = sys_.StateJacobian(x, theta);
        break;
      }
      if (it >= options_.max_newton_iterations) {
        throw NumericalFailure("no steady state for the constant infusion: Newton did not converge (is the rate "
                               "above the elimination capacity?)");
      }
    }
    CheckPhysical(x, "the constant infusion");
    const SegmentInput seg = MakeSegment(T(0.0), u, set);
    Eigen::VectorXd f;
    Eigen::MatrixXd forcing;
    sys_.RhsDirectional(x, theta, Eigen::MatrixXd::Zero(n_, p_), seg.dtheta, &f, &forcing);
    if (seg.du.cols() == forcing.cols()) forcing += seg.du;
    Place(x, sens_ ? Eigen::MatrixXd(-fx.fullPivLu().solve(forcing)) : Eigen::MatrixXd(), add);
    if (tape_on_) {
      TapeStep step;
      step.kind = TapeStep::kSteadyInfusion;
      step.x1 = x;
      step.jacobian = fx;
      step.forcing = forcing;
      step.add = add;
      tape_.push_back(std::move(step));
    }
  }

  void SteadyState(const SteadyStateCycle<T>& cycle, int set, bool add) {
    // Newton on x = P(x): directions are the n initial states, then (with
    // sensitivities) the P parameters. Newton needs only P_x; ∂P/∂p is needed
    // where it stops, so the parameter directions ride along only from an
    // iteration that may be the last: the second for a linear model (P is
    // affine, so the first lands on x*), else once the previous step was below
    // √(tolerance·|x|), from where quadratic convergence reaches the tolerance.
    Eigen::VectorXd x = Eigen::VectorXd::Zero(n_);
    Eigen::MatrixXd s;
    std::vector<TapeStep> steps;
    double last_step = INFINITY;
    bool with_parameters = false;
    for (int it = 0;; ++it) {
      with_parameters = sens_ && it > 0 &&
                        (sys_.is_linear() || last_step <= std::sqrt(Tolerance(x) * x.lpNorm<Eigen::Infinity>()));
      Eigen::VectorXd xp = x;
      s = Eigen::MatrixXd::Zero(n_, n_ + (with_parameters ? p_ : 0));
      s.leftCols(n_).setIdentity();
      steps.clear();
      RunCycle(cycle, set, &xp, &s, tape_on_ ? &steps : nullptr);
      Eigen::PartialPivLU<Eigen::MatrixXd> lu(Eigen::MatrixXd::Identity(n_, n_) - s.leftCols(n_));
      const Eigen::VectorXd dx = lu.solve(xp - x);
      if (!dx.allFinite()) {
        throw NumericalFailure("no periodic steady state (I − P_x is singular: " + CycleHint(x) + ")");
      }
      x += dx;
      const double step = dx.lpNorm<Eigen::Infinity>();
      // Newton stops once its step is at the integration tolerance: quadratic
      // convergence then leaves x* as accurate as the integration. Or once
      // the next update, about ρ|dx_k| with the contraction rate
      // ρ = |dx_k|/|dx_{k−1}| (as CVODES tests its own Newton iterations), is
      // below a thousandth of it. That saves a linear model its third cycle:
      // the first step lands on x*, the second is a few tolerances with ρ near
      // 1e-8. (With one tolerance instead of a thousandth, the error of x*,
      // which the steady-state gradient (I − P_x)⁻¹∂P/∂p amplifies, put the
      // forward and adjoint gradients of 2cmt_iv_mm at SS=1 1.3e-7 apart.)
      // Or once it is at the integration's own noise (NewtonAtNoise).
      const double rate = std::min(1.0, step / last_step);
      const bool stagnated =
          with_parameters && NewtonAtNoise(step, last_step, Tolerance(x), x.lpNorm<Eigen::Infinity>());
      last_step = step;
      const bool converged = step <= Tolerance(x) || rate * step <= 1e-3 * Tolerance(x) || stagnated;
      if (it > 0 && converged && (with_parameters || !sens_)) break;
      if (it >= options_.max_newton_iterations) {
        throw NumericalFailure("no periodic steady state: Newton on x = P(x) did not converge (" + CycleHint(x) + ")");
      }
    }
    CheckPhysical(x, "the dosing cycle");
    const Eigen::MatrixXd px = s.leftCols(n_);
    Eigen::MatrixXd dxdp = Eigen::MatrixXd::Zero(n_, sens_ ? p_ : 0);
    if (sens_) dxdp = (Eigen::MatrixXd::Identity(n_, n_) - px).partialPivLu().solve(s.rightCols(p_));
    TapeStep step;
    step.kind = TapeStep::kSteadyState;
    step.x1 = x;
    step.jacobian = px;
    step.add = add;
    step.cycle = std::move(steps);
    // From the fixed point (just before a cycle's bolus) to the record time.
    // This runs on the steady state alone: with SS=2 it is then added to the
    // state already present at the record time.
    std::vector<TapeStep>* to_record = tape_on_ ? &step.to_record : nullptr;
    Jump(cycle.cmt, cycle.bolus, 0, &x, &dxdp, to_record);
    for (const Segment<T>& seg : cycle.to_record) AdvanceAux(seg.duration, seg.rate, set, 0, &x, &dxdp, to_record);
    Place(x, dxdp, add);
    if (tape_on_) tape_.push_back(std::move(step));
  }

  void DoseEntered(const T&, int) {}
  void RecordDone(int, int) {}

  // ---- state ----
  const Eigen::VectorXd& state() const { return x_; }
  const Eigen::MatrixXd& sensitivity() const { return s_; }
  double auc() const { return auc_; }
  double continuous_loss() const { return loss_; }
  const Eigen::RowVectorXd& continuous_loss_gradient() const { return dloss_; }
  /// Record times are data: the time after a record carries no derivative.
  void set_time(double t) {
    t_ = t;
    dt_.setZero();
  }
  /// ∂/∂p of the continuous loss through moving segment ends (see Advance).
  const Eigen::RowVectorXd& continuous_loss_time_gradient() const { return dloss_time_; }
  std::vector<TapeStep>& tape() { return tape_; }
  void TapeSample(int sample, int key, int set) {
    if (!tape_on_) return;
    TapeStep step;
    step.kind = TapeStep::kSample;
    step.sample = sample;
    step.key = key;
    step.set = set;
    step.x1 = x_;
    tape_.push_back(std::move(step));
  }
  SegmentSolver& solver() { return *solver_; }
  /// θ of parameter set `set`, and ∂θ/∂p (m×P), formed once a set.
  const Eigen::VectorXd& SetTheta(int set) const { return Cached(set).theta; }
  const Eigen::MatrixXd& SetDtheta(int set) const { return *Cached(set).dtheta; }

  /// f(x(h)) + u at the end of a segment.
  Eigen::VectorXd FlowAtEnd(const SegmentInput& seg) const {
    Eigen::VectorXd f;
    sys_.Rhs(x_, seg.theta, &f);
    return f + seg.u;
  }

 private:
  // ∂u/∂p, with no columns when no rate has a derivative (a bolus regimen): solvers skip it then, and
  // an adjoint's segments do not carry an n×P block of zeros each.
  Eigen::MatrixXd InputDerivatives(const Vec<T>& u) const {
    for (Eigen::Index i = 0; i < u.size(); ++i) {
      if (HasDerivative(u(i))) return DerivativeMatrix(u, p_);
    }
    return Eigen::MatrixXd(u.size(), 0);
  }

  SegmentInput MakeSegment(const T& h, const Vec<T>& u, int set) const {
    SegmentInput seg;
    seg.h = Value(h);
    seg.u = Values(u);
    seg.du = InputDerivatives(u);
    seg.theta = SetTheta(set);
    seg.dtheta = Cached(set).dtheta;  // shared, not copied
    return seg;
  }

  // A nonlinear model's amounts cannot be negative; Newton may still find such
  // a root (for example when an infusion exceeds a saturable elimination).
  void CheckPhysical(const Eigen::VectorXd& x, const char* what) const {
    if (sys_.is_linear() || x.minCoeff() >= -Tolerance(x)) return;
    throw NumericalFailure(std::string("no steady state with non-negative amounts for ") + what +
                           " (is the dosing rate above the elimination capacity?)");
  }

  // Why a dosing cycle may have no fixed point. A saturable elimination
  // removes at most so much per cycle: above that dosing rate the amounts grow
  // without bound, and Newton runs to amounts where a cycle removes no more
  // than it did (P_x → I).
  std::string CycleHint(const Eigen::VectorXd& x) const {
    if (sys_.is_linear()) return "is nothing eliminated?";
    const std::string question = "is the dosing rate, AMT/II, above the elimination capacity?";
    const double largest = x.lpNorm<Eigen::Infinity>();
    if (!(largest > 0)) return question;
    char amounts[32];
    std::snprintf(amounts, sizeof amounts, "%.3g", largest);
    return std::string("Newton reached amounts of ") + amounts + ": " + question;
  }

  double Tolerance(const Eigen::VectorXd& x) const {
    return options_.relative_tolerance * x.lpNorm<Eigen::Infinity>() + options_.absolute_tolerance;
  }

  void Place(const Eigen::VectorXd& x, const Eigen::MatrixXd& dxdp, bool add) {
    if (add) {
      x_ += x;
      if (sens_) s_ += dxdp;
    } else {
      x_ = x;
      if (sens_) s_ = dxdp;
    }
  }

  // x[c] += amount, with its derivatives in the last P columns of *s.
  void Jump(int cmt, const T& amount, int offset, Eigen::VectorXd* x, Eigen::MatrixXd* s,
            std::vector<TapeStep>* steps) {
    const Eigen::RowVectorXd db = Derivatives(amount, p_).transpose();
    (*x)(cmt) += Value(amount);
    if (s->cols() > offset) s->row(cmt).tail(p_) += db;
    if (steps) {
      TapeStep b;
      b.kind = TapeStep::kBolus;
      b.cmt = cmt;
      b.damount = db;
      steps->push_back(std::move(b));
    }
  }

  // Integrates *x over one segment outside the main state (steady-state
  // cycles). *s holds `offset` initial-state directions, then the P parameter
  // directions (or none), or no columns at all for values only.
  void AdvanceAux(const T& h, const Vec<T>& u, int set, int offset, Eigen::VectorXd* x, Eigen::MatrixXd* s,
                  std::vector<TapeStep>* steps) {
    const SegmentInput seg_p = MakeSegment(h, u, set);
    TapeStep step;
    if (steps) step.x0 = *x;
    const Eigen::RowVectorXd dh = Derivatives(h, p_).transpose();
    if (s->cols() == 0) {
      solver_->Advance(seg_p, x);
    } else {
      const int params = static_cast<int>(s->cols()) - offset;  // p_, or 0 for the initial states alone
      SegmentInput seg = seg_p;
      seg.du = Eigen::MatrixXd::Zero(n_, offset + params);
      if (seg_p.du.cols() > 0) seg.du.rightCols(params) = seg_p.du.leftCols(params);
      Eigen::MatrixXd dtheta = Eigen::MatrixXd::Zero(sys_.num_theta(), offset + params);
      dtheta.rightCols(params) = seg_p.dtheta->leftCols(params);
      seg.dtheta = std::move(dtheta);
      solver_->AdvanceSensitivity(seg, x, s);
      if (params > 0) {
        Eigen::VectorXd f;
        sys_.Rhs(*x, seg.theta, &f);
        s->rightCols(params) += (f + seg.u) * dh;
      }
    }
    if (steps) {
      step.kind = TapeStep::kAdvance;
      step.x1 = *x;
      step.dh = dh;
      step.segment = seg_p;
      steps->push_back(std::move(step));
    }
  }

  // One dosing cycle from *x: the bolus, then the period's segments, with the
  // sensitivity directions [∂/∂x0 (n) | ∂/∂p (P)] in *s. Records the steps
  // (P parameter columns) for the adjoint when `steps` is given.
  void RunCycle(const SteadyStateCycle<T>& cycle, int set, Eigen::VectorXd* x, Eigen::MatrixXd* s,
                std::vector<TapeStep>* steps) {
    Jump(cycle.cmt, cycle.bolus, n_, x, s, steps);
    for (const Segment<T>& period : cycle.period) AdvanceAux(period.duration, period.rate, set, n_, x, s, steps);
  }

  struct SetValues {
    bool formed = false;
    Eigen::VectorXd theta;
    SharedMatrix dtheta;  // every segment of the set holds this one
  };
  const SetValues& Cached(int set) const {
    SetValues& v = set_values_.at(static_cast<size_t>(set));
    if (!v.formed) {
      const int m = sys_.num_theta();
      v.theta = Values(sets_[set], m);
      v.dtheta = DerivativeMatrix(sets_[set], p_, m);
      v.formed = true;
    }
    return v;
  }

  const OdeSystem& sys_;
  const std::vector<Vec<T>>& sets_;
  // Cached(): the sets' θ and ∂θ/∂p, formed at first use. Sized once: the sets are fixed for the
  // propagator's life, and references to their entries stay valid.
  mutable std::vector<SetValues> set_values_;
  const int p_;
  const int n_;
  std::unique_ptr<SegmentSolver> solver_;
  OdeOptions options_;
  const bool sens_;
  const bool tape_on_;
  const bool track_auc_;
  const ContinuousRecords* continuous_;
  Eigen::VectorXd x_;
  Eigen::MatrixXd s_;
  double t_ = 0;
  double auc_ = 0;
  double loss_ = 0;
  Eigen::RowVectorXd dloss_;
  Eigen::RowVectorXd dloss_time_;
  Eigen::RowVectorXd dt_;  // ∂t/∂p of the current time
  std::vector<TapeStep> tape_;
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_ODE_ODE_PROPAGATOR_H_
