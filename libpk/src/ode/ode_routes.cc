#include "ode_routes.h"

#include <algorithm>

#include <Eigen/Dense>

namespace pk {
namespace internal {

std::vector<ContinuousTerm> ContinuousRecords::Terms(double t0, double h) const {
  std::vector<ContinuousTerm> terms;
  const double mid = t0 + 0.5 * h;
  for (const Series& s : series) {
    // The record interval [t_i, t_{i+1}) holding the segment (segments never straddle a record).
    const size_t i = static_cast<size_t>(std::upper_bound(s.t.begin(), s.t.end(), mid) - s.t.begin());
    if (i == 0 || i == s.t.size()) continue;
    const size_t a = i - 1;
    const double span = s.t[i] - s.t[a];
    ContinuousTerm c;
    c.key = s.key;
    c.ym_slope = (s.y[i] - s.y[a]) / span;
    c.ym0 = s.y[a] + c.ym_slope * (t0 - s.t[a]);
    c.w_slope = (s.w[i] - s.w[a]) / span;
    c.w0 = s.w[a] + c.w_slope * (t0 - s.t[a]);
    terms.push_back(c);
  }
  return terms;
}

namespace {

// Forwards the engine's calls to the propagator and collects the samples.
template <typename T>
class Collector {
 public:
  Collector(const OdeSubject& o, const PreparedSubject& s, OdePropagator<T>* prop, Eigen::VectorXd* yhat,
            Eigen::MatrixXd* jacobian)
      : o_(o), s_(s), prop_(prop), yhat_(yhat), jacobian_(jacobian) {
    prop_->set_time(s.records().empty() ? 0.0 : s.records()[0].time);
  }

  void Advance(const T& h, const Vec<T>& u, int set) { prop_->Advance(h, u, set); }
  void Bolus(int cmt, const T& amount, int set) { prop_->Bolus(cmt, amount, set); }
  void Reset() { prop_->Reset(); }
  void SteadyState(const SteadyStateCycle<T>& c, int set, bool add) { prop_->SteadyState(c, set, add); }
  void SteadyInfusion(const Vec<T>& u, int set, bool add) { prop_->SteadyInfusion(u, set, add); }
  void DoseEntered(const T&, int) {}

  void RecordDone(int r, int set) {
    prop_->set_time(s_.records()[r].time);
    const int k = o_.sample_of_record[r];
    if (k < 0) return;
    const int key = o_.key_of_record[r];
    const Eigen::VectorXd& theta = prop_->SetTheta(set);  // the set's own, not an m×P copy a sample
    if (jacobian_ != nullptr) {
      const Eigen::MatrixXd& dtheta = prop_->SetDtheta(set);
      // ∂ŷ/∂p = g_x S + g_θ ∂θ/∂p
      Eigen::RowVectorXd dy;
      o_.system->ObserveDirectional(key, prop_->state(), theta, prop_->sensitivity(), dtheta, &(*yhat_)(k), &dy);
      jacobian_->row(k) = dy;
    } else {
      (*yhat_)(k) = o_.system->Observe(key, prop_->state(), theta);
      prop_->TapeSample(k, key, set);
    }
  }

 private:
  const OdeSubject& o_;
  const PreparedSubject& s_;
  OdePropagator<T>* prop_;
  Eigen::VectorXd* yhat_;
  Eigen::MatrixXd* jacobian_;
};

void Accumulate(const OdeStatistics& from, OdeStatistics* to) {
  if (to == nullptr) return;
  to->steps += from.steps;
  to->rhs_evaluations += from.rhs_evaluations;
  to->jacobian_evaluations += from.jacobian_evaluations;
  to->backward_steps += from.backward_steps;
  to->stiff_steps += from.stiff_steps;
  to->peak_adjoint_bytes = std::max(to->peak_adjoint_bytes, from.peak_adjoint_bytes);
}

}  // namespace

void OdePredict(const OdeSubject& o, const PreparedSubject& s, Eigen::VectorXd* yhat, double* continuous_loss,
                OdeStatistics* stats) {
  OdePropagator<double> prop(*o.system, s.sets, 0, o.options, false, false, false, &o.continuous, o.integrator);
  *yhat = Eigen::VectorXd::Zero(o.num_samples);
  Collector<double> c(o, s, &prop, yhat, nullptr);
  EventEngine<double, Collector<double>> engine(s, *o.layout, s.sets, &c);
  engine.Run();
  *continuous_loss = prop.continuous_loss();
  Accumulate(prop.solver().statistics(), stats);
}

void OdeForwardSensitivities(const OdeSubject& o, const PreparedSubject& s, const std::vector<DualVector>& sets,
                             int p, Eigen::VectorXd* yhat, Eigen::MatrixXd* jacobian, double* continuous_loss,
                             Eigen::RowVectorXd* continuous_gradient, OdeStatistics* stats) {
  OdePropagator<Dual> prop(*o.system, sets, p, o.options, true, false, false, &o.continuous, o.integrator);
  *yhat = Eigen::VectorXd::Zero(o.num_samples);
  *jacobian = Eigen::MatrixXd::Zero(o.num_samples, p);
  Collector<Dual> c(o, s, &prop, yhat, jacobian);
  EventEngine<Dual, Collector<Dual>> engine(s, *o.layout, sets, &c);
  engine.Run();
  *continuous_loss = prop.continuous_loss();
  *continuous_gradient = prop.continuous_loss_gradient() + prop.continuous_loss_time_gradient();
  Accumulate(prop.solver().statistics(), stats);
}

struct OdeAdjoint::Impl {
  const OdeSubject& o;
  const PreparedSubject& s;
  std::vector<DualVector> sets;
  int p;
  OdePropagator<Dual> prop;
  double scale = 0;  // S = Σ_k |Δλ_k|ᵀ|x(t_k)| (the backward solves' error control)
  Eigen::VectorXd gx, gtheta;  // an output's gradients, reused from sample to sample

  // S over every sample of a tape, Δλ_k = g_xᵀ ∂ℓ_k/∂y.
  double GradientScale(const std::vector<TapeStep>& tape, const Eigen::VectorXd& dl_dy) {
    double sum = 0;
    for (const TapeStep& step : tape) {
      if (step.kind == TapeStep::kSteadyState) {
        sum += GradientScale(step.to_record, dl_dy) + GradientScale(step.cycle, dl_dy);
      }
      if (step.kind != TapeStep::kSample || dl_dy(step.sample) == 0) continue;
      o.system->ObserveGradient(step.key, step.x1, prop.SetTheta(step.set), &gx, &gtheta);
      sum += std::fabs(dl_dy(step.sample)) * gx.cwiseAbs().dot(step.x1.cwiseAbs());
    }
    return sum;
  }

  Impl(const OdeSubject& oo, const PreparedSubject& ss, const std::vector<DualVector>& st, int pp)
      : o(oo), s(ss), sets(st), p(pp), prop(*oo.system, sets, pp, oo.options, false, true, false,
                                            &oo.continuous, oo.integrator) {}

  // Backward over one recorded segment: the moving-end term, then CVODES.
  void BackwardSegment(const TapeStep& step, Eigen::VectorXd* lambda, Eigen::VectorXd* g) {
    if (step.dh.size() && !step.dh.isZero(0.0)) {
      Eigen::VectorXd f;
      o.system->Rhs(step.x1, step.segment.theta, &f);
      *g += (lambda->dot(f + step.segment.u)) * step.dh.transpose();
    }
    Eigen::VectorXd lambda0;
    Eigen::RowVectorXd q;
    AdjointScales scales;
    scales.state = scale;
    scales.gradient = g;
    if (step.handle >= 0) {
      prop.solver().BackwardStored(step.handle, scales, *lambda, &lambda0, &q);
    } else {
      prop.solver().AdjointSegment(step.segment, step.x0, scales, *lambda, &lambda0, &q);
    }
    if (q.size()) *g += q.transpose();
    *lambda = lambda0;
  }

  void Sweep(const std::vector<TapeStep>& tape, const Eigen::VectorXd& dl_dy, Eigen::VectorXd* lambda,
             Eigen::VectorXd* g) {
    const int n = o.system->n();
    for (auto it = tape.rbegin(); it != tape.rend(); ++it) {
      const TapeStep& step = *it;
      switch (step.kind) {
        case TapeStep::kSample: {
          // λ jumps by g_xᵀ ∂ℓ/∂y; the output's own θ-dependence adds (g_θ ∂θ/∂p)ᵀ ∂ℓ/∂y.
          const double w = dl_dy(step.sample);
          if (w == 0) break;
          o.system->ObserveGradient(step.key, step.x1, prop.SetTheta(step.set), &gx, &gtheta);
          *lambda += w * gx;
          // An output that reads no θ (an amount over a fixed volume) skips the m×P product.
          if (!gtheta.isZero(0.0)) *g += w * (prop.SetDtheta(step.set).transpose() * gtheta);
          break;
        }
        case TapeStep::kAdvance:
          BackwardSegment(step, lambda, g);
          break;
        case TapeStep::kBolus:
          *g += (*lambda)(step.cmt) * step.damount.transpose();
          break;
        case TapeStep::kReset:
          lambda->setZero();
          break;
        case TapeStep::kSteadyInfusion: {
          // λᵀ ∂x*/∂p = −(f_x⁻ᵀ λ)ᵀ (f_θ θ_p + u_p)
          const Eigen::VectorXd mu = step.jacobian.transpose().fullPivLu().solve(*lambda);
          *g -= (mu.transpose() * step.forcing).transpose();
          if (!step.add) lambda->setZero();
          break;
        }
        case TapeStep::kSteadyState: {
          // Back from the record time to x* on the steady-state part, then
          // λ*ᵀ ∂x*/∂p = μᵀ ∂P/∂p with (I − P_x)ᵀ μ = λ*; ∂P/∂p by a backward pass over the cycle.
          Eigen::VectorXd lambda_ss = *lambda;
          Sweep(step.to_record, dl_dy, &lambda_ss, g);
          Eigen::VectorXd mu =
              (Eigen::MatrixXd::Identity(n, n) - step.jacobian).transpose().partialPivLu().solve(lambda_ss);
          Sweep(step.cycle, dl_dy, &mu, g);
          if (!step.add) lambda->setZero();
          break;
        }
      }
    }
  }
};

OdeAdjoint::OdeAdjoint(const OdeSubject& o, const PreparedSubject& s, const std::vector<DualVector>& sets, int p)
    : impl_(new Impl(o, s, sets, p)) {}
OdeAdjoint::~OdeAdjoint() = default;

void OdeAdjoint::Forward(Eigen::VectorXd* yhat, double* continuous_loss) {
  Impl& d = *impl_;
  *yhat = Eigen::VectorXd::Zero(d.o.num_samples);
  Collector<Dual> c(d.o, d.s, &d.prop, yhat, nullptr);
  EventEngine<Dual, Collector<Dual>> engine(d.s, *d.o.layout, d.sets, &c);
  engine.Run();
  *continuous_loss = d.prop.continuous_loss();
}

Eigen::VectorXd OdeAdjoint::Gradient(const Eigen::VectorXd& dl_dyhat) {
  Impl& d = *impl_;
  Eigen::VectorXd lambda = Eigen::VectorXd::Zero(d.o.system->n());
  Eigen::VectorXd g = Eigen::VectorXd::Zero(d.p);
  d.scale = d.GradientScale(d.prop.tape(), dl_dyhat);
  d.Sweep(d.prop.tape(), dl_dyhat, &lambda, &g);
  return g + d.prop.continuous_loss_time_gradient().transpose();
}

const OdeStatistics& OdeAdjoint::statistics() const { return impl_->prop.solver().statistics(); }

}  // namespace internal
}  // namespace pk
