// Boost.Odeint is sealed in this file.
#include "rk_solver.h"

#include <algorithm>
#include <cmath>
#include <exception>
#include <functional>
#include <string>

#include <boost/numeric/odeint.hpp>
#include <boost/numeric/odeint/external/eigen/eigen.hpp>

#include "numerical_failure.h"

namespace pk {
namespace internal {
namespace {

namespace odeint = boost::numeric::odeint;
using State = Eigen::VectorXd;
// always_resizer: the state's size changes between calls (values alone, with S, with quadratures), and
// Odeint's default sizes its buffers once.
using Stepper = odeint::runge_kutta_dopri5<State, double, State, double, odeint::vector_space_algebra,
                                           odeint::default_operations, odeint::always_resizer>;
using Dense = odeint::result_of::make_dense_output<Stepper>::type;
using Rhs = std::function<void(const State& z, State& dz, double t)>;

}  // namespace

struct RkSolver::Impl {
  const OdeSystem& sys;
  OdeOptions opt;
  int n;
  OdeStatistics stats;
  const SegmentInput* in = nullptr;
  Eigen::MatrixXd s_buf, df_buf;  // scratch of the sensitivity right-hand side
  Eigen::VectorXd f_buf;

  // The problem the stepper is on, for a segment that continues it (see rk_solver.h).
  Dense dense = odeint::make_dense_output(1e-10, 1e-8, Stepper());
  struct Continuation {
    bool at_end = false;
    double t = 0;  // the stepper's time at the end of the last segment
    int k = -1;    // sensitivity directions (-1: values only)
    Eigen::VectorXd z, theta, u;
    Eigen::MatrixXd dtheta, du;
    bool Continues(const SegmentInput& s, const Eigen::VectorXd& z0, int directions) const {
      return at_end && s.continuous.empty() && s.auc_key == 0 && k == directions && z == z0 && theta == s.theta &&
             u == s.u && (k < 0 || (dtheta == s.dtheta && du == s.du));
    }
  } last;

  Impl(const OdeSystem& s, const OdeOptions& o) : sys(s), opt(o), n(s.n()) {
    dense = odeint::make_dense_output(opt.absolute_tolerance, opt.relative_tolerance, Stepper());
  }

  // Hairer, Nørsett and Wanner's first step: 1% of the state's scale over its rate's, at most h.
  double InitialStep(const State& z, const Rhs& rhs, double h) {
    State f(z.size());
    rhs(z, f, 0.0);
    const Eigen::ArrayXd scale = opt.absolute_tolerance + opt.relative_tolerance * z.array().abs();
    const double d0 = (z.array() / scale).matrix().norm(), d1 = (f.array() / scale).matrix().norm();
    const double h0 = d0 < 1e-5 || d1 < 1e-5 ? 1e-6 : 0.01 * d0 / d1;
    return std::min(h0, h);
  }

  // z ← z(h) under `rhs`, continuing the stepper's problem when `continues`.
  void Integrate(const Rhs& rhs, double h, bool continues, State* z) {
    double target = h;
    if (continues) {
      target = last.t + h;
    } else {
      dense.initialize(*z, 0.0, InitialStep(*z, rhs, h));
    }
    long steps = 0;
    try {
      while (dense.current_time() < target) {
        dense.do_step(std::cref(rhs));
        ++stats.steps;
        if (!dense.current_state().allFinite()) {
          throw NumericalFailure("the ODE solution is not finite at t = " + std::to_string(dense.current_time()));
        }
        if (++steps > opt.max_steps) {
          throw NumericalFailure("too much work: more than " + std::to_string(opt.max_steps) +
                                 " Dormand–Prince steps between two events (a stiff system? use --propagator ode)");
        }
      }
    } catch (const NumericalFailure&) {
      last.at_end = false;
      throw;
    } catch (const std::exception& e) {  // Odeint's step-size failure
      last.at_end = false;
      throw NumericalFailure(std::string("the Dormand–Prince step size control failed: ") + e.what());
    }
    dense.calc_state(target, *z);
    last.t = target;
  }

  void Remember(const SegmentInput& s, const State& z, int k) {
    last.at_end = true;
    last.k = k;
    last.z = z;
    last.theta = s.theta;
    last.u = s.u;
    if (k >= 0) {
      last.dtheta = s.dtheta;
      last.du = s.du;
    }
  }
};

RkSolver::RkSolver(const OdeSystem& system, const OdeOptions& options) : impl_(new Impl(system, options)) {}
RkSolver::~RkSolver() = default;

const OdeStatistics& RkSolver::statistics() const { return impl_->stats; }

void RkSolver::Advance(const SegmentInput& in, Eigen::VectorXd* x, double* loss, double* auc, double* loss_time) {
  Impl& d = *impl_;
  const int n = d.n;
  const bool with_loss = loss != nullptr && !in.continuous.empty();
  const bool with_auc = auc != nullptr && in.auc_key != 0;
  // The state: x, then the continuous loss and ∫∂L/∂t, then ∫ y_auc dt.
  State z = State::Zero(n + (with_loss ? 2 : 0) + (with_auc ? 1 : 0));
  z.head(n) = *x;
  const Rhs rhs = [&](const State& zz, State& dz, double t) {
    ++d.stats.rhs_evaluations;
    const Eigen::VectorXd xs = zz.head(n);
    Eigen::VectorXd f;
    d.sys.Rhs(xs, in.theta, &f);
    dz.resize(zz.size());
    dz.head(n) = f + in.u;
    if (with_loss) {
      double lt = 0;
      dz(n) = ContinuousLoss(d.sys, in, t, xs, nullptr, &lt);
      dz(n + 1) = lt;
    }
    if (with_auc) dz(dz.size() - 1) = d.sys.Observe(in.auc_key, xs, in.theta);
  };
  const bool continues = !with_loss && !with_auc && d.last.Continues(in, z, -1);
  d.Integrate(rhs, in.h, continues, &z);
  *x = z.head(n);
  if (with_loss) {
    *loss += z(n);
    if (loss_time) *loss_time += z(n + 1);
  }
  if (with_auc) *auc += z(z.size() - 1);
  if (with_loss || with_auc) {
    d.last.at_end = false;
  } else {
    d.Remember(in, z, -1);
  }
}

void RkSolver::AdvanceSensitivity(const SegmentInput& in, Eigen::VectorXd* x, Eigen::MatrixXd* s, double* loss,
                                  Eigen::RowVectorXd* dloss, double* loss_time) {
  Impl& d = *impl_;
  const int n = d.n;
  const int k = static_cast<int>(s->cols());
  const bool with_loss = loss != nullptr && !in.continuous.empty();
  // The state: x, vec S (column by column), then the loss, its k derivatives and ∫∂L/∂t.
  const Eigen::Index nk = static_cast<Eigen::Index>(n) * k;
  State z = State::Zero(n + nk + (with_loss ? k + 2 : 0));
  z.head(n) = *x;
  z.segment(n, nk) = Eigen::Map<const Eigen::VectorXd>(s->data(), nk);
  const Rhs rhs = [&](const State& zz, State& dz, double t) {
    ++d.stats.rhs_evaluations;
    const Eigen::VectorXd xs = zz.head(n);
    d.s_buf = Eigen::Map<const Eigen::MatrixXd>(zz.data() + n, n, k);
    d.sys.RhsDirectional(xs, in.theta, d.s_buf, in.dtheta, &d.f_buf, &d.df_buf);
    if (in.du.cols() == k) d.df_buf += in.du;
    dz.resize(zz.size());
    dz.head(n) = d.f_buf + in.u;
    dz.segment(n, nk) = Eigen::Map<const Eigen::VectorXd>(d.df_buf.data(), nk);
    if (with_loss) {
      Eigen::VectorXd dl;
      double lt = 0;
      dz(n + nk) = ContinuousLoss(d.sys, in, t, xs, &dl, &lt);
      Eigen::RowVectorXd grad = Eigen::RowVectorXd::Zero(k);
      for (size_t i = 0; i < in.continuous.size(); ++i) {
        double y;
        Eigen::RowVectorXd dy;
        d.sys.ObserveDirectional(in.continuous[i].key, xs, in.theta, d.s_buf, in.dtheta, &y, &dy);
        grad += dl(static_cast<Eigen::Index>(i)) * dy;
      }
      dz.segment(n + nk + 1, k) = grad.transpose();
      dz(dz.size() - 1) = lt;
    }
  };
  const bool continues = !with_loss && d.last.Continues(in, z, k);
  d.Integrate(rhs, in.h, continues, &z);
  *x = z.head(n);
  *s = Eigen::Map<const Eigen::MatrixXd>(z.data() + n, n, k);
  if (with_loss) {
    *loss += z(n + nk);
    if (dloss) *dloss += z.segment(n + nk + 1, k).transpose();
    if (loss_time) *loss_time += z(z.size() - 1);
    d.last.at_end = false;
  } else {
    d.Remember(in, z, k);
  }
}

}  // namespace internal
}  // namespace pk
