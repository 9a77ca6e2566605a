// RODAS4 with block-triangular sensitivity solves (rosenbrock.h).
#include "rosenbrock.h"

#include <algorithm>
#include <utility>
#include <cmath>
#include <string>
#include <vector>

#include <Eigen/LU>

#include "../numerical_failure.h"

namespace pk {
namespace internal {
namespace {

// RODAS4 (Hairer & Wanner): γ, the stage weights a_ij of the points and c_ij of the right-hand sides.
constexpr double kGamma = 0.25;
constexpr double kA21 = 1.544;
constexpr double kA31 = 0.9466785280815826, kA32 = 0.2557011698983284;
constexpr double kA41 = 3.314825187068521, kA42 = 2.896124015972201, kA43 = 0.9986419139977817;
constexpr double kA51 = 1.221224509226641, kA52 = 6.019134481288629, kA53 = 12.53708332932087,
                 kA54 = -0.687886036105895;
constexpr double kC21 = -5.6688;
constexpr double kC31 = -2.430093356833875, kC32 = -0.2063599157091915;
constexpr double kC41 = -0.1073529058151375, kC42 = -9.594562251023355, kC43 = -20.47028614809616;
constexpr double kC51 = 7.496443313967647, kC52 = -10.24680431464352, kC53 = -33.99990352819905,
                 kC54 = 11.7089089320616;
constexpr double kC61 = 8.083246795921522, kC62 = -7.981132988064893, kC63 = -31.52159432874371,
                 kC64 = 16.31930543123136, kC65 = -6.058818238834054;

// A stage value: x and its k sensitivity columns.
struct Point {
  Eigen::VectorXd x;
  Eigen::MatrixXd s;
};

}  // namespace

// One segment's stepping: the stacked system, its Jacobian blocks at a step's start and the stages.
struct Rosenbrock::Stepper {
  const OdeSystem& sys;
  const SegmentInput& in;
  const int n, k;
  OdeStatistics* stats;
  Eigen::PartialPivLU<Eigen::MatrixXd> lu;
  std::vector<Eigen::MatrixXd> b;  // B_a at the step's start
  Point g[6];                      // g₁ … g₅ and the error estimate
  Point stage, rhs;
  Eigen::MatrixXd df;
  // A linear system's A and B_a = ∂A/∂θ·θ_a, constant over the segment: formed once.
  const bool linear;
  Eigen::MatrixXd a;

  Stepper(const OdeSystem& s, const SegmentInput& i, int cols, OdeStatistics* st)
      : sys(s), in(i), n(s.n()), k(cols), stats(st), linear(s.is_linear()) {
    if (!linear) return;
    const Eigen::VectorXd x = Eigen::VectorXd::Zero(n);
    a = sys.StateJacobian(x, in.theta);
    if (k > 0) sys.SensitivityJacobians(x, in.theta, Eigen::MatrixXd::Zero(n, k), in.dtheta, &b);
  }

  // F at p into *out: f + u, and f_x s + f_θ θ_p + u_p.
  void F(const Point& p, Point* out) {
    ++stats->rhs_evaluations;
    if (linear) {
      out->x = a * p.x;
      if (k > 0) {
        out->s.noalias() = a * p.s;
        for (int c = 0; c < k; ++c) out->s.col(c) += b[static_cast<size_t>(c)] * p.x;
        if (in.du.cols() == k) out->s += in.du;
      }
    } else if (k == 0) {
      sys.Rhs(p.x, in.theta, &out->x);
    } else {
      sys.RhsDirectional(p.x, in.theta, p.s, in.dtheta, &out->x, &df);
      out->s = df;
      if (in.du.cols() == k) out->s += in.du;
    }
    out->x += in.u;
  }

  // W_aug g = r by block substitution (rosenbrock.h), in place.
  void Solve(Point* r) const {
    r->x = lu.solve(r->x);
    if (k == 0) return;
    for (int a = 0; a < k; ++a) r->s.col(a) += b[static_cast<size_t>(a)] * r->x;
    r->s = lu.solve(r->s);  // every column in one call
  }

  // x₀ + Σ w_j g_j over the first `count` stages.
  void Combine(const Point& x0, const double* w, int count, Point* out) const {
    out->x = x0.x;
    out->s = x0.s;
    for (int j = 0; j < count; ++j) {
      out->x += w[j] * g[j].x;
      if (k > 0) out->s += w[j] * g[j].s;
    }
  }

  // Stage i's solve: W g_i = F(point) + Σ_j (c_j/h) g_j.
  void Stage(int i, const Point& point, const double* c, double h) {
    F(point, &rhs);
    for (int j = 0; j < i; ++j) {
      rhs.x += (c[j] / h) * g[j].x;
      if (k > 0) rhs.s += (c[j] / h) * g[j].s;
    }
    Solve(&rhs);
    std::swap(g[i], rhs);  // rhs keeps g[i]'s storage for the next stage
  }

  // One step of length h from z0 into *z1; the error norm (≤ 1 accepts).
  double Step(const Point& z0, double h, double atol, double rtol, bool control_s, Point* z1) {
    if (linear) {
      lu.compute(Eigen::MatrixXd::Identity(n, n) / (kGamma * h) - a);
    } else {
      ++stats->jacobian_evaluations;
      lu.compute(Eigen::MatrixXd::Identity(n, n) / (kGamma * h) - sys.StateJacobian(z0.x, in.theta));
      if (k > 0) sys.SensitivityJacobians(z0.x, in.theta, z0.s, in.dtheta, &b);
    }
    const double a2[] = {kA21}, a3[] = {kA31, kA32}, a4[] = {kA41, kA42, kA43}, a5[] = {kA51, kA52, kA53, kA54};
    const double c2[] = {kC21}, c3[] = {kC31, kC32}, c4[] = {kC41, kC42, kC43}, c5[] = {kC51, kC52, kC53, kC54};
    const double c6[] = {kC61, kC62, kC63, kC64, kC65};
    Stage(0, z0, nullptr, h);
    Combine(z0, a2, 1, &stage);
    Stage(1, stage, c2, h);
    Combine(z0, a3, 2, &stage);
    Stage(2, stage, c3, h);
    Combine(z0, a4, 3, &stage);
    Stage(3, stage, c4, h);
    Combine(z0, a5, 4, &stage);
    Stage(4, stage, c5, h);
    stage.x += g[4].x;  // x̃
    if (k > 0) stage.s += g[4].s;
    Stage(5, stage, c6, h);
    z1->x = stage.x + g[5].x;
    if (k > 0) {
      z1->s = stage.s + g[5].s;
    } else {
      z1->s.resize(n, 0);
    }
    // max_i |e_i| / (atol + rtol·max(|z0_i|, |z1_i|)) over x and S.
    const auto norm = [&](const auto& e, const auto& a, const auto& c) {
      return (e.array().abs() / (atol + rtol * a.array().abs().max(c.array().abs()))).maxCoeff();
    };
    double err = norm(g[5].x, z0.x, z1->x);
    if (k > 0 && control_s) err = std::max(err, norm(g[5].s, z0.s, z1->s));
    return std::isfinite(err) && z1->x.allFinite() && (k == 0 || z1->s.allFinite()) ? err : HUGE_VAL;
  }
};

void Rosenbrock::Integrate(const SegmentInput& in, Eigen::VectorXd* x, Eigen::MatrixXd* s, bool control_s,
                           std::vector<double>* record, const std::vector<double>* replay) {
  const int k = s == nullptr ? 0 : static_cast<int>(s->cols());
  Stepper st(sys_, in, k, stats_);
  Point z{*x, s == nullptr ? Eigen::MatrixXd(sys_.n(), 0) : *s}, next;
  if (record) record->clear();
  if (replay) {  // the recorded steps, accepted as they were
    for (const double h : *replay) {
      st.Step(z, h, opt_.absolute_tolerance, opt_.relative_tolerance, control_s, &next);
      if (!next.x.allFinite() || (k > 0 && !next.s.allFinite())) {
        throw NumericalFailure("the stiff solution or its derivatives are not finite");
      }
      ++stats_->steps;
      ++stats_->stiff_steps;
      z = next;
    }
  } else {
    // The first step from the segment alone, so that the same segment always takes the same steps.
    double t = 0, dt = in.h / 100;
    long steps = 0;
    while (t < in.h) {
      const bool last = dt >= in.h - t;
      const double h = last ? in.h - t : dt;
      const double err = st.Step(z, h, opt_.absolute_tolerance, opt_.relative_tolerance, control_s, &next);
      // Hairer & Wanner's control for an order-3 estimate: h·min(6, max(0.2, 0.9·err^(−1/4))).
      const double factor = err == 0 ? 6 : std::min(6.0, std::max(0.2, 0.9 * std::pow(err, -0.25)));
      if (++steps > opt_.max_steps) {
        throw NumericalFailure("too much work: more than " + std::to_string(opt_.max_steps) +
                               " Rosenbrock steps in one segment");
      }
      if (!(err <= 1)) {
        if (err == HUGE_VAL && h < 1e-14 * in.h) throw NumericalFailure("the stiff solution is not finite");
        dt = h * (err == HUGE_VAL ? 0.2 : factor);
        continue;
      }
      ++stats_->steps;
      ++stats_->stiff_steps;
      if (record) record->push_back(h);
      z = next;
      t = last ? in.h : t + h;
      dt = h * factor;
    }
  }
  *x = z.x;
  if (s != nullptr) *s = z.s;
}

void Rosenbrock::Advance(const SegmentInput& in, Eigen::VectorXd* x, std::vector<double>* steps) {
  Integrate(in, x, nullptr, false, steps, nullptr);
}

void Rosenbrock::AdvanceAlong(const SegmentInput& in, Eigen::VectorXd* x, const std::vector<double>& steps) {
  Integrate(in, x, nullptr, false, nullptr, &steps);
}

void Rosenbrock::AdvanceSensitivity(const SegmentInput& in, Eigen::VectorXd* x, Eigen::MatrixXd* s) {
  Integrate(in, x, s, true, nullptr, nullptr);
}

void Rosenbrock::AdjointSegment(const SegmentInput& in, const Eigen::VectorXd& x0, const std::vector<double>& steps,
                                const Eigen::VectorXd& lambda_end, Eigen::VectorXd* lambda_start,
                                Eigen::RowVectorXd* q) {
  const int n = sys_.n();
  const auto k = in.dtheta->cols();
  // S = [∂x/∂x₀ | ∂x/∂p]: n identity columns, then the parameters' (θ_p and u_p after n zero columns).
  SegmentInput seeded = in;
  Eigen::MatrixXd dtheta = Eigen::MatrixXd::Zero(in.theta.size(), n + k);
  dtheta.rightCols(k) = *in.dtheta;
  seeded.dtheta = std::move(dtheta);
  seeded.du = Eigen::MatrixXd::Zero(n, n + k);
  if (in.du.cols() == k) seeded.du.rightCols(k) = in.du;
  Eigen::VectorXd x = x0;
  Eigen::MatrixXd s = Eigen::MatrixXd::Zero(n, n + k);
  s.leftCols(n).setIdentity();
  // The values pass's steps again: the derivative of the computed segment, the discrete adjoint.
  Integrate(seeded, &x, &s, false, nullptr, &steps);
  *lambda_start = s.leftCols(n).transpose() * lambda_end;
  *q = lambda_end.transpose() * s.rightCols(k);
}

}  // namespace internal
}  // namespace pk
