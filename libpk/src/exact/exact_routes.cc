#include "exact_routes.h"

#include <Eigen/LU>

#include "exact_propagator.h"
#include "linear_derivatives.h"

namespace pk {
namespace internal {

std::vector<int> SampleIndex(const PreparedSubject& subject, int* count) {
  std::vector<int> index(subject.records().size(), -1);
  int k = 0;
  for (size_t r = 0; r < index.size(); ++r) {
    if (subject.records()[r].IsSample()) index[r] = k++;
  }
  *count = k;
  return index;
}

namespace {

// The value of a steady state's fixed point (discretization.h), for either scalar type.
template <typename T>
PeriodicSteadyState FixedPoint(LinearDerivatives* sys, int set, const SteadyStateCycle<T>& cycle,
                               Eigen::VectorXd* bolus) {
  std::vector<std::pair<double, Eigen::VectorXd>> period;
  for (const Segment<T>& seg : cycle.period) period.emplace_back(Value(seg.duration), Values(seg.rate));
  *bolus = Eigen::VectorXd::Zero(sys->n());
  (*bolus)(cycle.cmt) = Value(cycle.bolus);
  return SolvePeriodicSteadyState(sys->discretization(set), sys->n(), *bolus, period);
}

// ---------------------------------------------------------------------------
// Route (a): forward sensitivities.

template <typename T>
class ForwardVisitor {
 public:
  ForwardVisitor(LinearDerivatives* sys, const PreparedSubject& s, int num_free, Eigen::VectorXd* yhat,
                 Eigen::MatrixXd* jac)
      : sys_(*sys), s_(s), p_(num_free), yhat_(yhat), jac_(jac) {
    int count = 0;
    sample_ = SampleIndex(s, &count);
    yhat->setZero(count);
    jac->setZero(count, num_free);
    x_ = Eigen::VectorXd::Zero(sys_.n());
    sens_ = Eigen::MatrixXd::Zero(sys_.n(), p_);
  }

  void Advance(const T& h, const Vec<T>& u, int set) {
    Propagate(set, Value(h), Values(u), DerivativeMatrix(u, p_), Derivatives(h, p_), &x_, &sens_);
  }
  void Bolus(int cmt, const T& amount, int /*set*/) {
    x_(cmt) += Value(amount);
    if (HasDerivative(amount)) sens_.row(cmt) += Derivatives(amount, p_).transpose();
  }
  void Reset() {
    x_.setZero();
    sens_.setZero();
  }
  void DoseEntered(const T&, int) {}

  void SteadyState(const SteadyStateCycle<T>& cycle, int set, bool add) {
    const int n = sys_.n();
    Eigen::VectorXd b;
    const PeriodicSteadyState ps = FixedPoint(&sys_, set, cycle, &b);
    const Eigen::VectorXd& x_star = ps.x_star;
    // ∂_p P at x*, by propagating (x*, S = 0) through one period.
    Eigen::MatrixXd db = Eigen::MatrixXd::Zero(n, p_);
    db.row(cycle.cmt) = Derivatives(cycle.bolus, p_).transpose();
    Eigen::VectorXd x = x_star + b;
    Eigen::MatrixXd sens = db;
    RunSegments(cycle.period, set, &x, &sens);
    // Implicit function theorem: S* = (I − M)⁻¹ ∂_p P.
    Eigen::MatrixXd s_star = ps.lu.solve(sens);
    Eigen::VectorXd z = x_star + b;
    Eigen::MatrixXd sz = s_star + db;
    RunSegments(cycle.to_record, set, &z, &sz);
    SetOrAdd(z, sz, add);
  }

  void SteadyInfusion(const Vec<T>& u, int set, bool add) {
    // 0 = A z + u  ⇒  ∂z = −A⁻¹ (Σ_j ∂A/∂θ_j z ∂θ_j/∂p + ∂u/∂p).
    const Eigen::PartialPivLU<Eigen::MatrixXd> lu(sys_.A(set));
    if (!(lu.rcond() > 1e-13)) throw NumericalFailure("no steady state for a constant infusion");
    const Eigen::VectorXd z = lu.solve(-Values(u));
    Eigen::MatrixXd rhs = DerivativeMatrix(u, p_);
    for (int j : sys_.active(set)) rhs += (sys_.dA(set, j) * z) * sys_.dtheta(set).row(j);
    SetOrAdd(z, -lu.solve(rhs), add);
  }

  void RecordDone(int r, int set) {
    const int k = sample_[r];
    if (k < 0) return;
    const int cmt = s_.cmt[r] + 1;
    const Eigen::RowVectorXd& c = sys_.C(set, cmt);
    (*yhat_)(k) = c * x_;
    jac_->row(k) = c * sens_ + x_.transpose() * sys_.dCdp(set, cmt);
  }

 private:
  // A steady state replaces the state (SS=1) or adds to it (SS=2), with its sensitivity.
  void SetOrAdd(const Eigen::VectorXd& z, const Eigen::MatrixXd& sz, bool add) {
    if (add) {
      x_ += z;
      sens_ += sz;
    } else {
      x_ = z;
      sens_ = sz;
    }
  }

  void RunSegments(const std::vector<Segment<T>>& segments, int set, Eigen::VectorXd* x, Eigen::MatrixXd* sens) {
    for (const Segment<T>& seg : segments) {
      Propagate(set, Value(seg.duration), Values(seg.rate), DerivativeMatrix(seg.rate, p_),
                Derivatives(seg.duration, p_), x, sens);
    }
  }

  // x⁺ = Φx + Γu and its sensitivity (see the header).
  void Propagate(int set, double h, const Eigen::VectorXd& u, const Eigen::MatrixXd& du, const Eigen::VectorXd& dh,
                 Eigen::VectorXd* x, Eigen::MatrixXd* sens) {
    if (h == 0 && dh.isZero(0.0)) return;
    const bool input = !u.isZero(0.0) || !du.isZero(0.0);
    const LinearDerivatives::Step& st = sys_.Get(set, h, input);
    Eigen::VectorXd xn = st.phi * *x;
    Eigen::MatrixXd sn = st.phi * *sens;
    if (input) {
      xn += st.gamma * u;
      sn += st.gamma * du;
    }
    const std::vector<int>& active = sys_.active(set);
    if (!active.empty()) {
      const bool with_gamma = !u.isZero(0.0);
      const LinearDerivatives::StepSensitivity& ss = sys_.GetSensitivity(set, h, with_gamma);
      for (size_t a = 0; a < active.size(); ++a) {
        Eigen::VectorXd d = ss.dphi[a] * *x;
        if (with_gamma) d += ss.dgamma[a] * u;
        sn += d * sys_.dtheta(set).row(active[a]);
      }
    }
    if (!dh.isZero(0.0)) sn += (sys_.A(set) * xn + u) * dh.transpose();
    *x = std::move(xn);
    *sens = std::move(sn);
  }

  LinearDerivatives& sys_;
  const PreparedSubject& s_;
  int p_;
  Eigen::VectorXd* yhat_;
  Eigen::MatrixXd* jac_;
  std::vector<int> sample_;
  Eigen::VectorXd x_;
  Eigen::MatrixXd sens_;
};

}  // namespace

void ForwardSensitivities(const LinearModel& model, const ParameterLayout& layout, const PreparedSubject& subject,
                          const std::vector<DualVector>& sets, int num_free, bool events_depend_on_p,
                          Eigen::VectorXd* yhat, Eigen::MatrixXd* jacobian) {
  LinearDerivatives sys(model, sets, num_free);
  if (events_depend_on_p) {
    ForwardVisitor<Dual> visitor(&sys, subject, num_free, yhat, jacobian);
    EventEngine<Dual, ForwardVisitor<Dual>> engine(subject, layout, sets, &visitor);
    engine.Run();
  } else {
    ForwardVisitor<double> visitor(&sys, subject, num_free, yhat, jacobian);
    EventEngine<double, ForwardVisitor<double>> engine(subject, layout, subject.sets, &visitor);
    engine.Run();
  }
}

// ---------------------------------------------------------------------------
// Route (b): the discrete adjoint.

namespace {

struct SegmentTape {
  int set = 0;
  double h = 0;
  Eigen::VectorXd dh;        // empty when h does not depend on p
  Eigen::VectorXd u;         // empty when there is no input
  Eigen::MatrixXd du;        // empty when the input does not depend on p
  Eigen::VectorXd x_before;
  Eigen::VectorXd x_after;   // kept only when dh is not empty
};

struct SteadyTape {
  bool add = false;
  int cmt = 0;
  Eigen::VectorXd db;
  Eigen::MatrixXd m;  // period map
  std::vector<SegmentTape> period;
  std::vector<SegmentTape> to_record;
};

struct TapeOp {
  enum Kind { kAdvance, kBolus, kReset, kSteadyState, kSteadyInfusion, kOutput } kind;
  int set = 0;
  SegmentTape step;                 // kAdvance
  int cmt = 0;                      // kBolus, kOutput (1-based for outputs)
  Eigen::VectorXd d_amount;         // kBolus
  int sample = -1;                  // kOutput
  Eigen::VectorXd x;                // kOutput: state; kSteadyInfusion: z
  Eigen::MatrixXd du;               // kSteadyInfusion
  bool add = false;                 // kSteadyInfusion
  std::shared_ptr<SteadyTape> ss;   // kSteadyState
};

template <typename T>
class AdjointRecorder {
 public:
  AdjointRecorder(LinearDerivatives* sys, const PreparedSubject& s, int num_free, Eigen::VectorXd* yhat,
                  std::vector<TapeOp>* tape)
      : sys_(*sys), s_(s), p_(num_free), yhat_(yhat), tape_(*tape) {
    int count = 0;
    sample_ = SampleIndex(s, &count);
    yhat->setZero(count);
    x_ = Eigen::VectorXd::Zero(sys_.n());
  }

  void Advance(const T& h, const Vec<T>& u, int set) {
    TapeOp op;
    op.kind = TapeOp::kAdvance;
    op.set = set;
    op.step = Step(set, h, u, &x_);
    tape_.push_back(std::move(op));
  }
  void Bolus(int cmt, const T& amount, int /*set*/) {
    x_(cmt) += Value(amount);
    TapeOp op;
    op.kind = TapeOp::kBolus;
    op.cmt = cmt;
    if (HasDerivative(amount)) op.d_amount = Derivatives(amount, p_);
    tape_.push_back(std::move(op));
  }
  void Reset() {
    x_.setZero();
    TapeOp op;
    op.kind = TapeOp::kReset;
    tape_.push_back(std::move(op));
  }
  void DoseEntered(const T&, int) {}

  void SteadyState(const SteadyStateCycle<T>& cycle, int set, bool add) {
    auto tape = std::make_shared<SteadyTape>();
    tape->add = add;
    tape->cmt = cycle.cmt;
    tape->db = Derivatives(cycle.bolus, p_);
    Eigen::VectorXd b;
    const PeriodicSteadyState ps = FixedPoint(&sys_, set, cycle, &b);
    const Eigen::VectorXd& x_star = ps.x_star;
    tape->m = ps.m;
    Eigen::VectorXd x = x_star + b;
    for (const Segment<T>& seg : cycle.period) tape->period.push_back(Step(set, seg.duration, seg.rate, &x));
    Eigen::VectorXd z = x_star + b;
    for (const Segment<T>& seg : cycle.to_record) tape->to_record.push_back(Step(set, seg.duration, seg.rate, &z));
    x_ = add ? Eigen::VectorXd(x_ + z) : z;
    TapeOp op;
    op.kind = TapeOp::kSteadyState;
    op.set = set;
    op.ss = tape;
    tape_.push_back(std::move(op));
  }

  void SteadyInfusion(const Vec<T>& u, int set, bool add) {
    const Eigen::PartialPivLU<Eigen::MatrixXd> lu(sys_.A(set));
    if (!(lu.rcond() > 1e-13)) throw NumericalFailure("no steady state for a constant infusion");
    TapeOp op;
    op.kind = TapeOp::kSteadyInfusion;
    op.set = set;
    op.x = lu.solve(-Values(u));
    op.du = DerivativeMatrix(u, p_);
    op.add = add;
    x_ = add ? Eigen::VectorXd(x_ + op.x) : op.x;
    tape_.push_back(std::move(op));
  }

  void RecordDone(int r, int set) {
    const int k = sample_[r];
    if (k < 0) return;
    TapeOp op;
    op.kind = TapeOp::kOutput;
    op.set = set;
    op.cmt = s_.cmt[r] + 1;
    op.sample = k;
    op.x = x_;
    (*yhat_)(k) = sys_.C(set, op.cmt) * x_;
    tape_.push_back(std::move(op));
  }

 private:
  // Records only what the backward step needs: most steps have no input and
  // no time derivative, and then store just (set, h, x before).
  SegmentTape Step(int set, const T& h, const Vec<T>& u, Eigen::VectorXd* x) {
    SegmentTape t;
    t.set = set;
    t.h = Value(h);
    if (HasDerivative(h)) t.dh = Derivatives(h, p_);
    bool input = false, input_derivative = false;
    for (int i = 0; i < u.size(); ++i) {
      input = input || Value(u(i)) != 0;
      input_derivative = input_derivative || HasDerivative(u(i));
    }
    if (input) t.u = Values(u);
    if (input_derivative) t.du = DerivativeMatrix(u, p_);
    t.x_before = *x;
    if (t.h != 0) {
      const LinearDerivatives::Step& st = sys_.Get(set, t.h, input);
      *x = st.phi * *x;
      if (input) *x += st.gamma * t.u;
    }
    if (t.dh.size()) t.x_after = *x;
    return t;
  }

  LinearDerivatives& sys_;
  const PreparedSubject& s_;
  int p_;
  Eigen::VectorXd* yhat_;
  std::vector<TapeOp>& tape_;
  std::vector<int> sample_;
  Eigen::VectorXd x_;
};

}  // namespace

struct DiscreteAdjoint::Impl {
  const LinearModel& model;
  const ParameterLayout& layout;
  const PreparedSubject& subject;
  const std::vector<DualVector> sets;  // owned: the event engine and sys refer to it
  int p;
  LinearDerivatives sys;
  std::vector<TapeOp> tape;
  std::vector<Eigen::VectorXd> theta_grad;
  Eigen::VectorXd grad;

  bool dual_events;

  Impl(const LinearModel& m, const ParameterLayout& l, const PreparedSubject& s, const std::vector<DualVector>& st,
       int num_free, bool events_depend_on_p)
      : model(m), layout(l), subject(s), sets(st), p(num_free), sys(m, sets, num_free), dual_events(events_depend_on_p) {}

  // One step x⁺ = Φx + Γu backwards: λ ← Φᵀλ, with the h, u and θ terms.
  // Empty tape fields are zero (see AdjointRecorder::Step).
  void BackStep(const SegmentTape& t, Eigen::VectorXd* lambda) {
    const Eigen::VectorXd& lam = *lambda;
    if (t.dh.size()) {
      Eigen::VectorXd f = sys.A(t.set) * t.x_after;
      if (t.u.size()) f += t.u;
      grad += lam.dot(f) * t.dh;
    }
    if (t.h == 0) return;
    const bool input = t.du.size() > 0;
    const LinearDerivatives::Step& st = sys.Get(t.set, t.h, input || t.u.size() > 0);
    if (input) grad += t.du.transpose() * (st.gamma.transpose() * lam);
    sys.AccumulateFrechet(t.set, t.h, lam, t.x_before, t.u);
    *lambda = st.phi.transpose() * lam;
  }

  Eigen::VectorXd Backward(const Eigen::VectorXd& dl_dy) {
    const int n = sys.n();
    grad = Eigen::VectorXd::Zero(p);
    theta_grad.assign(sets.size(), Eigen::VectorXd::Zero(model.num_parameters()));
    Eigen::VectorXd lambda = Eigen::VectorXd::Zero(n);
    for (auto it = tape.rbegin(); it != tape.rend(); ++it) {
      const TapeOp& op = *it;
      switch (op.kind) {
        case TapeOp::kOutput: {
          const double g = dl_dy(op.sample);
          if (g == 0) break;
          lambda += g * sys.C(op.set, op.cmt).transpose();
          grad += g * (sys.dCdp(op.set, op.cmt).transpose() * op.x);
          break;
        }
        case TapeOp::kAdvance:
          BackStep(op.step, &lambda);
          break;
        case TapeOp::kBolus:
          if (op.d_amount.size()) grad += lambda(op.cmt) * op.d_amount;
          break;
        case TapeOp::kReset:
          lambda.setZero();
          break;
        case TapeOp::kSteadyInfusion: {
          // z = −A⁻¹u: ν = −A⁻ᵀλ, ∂/∂θ_j = νᵀ ∂A/∂θ_j z, ∂/∂u = ν.
          const Eigen::PartialPivLU<Eigen::MatrixXd> lu(sys.A(op.set).transpose());
          const Eigen::VectorXd nu = -lu.solve(lambda);
          for (int j : sys.active(op.set)) theta_grad[op.set](j) += nu.dot(sys.dA(op.set, j) * op.x);
          grad += op.du.transpose() * nu;
          if (!op.add) lambda.setZero();
          break;
        }
        case TapeOp::kSteadyState: {
          const SteadyTape& ss = *op.ss;
          // Back through the advance to the record time: μ is the adjoint of z₀ = x* + b.
          Eigen::VectorXd mu = lambda;
          for (auto s = ss.to_record.rbegin(); s != ss.to_record.rend(); ++s) BackStep(*s, &mu);
          grad += mu(ss.cmt) * ss.db;
          // Implicit function theorem on x* = P(x*): ν = (I − M)⁻ᵀ μ, then νᵀ ∂_p P.
          const Eigen::PartialPivLU<Eigen::MatrixXd> lu(
              (Eigen::MatrixXd::Identity(n, n) - ss.m).transpose());
          Eigen::VectorXd rho = lu.solve(mu);
          for (auto s = ss.period.rbegin(); s != ss.period.rend(); ++s) BackStep(*s, &rho);
          grad += rho(ss.cmt) * ss.db;
          if (!ss.add) lambda.setZero();
          break;
        }
      }
    }
    sys.FinishAdjoint(theta_grad, &grad);
    return grad;
  }
};

DiscreteAdjoint::DiscreteAdjoint(const LinearModel& model, const ParameterLayout& layout,
                                 const PreparedSubject& subject, const std::vector<DualVector>& sets, int num_free,
                                 bool events_depend_on_p)
    : impl_(new Impl(model, layout, subject, sets, num_free, events_depend_on_p)) {}

DiscreteAdjoint::~DiscreteAdjoint() = default;

void DiscreteAdjoint::Forward(Eigen::VectorXd* yhat) {
  impl_->tape.clear();
  if (impl_->dual_events) {
    AdjointRecorder<Dual> recorder(&impl_->sys, impl_->subject, impl_->p, yhat, &impl_->tape);
    EventEngine<Dual, AdjointRecorder<Dual>> engine(impl_->subject, impl_->layout, impl_->sets, &recorder);
    engine.Run();
  } else {
    AdjointRecorder<double> recorder(&impl_->sys, impl_->subject, impl_->p, yhat, &impl_->tape);
    EventEngine<double, AdjointRecorder<double>> engine(impl_->subject, impl_->layout, impl_->subject.sets, &recorder);
    engine.Run();
  }
}

Eigen::VectorXd DiscreteAdjoint::Gradient(const Eigen::VectorXd& dl_dyhat) { return impl_->Backward(dl_dyhat); }

// ---------------------------------------------------------------------------

namespace {

class PredictVisitor {
 public:
  PredictVisitor(const LinearModel& model, const PreparedSubject& s, Eigen::VectorXd* yhat)
      : model_(model), s_(s), prop_(model, s.sets, false), yhat_(yhat) {
    int count = 0;
    sample_ = SampleIndex(s, &count);
    yhat->setZero(count);
  }
  void Advance(double h, const Eigen::VectorXd& u, int set) { prop_.Advance(h, u, set); }
  void Bolus(int cmt, double amount, int set) { prop_.Bolus(cmt, amount, set); }
  void Reset() { prop_.Reset(); }
  void SteadyState(const SteadyStateCycle<double>& c, int set, bool add) { prop_.SteadyState(c, set, add); }
  void SteadyInfusion(const Eigen::VectorXd& u, int set, bool add) { prop_.SteadyInfusion(u, set, add); }
  void DoseEntered(double, int) {}
  void RecordDone(int r, int set) {
    const int k = sample_[r];
    if (k < 0) return;
    // C x alone, as on every exact route: the objective adds an output's offset (output_offsets.h).
    (*yhat_)(k) = model_.OutputRow<double>(s_.cmt[r] + 1, s_.sets[set].head(model_.num_parameters())) * prop_.state();
  }

 private:
  const LinearModel& model_;
  const PreparedSubject& s_;
  ExactPropagator prop_;
  Eigen::VectorXd* yhat_;
  std::vector<int> sample_;
};

}  // namespace

void Predict(const LinearModel& model, const ParameterLayout& layout, const PreparedSubject& subject,
             Eigen::VectorXd* yhat) {
  PredictVisitor visitor(model, subject, yhat);
  EventEngine<double, PredictVisitor> engine(subject, layout, subject.sets, &visitor);
  engine.Run();
}

}  // namespace internal
}  // namespace pk
