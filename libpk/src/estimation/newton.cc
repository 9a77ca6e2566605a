// Newton with the Gauss–Newton matrix or the Fisher information, in a trust region.
//
#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Eigenvalues>

#include "estimation/minimizer.h"

namespace pk {
namespace internal {
namespace {

using Need = Objective::Need;

// The model of V around φ is m(s) = V + gᵀs + ½sᵀHs, with H the Gauss–Newton matrix JᵀWJ (least squares) or the
// expected information (maximum likelihood). Both are positive semidefinite and both underestimate the curvature
// far from the optimum: with maximum likelihood, a start whose residuals are large against σ gives a Fisher
// scoring step of tens of units in log σ. A line search along the full step accepts such a leap as soon as V
// falls a little, and the iterates then walk down a degenerate valley (predictions → 0, σ → ∞) that ends at a
// higher objective than the optimum. A trust region trusts the model only as far as it has predicted V
// (Moré 1983; Nocedal and Wright, Numerical Optimization, Algorithm 4.1): the step solves
//   min m(s) subject to ‖Ds‖ ≤ Δ,
// and Δ grows or shrinks with ρ = (V(φ) − V(φ + s)) / (m(0) − m(s)).
// D is 1 for log- and logit-scale parameters (their steps are relative changes) and 1/max(1, |φ₀|) for the others.

// The subproblem's solution for a positive semidefinite H (Moré and Sorensen 1983): s = −(H + μD²)⁻¹g, with μ = 0
// when the minimum-norm Newton step lies in the region, else the μ > 0 where ‖Ds(μ)‖ = Δ. In the eigenbasis
// D⁻¹HD⁻¹ = QΛQᵀ, with c = QᵀD⁻¹g, ‖Ds(μ)‖² = Σ cᵢ²/(λᵢ + μ)²; μ comes from Newton's method on 1/‖Ds(μ)‖ − 1/Δ,
// which is nearly linear in μ, safeguarded by bisection.
Eigen::VectorXd TrustRegionStep(const Eigen::MatrixXd& h, const Eigen::VectorXd& g, const Eigen::VectorXd& d,
                                double delta) {
  const Eigen::VectorXd dinv = d.cwiseInverse();
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(dinv.asDiagonal() * h * dinv.asDiagonal());
  const Eigen::VectorXd lambda = es.eigenvalues().cwiseMax(0.0);
  const Eigen::VectorXd c = es.eigenvectors().transpose() * g.cwiseProduct(dinv);
  const double zero = 64 * std::numeric_limits<double>::epsilon() * std::max(lambda.maxCoeff(), 0.0);
  // ‖Ds(μ)‖ and its derivative in μ; at μ = 0 the null space of H is left out (minimum norm).
  auto norm = [&](double mu, double* slope) {
    double s2 = 0, s3 = 0;
    for (Eigen::Index i = 0; i < c.size(); ++i) {
      const double l = lambda(i) + mu;
      if (l <= zero) continue;
      s2 += c(i) * c(i) / (l * l);
      s3 += c(i) * c(i) / (l * l * l);
    }
    const double nrm = std::sqrt(s2);
    if (slope) *slope = nrm > 0 ? -s3 / nrm : 0;
    return nrm;
  };
  // A gradient with a part in H's null space makes the model fall linearly along it: no Newton step, the
  // solution is on the boundary.
  double null_part = 0;
  for (Eigen::Index i = 0; i < c.size(); ++i) {
    if (lambda(i) <= zero) null_part += c(i) * c(i);
  }
  double mu = 0;
  if (norm(0, nullptr) > delta || null_part > 1e-16 * c.squaredNorm()) {
    double lo = 0, hi = c.norm() / delta;  // ‖Ds(μ)‖ ≤ ‖c‖/μ
    mu = hi;
    for (int it = 0; it < 60; ++it) {
      double slope = 0;
      const double nrm = norm(mu, &slope);
      if (std::fabs(nrm - delta) <= 1e-3 * delta) break;
      (nrm > delta ? lo : hi) = mu;
      // Newton on ψ(μ) = 1/‖Ds‖ − 1/Δ: ψ' = −slope/‖Ds‖².
      const double next = mu - (1 / nrm - 1 / delta) * nrm * nrm / -slope;
      mu = (next > lo && next < hi && std::isfinite(next)) ? next : 0.5 * (lo + hi);
    }
  }
  Eigen::VectorXd t = Eigen::VectorXd::Zero(c.size());
  for (Eigen::Index i = 0; i < c.size(); ++i) {
    const double l = lambda(i) + mu;
    if (l > zero) t(i) = -c(i) / l;
  }
  return (es.eigenvectors() * t).cwiseProduct(dinv);
}

RunResult RunNewton(Problem* pb, const Eigen::VectorXd& phi0, const FitOptions& o) {
  RunResult r;
  Eigen::VectorXd phi = phi0;
  Objective::Evaluation ev = pb->Eval(phi, Need::kJacobian);
  if (!ev.ok) {
    r.phi = phi;
    r.message = "the objective could not be evaluated at the start: " + ev.message;
    return r;
  }
  const int n = pb->n();
  Eigen::VectorXd d(n);
  for (int k = 0; k < n; ++k) d(k) = pb->LogLike(k) ? 1.0 : 1.0 / std::max(1.0, std::fabs(phi0(k)));
  // Δ₀ = 1: a first step changes a log-scale parameter by at most a factor e. Δ at most doubles per iteration,
  // up to kMaxRadius (a factor e¹⁰ ≈ 22 000).
  constexpr double kMaxRadius = 10;
  double delta = 1;
  // V at φ as a value-only evaluation computes it, the same way as at the trial points: an ODE solve with
  // sensitivities takes other steps than one without, and differs from it by about the solver's tolerance,
  // which near the optimum is more than the predicted decrease.
  double value = ev.value;
  r.termination = TerminationType::kNoConvergence;  // unless a test below ends the search
  r.message = "iteration limit reached";
  for (int it = 1; it <= o.max_iterations; ++it) {
    r.iterations = it;
    if (ev.gradient.cwiseAbs().maxCoeff() <= o.gradient_tolerance) {
      r.termination = TerminationType::kConvergence;
      r.message = "gradient below tolerance";
      break;
    }
    const Eigen::VectorXd step = TrustRegionStep(ev.information, ev.gradient, d, delta);
    const double predicted = -(ev.gradient.dot(step) + 0.5 * step.dot(ev.information * step));
    if (!step.allFinite() || !(predicted > 0)) {
      r.termination = TerminationType::kConvergence;
      r.message = "no descent step found: the objective is minimal to machine precision";
      break;
    }
    const Eigen::VectorXd next = phi + step;
    const Objective::Evaluation& trial = pb->Eval(next, Need::kValue);
    const double actual = trial.ok && std::isfinite(trial.value) ? value - trial.value : -HUGE_VAL;
    const double rho = actual / predicted;
    const double step_norm = step.cwiseProduct(d).norm();
    if (rho < 0.25) {
      delta = 0.25 * step_norm;
    } else if (rho > 0.75 && step_norm >= 0.99 * delta) {
      delta = std::min(2 * delta, kMaxRadius);
    }
    if (rho <= 1e-4) {
      if (delta <= o.parameter_tolerance * (1 + phi.cwiseProduct(d).norm())) {
        r.termination = TerminationType::kConvergence;
        r.message = "no descent step found: the objective is minimal to machine precision";
        break;
      }
      continue;
    }
    const double step_size = step.cwiseAbs().maxCoeff();
    value = trial.value;
    phi = next;
    ev = pb->Eval(phi, Need::kJacobian);
    if (!ev.ok) {
      r.message = "the Jacobian could not be evaluated: " + ev.message;
      r.termination = TerminationType::kFailure;
      break;
    }
    if (actual <= o.function_tolerance * (std::fabs(value) + o.function_tolerance) &&
        step_size <= std::sqrt(o.parameter_tolerance) * (1 + phi.cwiseAbs().maxCoeff())) {
      r.termination = TerminationType::kConvergence;
      r.message = "relative reduction and parameter change below tolerance";
      break;
    }
  }
  r.phi = phi;
  return r;
}

class Newton final : public Minimizer {
 public:
  RunResult Minimize(Problem* problem, const Eigen::VectorXd& phi0, const FitOptions& options) const override {
    return RunNewton(problem, phi0, options);
  }
  bool needs_jacobian() const override { return true; }
};

}  // namespace

std::unique_ptr<Minimizer> MakeNewton(const std::string&, std::string*) { return std::make_unique<Newton>(); }

}  // namespace internal
}  // namespace pk
