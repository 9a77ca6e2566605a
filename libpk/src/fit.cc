#include "pk/fit.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <sstream>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <cminpack.h>
#include <nlopt.hpp>

#include "identifiability.h"
#include "internal_text.h"
#include "pk/error.h"

namespace pk {

const char* ToString(OptimizerType o) {
  switch (o) {
    case OptimizerType::kLevenbergMarquardt: return "lm";
    case OptimizerType::kBfgs: return "bfgs";
    case OptimizerType::kNewton: return "newton";
    case OptimizerType::kNlopt: return "nlopt";
  }
  return "?";
}

bool FitOptions::IsValid(std::string* error) const {
  auto fail = [&](const std::string& why) {
    if (error) *error = why;
    return false;
  };
  if (max_iterations < 1) return fail("max_iterations must be at least 1");
  if (!(function_tolerance >= 0) || !(parameter_tolerance >= 0) || !(gradient_tolerance >= 0)) {
    return fail("tolerances must not be negative");
  }
  if (starts < 1) return fail("starts must be at least 1");
  if (!(start_spread >= 0)) return fail("start_spread must not be negative");
  if (optimizer == OptimizerType::kNlopt) {
    if (nlopt_algorithm_from_string(nlopt_algorithm.c_str()) < 0) {
      return fail("unknown NLopt algorithm '" + nlopt_algorithm + "' (for example LD_LBFGS, LN_BOBYQA, LD_MMA)");
    }
  }
  return true;
}

bool IsCompatible(const FitOptions& fit, const ObjectiveOptions& objective, std::string* why) {
  if (objective.error_model != ErrorModel::kLeastSquares && fit.optimizer == OptimizerType::kLevenbergMarquardt) {
    if (why) *why = "Levenberg-Marquardt minimises a sum of squares; for maximum likelihood use bfgs, newton or nlopt:NAME";
    return false;
  }
  if (objective.gradient == GradientRoute::kAdjoint &&
      (fit.optimizer == OptimizerType::kLevenbergMarquardt || fit.optimizer == OptimizerType::kNewton)) {
    if (why) {
      *why = std::string(ToString(fit.optimizer)) +
             " needs the residual Jacobian, which the adjoint route does not give; use --gradient forward or fd, "
             "or a gradient-only optimizer (bfgs, nlopt:NAME)";
    }
    return false;
  }
  return true;
}

namespace {

using Clock = std::chrono::steady_clock;
using Need = Objective::Need;
using internal::Cell;
using internal::Num;

// Maps an unbounded φ to θ: first to the scale s (log θ or θ), bounded by the
// bounds' images, then θ = exp(s) or s.
struct Transform {
  bool log = true;
  double sl = -INFINITY, su = INFINITY;

  double S(double phi) const {
    const bool lo = std::isfinite(sl), hi = std::isfinite(su);
    if (lo && hi) return sl + (su - sl) / (1 + std::exp(-phi));
    if (lo) return sl + std::exp(phi);
    if (hi) return su - std::exp(phi);
    return phi;
  }
  double DsDphi(double phi) const {
    const bool lo = std::isfinite(sl), hi = std::isfinite(su);
    if (lo && hi) {
      const double sig = 1 / (1 + std::exp(-phi));
      return (su - sl) * sig * (1 - sig);
    }
    if (lo) return std::exp(phi);
    if (hi) return -std::exp(phi);
    return 1;
  }
  double Theta(double phi) const { return log ? std::exp(S(phi)) : S(phi); }
  double DthetaDphi(double phi) const { return (log ? Theta(phi) : 1.0) * DsDphi(phi); }
  double Phi(double theta) const {
    const double s = log ? std::log(theta) : theta;
    const bool lo = std::isfinite(sl), hi = std::isfinite(su);
    if (lo && hi) {
      const double f = (s - sl) / (su - sl);
      return std::log(f / (1 - f));
    }
    if (lo) return std::log(s - sl);
    if (hi) return std::log(su - s);
    return s;
  }
};

class Problem {
 public:
  Problem(const Objective& obj, std::vector<int> free, std::vector<Transform> tr, Eigen::VectorXd base)
      : obj_(obj), free_(std::move(free)), tr_(std::move(tr)), base_(std::move(base)) {}

  int n() const { return static_cast<int>(free_.size()); }
  const std::vector<int>& free() const { return free_; }
  const Objective& objective() const { return obj_; }

  Eigen::VectorXd Values(const Eigen::VectorXd& phi) const {
    Eigen::VectorXd v = base_;
    for (int k = 0; k < n(); ++k) v(free_[k]) = tr_[k].Theta(phi(k));
    return v;
  }
  Eigen::VectorXd Dtheta(const Eigen::VectorXd& phi) const {
    Eigen::VectorXd d(n());
    for (int k = 0; k < n(); ++k) d(k) = tr_[k].DthetaDphi(phi(k));
    return d;
  }
  Eigen::VectorXd PhiOf(const Eigen::VectorXd& values) const {
    Eigen::VectorXd phi(n());
    for (int k = 0; k < n(); ++k) phi(k) = tr_[k].Phi(values(free_[k]));
    return phi;
  }

  // Evaluates on the φ scale: chain rule with D = diag(dθ/dφ). The last two
  // evaluations are remembered: Fit asks again for the start and for the
  // optimiser's final point, where the optimiser has usually just evaluated.
  // The reference stays valid until Eval has computed two more evaluations.
  const Objective::Evaluation& Eval(const Eigen::VectorXd& phi, Need need) {
    for (const Memo& m : memo_) {
      // A failed evaluation answers only what it was asked: a value may exist without its Jacobian.
      if ((m.need == need || (m.need > need && m.ev.ok)) && m.phi.size() == phi.size() && m.phi == phi) return m.ev;
    }
    ++evaluations_;
    std::swap(memo_[0], memo_[1]);
    Objective::Evaluation& ev = memo_[0].ev;
    ev = obj_.Evaluate(Values(phi), free_, need);
    if (ev.ok && need != Need::kValue) {
      const Eigen::VectorXd d = Dtheta(phi);
      route_ = ev.route;
      propagator_ = ev.propagator;
      ev.gradient = ev.gradient.cwiseProduct(d);
      if (need == Need::kJacobian) {
        if (ev.jacobian.size()) ev.jacobian = ev.jacobian * d.asDiagonal();
        ev.information = d.asDiagonal() * ev.information * d.asDiagonal();
      }
    }
    memo_[0].phi = phi;
    memo_[0].need = need;
    return ev;
  }

  // Whether φ_k is a log or logit of the parameter (else the parameter itself).
  bool LogLike(int k) const {
    return tr_[k].log || std::isfinite(tr_[k].sl) || std::isfinite(tr_[k].su);
  }
  const std::string& Name(int k) const { return obj_.parameter_names()[free_[k]]; }

  int evaluations() const { return evaluations_; }
  const std::string& route() const { return route_; }
  const std::string& propagator() const { return propagator_; }

 private:
  const Objective& obj_;
  std::vector<int> free_;
  std::vector<Transform> tr_;
  Eigen::VectorXd base_;
  int evaluations_ = 0;
  struct Memo {
    Eigen::VectorXd phi;  // empty: unused
    Need need = Need::kValue;
    Objective::Evaluation ev;
  };
  Memo memo_[2];
  std::string propagator_ = ToString(obj_.propagator());
  std::string route_ = "none";
};

struct RunResult {
  Eigen::VectorXd phi;
  double value = NAN;
  int iterations = 0;
  TerminationType termination = TerminationType::kFailure;
  std::string message;
  std::vector<int> held;  // LM: coordinates held at their start (see LmSingular)
};

// ---- Levenberg–Marquardt: MINPACK's lmder, through cminpack (libcminpack-dev).
// Chosen over a hand-written LM because lmder's trust-region logic and scaling
// are decades-tested. cminpack is the C translation of the original Fortran, on
// caller-owned arrays; Eigen's unsupported port of the same algorithm allocates
// and runs dynamic-size kernels at every iteration, which on a PK fit (3
// parameters, 11 residuals) cost a third of the fitting time.
struct LmData {
  Problem* pb;
  Eigen::VectorXd phi;     // the point lmder asks about, all coordinates (the problem's memo key)
  std::vector<int> active;  // the coordinates lmder moves; the others stay as in phi
};

// lmder's pivoted QR takes a pivot of rounding size for a real one. So on a
// Jacobian that is singular to rounding, its Gauss–Newton step has an enormous
// component along the null direction, and a successful trust region follows
// it: with F1 free on oral data, CL, V and F1 went to 1e264 together, and the
// fit missed its minimum. When the Jacobian is singular at the start and also
// at a point nearby, so that the null direction is the model's and not a
// coincidence of the start (two peripheral compartments alike, KA = CL/V), the
// coordinate that dominates it is held at its start while lmder moves the
// others. Singular means σ_min/σ_max of the column-scaled Jacobian at most
// 1e-12, far above rounding and far below the conditioning of anything a fit
// can determine; with the ODE propagator rtol, as its sensitivities keep the
// model's exact relations only to a tenth of that or so (theophylline with F1
// free: 1e-16 to 8e-10 at rtol 1e-8).
double LmSingular(const Objective& objective) {
  constexpr double kExact = 1e-12;
  if (objective.propagator() != Propagator::kOde) return kExact;
  return std::max(kExact, objective.options().ode.relative_tolerance);
}

// 0..n−1 without the coordinates in `held`.
std::vector<int> Without(int n, const std::vector<int>& held) {
  std::vector<int> rest;
  for (int k = 0; k < n; ++k) {
    if (std::find(held.begin(), held.end(), k) == held.end()) rest.push_back(k);
  }
  return rest;
}

// The column to hold, or -1. A zero column is no trouble for lmder (its pivot
// is exactly 0, so that coordinate never moves).
int LmHold(const Eigen::MatrixXd& jac, double singular) {
  std::vector<int> moving;
  for (int k = 0; k < static_cast<int>(jac.cols()); ++k) {
    if (jac.col(k).squaredNorm() > 0) moving.push_back(k);
  }
  if (moving.size() < 2) return -1;
  const int j = internal::NullCoordinate(jac(Eigen::all, moving), singular);
  return j < 0 ? -1 : moving[j];
}

// lmder's callback: iflag 1 asks for the residuals, 2 for their Jacobian at the
// same point (found in the problem's memo), 0 for printing (unused). A negative
// return stops lmder.
int LmCallback(void* p, int m, int n, const double* x, double* fvec, double* fjac, int ldfjac, int iflag) {
  if (iflag == 0) return 0;
  auto* d = static_cast<LmData*>(p);
  for (int k = 0; k < n; ++k) d->phi(d->active[k]) = x[k];
  const Objective::Evaluation& ev = d->pb->Eval(d->phi, Need::kJacobian);
  if (iflag == 1) {
    if (!ev.ok) {
      std::fill(fvec, fvec + m, 1e100);  // rejects the step; LM shrinks its trust region
      return 0;
    }
    Eigen::Map<Eigen::VectorXd>(fvec, m) = ev.residuals;
    return 0;
  }
  if (!ev.ok) return -1;
  Eigen::Map<Eigen::MatrixXd, 0, Eigen::OuterStride<>> jac(fjac, m, n, Eigen::OuterStride<>(ldfjac));
  for (int k = 0; k < n; ++k) jac.col(k) = ev.jacobian.col(d->active[k]);
  return 0;
}

// The coordinates to hold from the start φ0 (see LmSingular): one per null
// direction the Jacobian has both at φ0 and nearby.
std::vector<int> LmStructuralHolds(Problem* pb, const Eigen::VectorXd& phi0) {
  std::vector<int> held;
  const double singular = LmSingular(pb->objective());
  const Objective::Evaluation& start = pb->Eval(phi0, Need::kJacobian);
  if (!start.ok) return held;
  const Eigen::MatrixXd j0 = start.jacobian;
  // Nearby: every coordinate moved by 0.05–0.15, in alternating directions.
  Eigen::VectorXd nearby = phi0;
  for (int k = 0; k < nearby.size(); ++k) nearby(k) += (k % 2 ? -1 : 1) * (0.05 + 0.1 * std::fmod(0.618 * (k + 1), 1.0));
  Eigen::MatrixXd j1;
  for (;;) {
    const std::vector<int> rest = Without(static_cast<int>(j0.cols()), held);
    const int j = LmHold(j0(Eigen::all, rest), singular);
    if (j < 0) return held;
    if (j1.size() == 0) {
      const Objective::Evaluation& there = pb->Eval(nearby, Need::kJacobian);
      if (!there.ok) return held;
      j1 = there.jacobian;
    }
    if (LmHold(j1(Eigen::all, rest), singular) != j) return held;
    held.push_back(rest[j]);
  }
}

// lmder from data->phi over the coordinates not in `held`; returns its info.
int LmRun(LmData* data, int m, const std::vector<int>& held, const FitOptions& o, int* nfev_total, int* njev_total) {
  data->active = Without(static_cast<int>(data->phi.size()), held);
  const int na = static_cast<int>(data->active.size());
  Eigen::VectorXd x(na), fvec(m), diag(na), qtf(na), wa1(na), wa2(na), wa3(na), wa4(m);
  for (int k = 0; k < na; ++k) x(k) = data->phi(data->active[k]);
  Eigen::MatrixXd fjac(m, na);
  std::vector<int> ipvt(static_cast<size_t>(na));
  int nfev = 0, njev = 0;
  const int info = lmder(LmCallback, data, m, na, x.data(), fvec.data(), fjac.data(), m,
                         std::max(o.function_tolerance, 1e-15), std::max(o.parameter_tolerance, 1e-15), /*gtol=*/0.0,
                         /*maxfev=*/std::max(1, o.max_iterations - *nfev_total), diag.data(), /*mode=*/1,
                         /*factor=*/100.0, /*nprint=*/0, &nfev, &njev, ipvt.data(), qtf.data(), wa1.data(),
                         wa2.data(), wa3.data(), wa4.data());
  *nfev_total += nfev;
  *njev_total += njev;
  for (int k = 0; k < na; ++k) data->phi(data->active[k]) = x(k);
  return info;
}

RunResult RunLm(Problem* pb, int m, const Eigen::VectorXd& phi0, const FitOptions& o) {
  RunResult r;
  LmData data{pb, phi0, {}};
  std::vector<int> held = pb->n() > 1 ? LmStructuralHolds(pb, phi0) : std::vector<int>();
  int nfev_total = 0, njev_total = 0;
  int info = LmRun(&data, m, held, o, &nfev_total, &njev_total);
  const bool converged = info >= 1 && info != 5;
  if (!held.empty() && converged && nfev_total < o.max_iterations) {
    // Once more with every coordinate. Kept only when it lowers the objective
    // by more than rounding: otherwise it was a walk along the null direction.
    const Eigen::VectorXd phi_held = data.phi;
    const Objective::Evaluation& at_held = pb->Eval(phi_held, Need::kValue);
    const double v_held = at_held.ok ? at_held.value : INFINITY;
    const int info_all = LmRun(&data, m, {}, o, &nfev_total, &njev_total);
    const Objective::Evaluation& at_all = pb->Eval(data.phi, Need::kValue);
    if (at_all.ok && at_all.value < v_held - 1e-6 * std::fabs(v_held)) {
      held.clear();
      info = info_all;
    } else {
      data.phi = phi_held;
    }
  }
  r.phi = data.phi;
  r.iterations = njev_total;  // one Jacobian per iteration
  for (int k : held) r.held.push_back(k);
  // lmder's outcomes: 1–4 are convergence tests; 6–8 mean no further reduction is possible at machine precision.
  struct Outcome {
    int info;
    TerminationType termination;
    const char* message;
  };
  static const Outcome kOutcomes[] = {
      {1, TerminationType::kConvergence, "relative reduction of the sum of squares below ftol"},
      {2, TerminationType::kConvergence, "relative change of the parameters below xtol"},
      {3, TerminationType::kConvergence, "relative reduction and parameter change below tolerance"},
      {4, TerminationType::kConvergence, "residuals orthogonal to the Jacobian columns"},
      {5, TerminationType::kNoConvergence, "evaluation limit reached"},
      {6, TerminationType::kConvergence, "no further reduction possible at machine precision"},
      {7, TerminationType::kConvergence, "no further reduction possible at machine precision"},
      {8, TerminationType::kConvergence, "no further reduction possible at machine precision"},
  };
  r.termination = TerminationType::kFailure;
  r.message = info < 0 ? "the Jacobian could not be evaluated" : "improper input to Levenberg-Marquardt";
  for (const Outcome& oc : kOutcomes) {
    if (oc.info == info) {
      r.termination = oc.termination;
      r.message = oc.message;
    }
  }
  return r;
}

// ---- NLopt (BFGS is LD_LBFGS).
struct NloptData {
  Problem* pb;
  bool failed_last = false;
};

double NloptObjective(const std::vector<double>& x, std::vector<double>& grad, void* data) {
  auto* d = static_cast<NloptData*>(data);
  const Eigen::VectorXd phi = Eigen::Map<const Eigen::VectorXd>(x.data(), static_cast<Eigen::Index>(x.size()));
  const Objective::Evaluation& ev = d->pb->Eval(phi, grad.empty() ? Need::kValue : Need::kGradient);
  if (!ev.ok) {
    std::fill(grad.begin(), grad.end(), 0.0);
    return 1e300;
  }
  for (size_t k = 0; k < grad.size(); ++k) grad[k] = ev.gradient(static_cast<Eigen::Index>(k));
  return ev.value;
}

// Lukšan's gradient-based NLopt algorithms run in a box around their start on the
// unbounded scale, moved to the result when it ends on the box's edge. Without
// it, L-BFGS's first line search may extrapolate by factors of 1e100 into a
// region where the likelihood is flat (CL → 0 with V → ∞ and σ → ∞ fits a
// constant) and stop there "converged". The box is a factor of 1000 either way
// for log-scale parameters; a parameter that still runs to the edge after
// kBoxMoves moves is reported as not determined by the data.
constexpr double kBoxLogHalfWidth = 6.907755278982137;  // ln 1000
constexpr int kBoxMoves = 6;

RunResult RunNlopt(Problem* pb, const std::string& algorithm, const Eigen::VectorXd& phi0, const FitOptions& o) {
  RunResult r;
  const int n = pb->n();
  nlopt::opt opt(algorithm.c_str(), static_cast<unsigned>(n));
  NloptData data{pb};
  opt.set_min_objective(NloptObjective, &data);
  opt.set_ftol_rel(o.function_tolerance);
  opt.set_xtol_rel(o.parameter_tolerance);
  std::vector<double> x(phi0.data(), phi0.data() + n);
  const bool global = algorithm.rfind("G", 0) == 0;
  // Lukšan's line-search methods (L-BFGS, the variable-metric and truncated-Newton ones) extrapolate without
  // limit; MMA, CCSAQ and SLSQP control their steps themselves, and their steps depend on the bounds.
  const bool moving_box = algorithm.rfind("LD_LBFGS", 0) == 0 || algorithm.rfind("LD_VAR", 0) == 0 ||
                          algorithm.rfind("LD_TNEWTON", 0) == 0;
  std::vector<double> half(n), lo(n), hi(n);
  for (int k = 0; k < n; ++k) {
    // Global algorithms need a finite box: e^±5 around the start on the unbounded scale.
    half[k] = global ? 5.0 : (pb->LogLike(k) ? kBoxLogHalfWidth : 1000 * std::max(1.0, std::fabs(x[k])));
  }
  const auto center = [&](const std::vector<double>& c) {
    for (int k = 0; k < n; ++k) {
      lo[k] = c[k] - half[k];
      hi[k] = c[k] + half[k];
    }
    opt.set_lower_bounds(lo);
    opt.set_upper_bounds(hi);
  };
  if (global || moving_box) center(x);
  // The first parameter on the box's edge, and whether on its lower side; -1 for none.
  bool edge_low = false;
  const auto at_edge = [&]() {
    if (!moving_box) return -1;
    for (int k = 0; k < n; ++k) {
      const double tol = 1e-6 * half[k];
      edge_low = x[k] - lo[k] <= tol;
      if (edge_low || hi[k] - x[k] <= tol) return k;
    }
    return -1;
  };
  int evaluations = 0, edge = -1;
  double fval = NAN;
  try {
    nlopt::result res = nlopt::FAILURE;
    for (int move = 0;; ++move) {
      opt.set_maxeval(std::max(1, o.max_iterations - evaluations));
      res = opt.optimize(x, fval);
      evaluations += opt.get_numevals();
      edge = at_edge();
      if (edge < 0 || move == kBoxMoves || evaluations >= o.max_iterations) break;
      center(x);
    }
    switch (res) {
      case nlopt::SUCCESS:
      case nlopt::STOPVAL_REACHED:
      case nlopt::FTOL_REACHED:
      case nlopt::XTOL_REACHED:
        r.termination = TerminationType::kConvergence;
        break;
      case nlopt::MAXEVAL_REACHED:
      case nlopt::MAXTIME_REACHED:
        r.termination = TerminationType::kNoConvergence;
        break;
      default:
        r.termination = TerminationType::kFailure;
    }
    r.message = std::string("NLopt ") + opt.get_algorithm_name() + ": " +
                nlopt_result_to_string(static_cast<nlopt_result>(res));
  } catch (const nlopt::roundoff_limited&) {
    r.termination = TerminationType::kConvergence;
    r.message = "NLopt stopped: roundoff-limited (the optimum is resolved to machine precision)";
    evaluations += opt.get_numevals();  // the round that threw
    edge = at_edge();
  } catch (const std::exception& e) {
    r.termination = TerminationType::kFailure;
    r.message = std::string("NLopt failed: ") + e.what();
    evaluations += opt.get_numevals();
    edge = -1;
  }
  if (edge >= 0 && r.termination != TerminationType::kFailure) {
    r.termination = TerminationType::kNoConvergence;
    r.message = pb->Name(edge) + " keeps moving towards " + (edge_low ? "its lower end" : "its upper end") +
                " without an optimum: the data do not determine it (try other --init values, --starts N or "
                "--optimizer newton)";
  }
  r.phi = Eigen::Map<Eigen::VectorXd>(x.data(), n);
  r.iterations = evaluations;
  return r;
}

// ---- Newton with the Gauss–Newton matrix or the Fisher information, in a trust region.
//
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

// Whether parameter `i` is a σ gone to 0: SIGMA_ADD below 1e-6 of the largest
// |DV|, SIGMA_PROP or SIGMA_LOG below 1e-6.
bool SigmaAtZero(const Objective& objective, const Eigen::VectorXd& values, int i) {
  constexpr double kCollapse = 1e-6;
  if (i < 0) return false;
  const std::string& name = objective.parameter_names()[i];
  if (name == kSigmaProp || name == kSigmaLog) return std::fabs(values(i)) < kCollapse;
  if (name != kSigmaAdd || objective.observations().size() == 0) return false;
  return std::fabs(values(i)) < kCollapse * objective.observations().cwiseAbs().maxCoeff();
}

// Maximum likelihood has no maximum when a sample's σ_k can shrink to 0 together
// with its residual: −½ log σ_k² → +∞. That happens when the curve can pass
// through every sample (typically no more samples than model parameters), or
// when a combined error's additive part is a sample's whole σ_k because the
// sample is predicted as 0 (a DV of 0 at an oral dose's time). Optimisers then
// stop wherever their tests happen to hold, at σ of 1e-6 to 1e-150 and
// objectives of −20 to −500, and would report convergence. A σ below 1e-6 of
// the largest |DV| (SIGMA_ADD) or below 1e-6 (SIGMA_PROP), far below any
// assay's precision, is taken as collapsed. A combined error's SIGMA_ADD alone
// may go to 0 at a finite likelihood (data with a constant CV: a boundary
// estimate); it is a collapse only where a prediction is 0 (the ML loss's own
// zero level, kZeroPredictionLevel). Sets `why`.
bool CollapsedSigma(const Objective& objective, const Eigen::VectorXd& values, const Eigen::VectorXd& yhat,
                    int structural, std::string* why) {
  const int ia = objective.ParameterIndex(kSigmaAdd), ip = objective.ParameterIndex(kSigmaProp);
  const Eigen::VectorXd& y = objective.observations();
  const int nobs = static_cast<int>(y.size());
  if (nobs == 0 || yhat.size() != nobs) return false;
  const double scale = y.cwiseAbs().maxCoeff();
  const double a = ia >= 0 ? std::fabs(values(ia)) : 0, b = ip >= 0 ? std::fabs(values(ip)) : 0;
  const bool a_gone = SigmaAtZero(objective, values, ia), b_gone = SigmaAtZero(objective, values, ip);
  std::string what;
  int at = -1;  // a sample predicted as 0
  if (ia < 0 || ip < 0) {  // one σ: SIGMA_ADD, SIGMA_PROP or the exponential error's SIGMA_LOG
    const int is = ia >= 0 ? ia : ip >= 0 ? ip : objective.ParameterIndex(kSigmaLog);
    if (!SigmaAtZero(objective, values, is)) return false;
    what = objective.parameter_names()[is] + " fell to " + Num(std::fabs(values(is)), "%.3g");
    if (is == ia) what += ", " + Num(a / scale, "%.2g") + " of the largest DV";
  } else {
    if (!a_gone) return false;
    if (!b_gone) {
      const double zero = kZeroPredictionLevel * yhat.cwiseAbs().maxCoeff();
      // (A censored sample predicted as 0 is not one: its probability goes to 1, not its density to ∞.)
      for (int k = 0; k < nobs && at < 0; ++k) {
        if (std::fabs(yhat(k)) <= zero && objective.censoring()(k) == 0) at = k;
      }
      if (at < 0) return false;
      what = "the sample at TIME " + Num(objective.sample_times()[at]) + " (DV " + Num(y(at)) + ", prediction " +
             Num(yhat(at), "%.3g") + ") has a σ of " + Num(a, "%.3g") + ", " + Num(a / scale, "%.2g") +
             " of the largest DV";
    } else {
      what = "SIGMA_ADD fell to " + Num(a, "%.3g") + " and SIGMA_PROP to " + Num(b, "%.3g");
    }
  }
  std::string cause;
  if (nobs <= structural) {
    cause = "with " + std::to_string(nobs) + " samples for " + std::to_string(structural) +
            " model parameters the curve passes through every sample; fix some parameters or σ, or fit the population";
  } else if (at >= 0) {
    cause = "its prediction is 0, so its σ is SIGMA_ADD alone; give it MDV=1, or fix SIGMA_ADD";
  } else {
    cause = "the curve passes through the samples; fix σ, or use least squares";
  }
  *why = "the likelihood has no maximum: " + what + " (" + cause + ")";
  return true;
}

}  // namespace

FitSummary Fit(const Objective& objective, const std::vector<ParameterSpec>& params, const FitOptions& options) {
  const auto t0 = Clock::now();
  std::string why;
  if (!options.IsValid(&why)) throw InputError("", 0, 0, why);
  FitSummary summary;
  summary.optimizer = options.optimizer == OptimizerType::kNlopt ? "nlopt:" + options.nlopt_algorithm
                                                                 : ToString(options.optimizer);
  summary.num_samples = objective.num_samples();
  const bool ml = objective.options().error_model != ErrorModel::kLeastSquares;
  if (!IsCompatible(options, objective.options(), &why)) throw InputError("", 0, 0, why);

  Eigen::VectorXd base = objective.DefaultValues();
  std::vector<int> free;
  std::vector<Transform> tr;
  for (const ParameterSpec& p : params) {
    const int i = objective.ParameterIndex(p.name);
    if (i < 0) {
      throw InputError("", 0, 0, "unknown parameter '" + p.name + "'; this model has " +
                                     internal::Join(objective.parameter_names(), ", "));
    }
    if (!std::isnan(p.initial)) base(i) = p.initial;  // NaN: the objective's default
    ParameterEstimate est;
    est.name = objective.parameter_names()[i];
    const double initial = base(i);
    est.estimate = initial;
    est.fixed = p.fixed;
    summary.estimates.push_back(est);
    if (p.fixed) continue;
    if (!(p.lower < p.upper) || !(initial > p.lower) || !(initial < p.upper)) {
      throw InputError("", 0, 0, "initial value of " + est.name + " (" + Num(initial) + ") must lie strictly within its bounds");
    }
    Transform t;
    t.log = options.log_scale;
    if (t.log && !(initial > 0)) {
      throw InputError("", 0, 0, est.name + " is estimated on the log scale, so its initial value must be positive");
    }
    if (t.log) {
      t.sl = p.lower > 0 ? std::log(p.lower) : -INFINITY;
      t.su = std::isfinite(p.upper) ? std::log(p.upper) : INFINITY;
    } else {
      t.sl = p.lower;
      t.su = p.upper;
    }
    free.push_back(i);
    tr.push_back(t);
    summary.estimated.push_back(est.name);
  }
  objective.CheckValues(base);
  Problem pb(objective, free, tr, base);
  const int n = pb.n();
  const Eigen::VectorXd phi0 = pb.PhiOf(base);

  // LM and Newton start by asking for the Jacobian here, so ask for it now.
  const bool jacobian_first =
      n > 0 && (options.optimizer == OptimizerType::kLevenbergMarquardt || options.optimizer == OptimizerType::kNewton);
  const Objective::Evaluation* start_ev = &pb.Eval(phi0, jacobian_first ? Need::kJacobian : Need::kValue);
  if (!start_ev->ok && jacobian_first) start_ev = &pb.Eval(phi0, Need::kValue);
  const Objective::Evaluation& first = *start_ev;
  summary.initial_objective = first.ok ? first.value : NAN;
  const int residuals = objective.num_residuals();

  RunResult best;
  if (n == 0) {
    best.phi = phi0;
    best.value = summary.initial_objective;
    best.termination = first.ok ? TerminationType::kConvergence : TerminationType::kFailure;
    best.message = first.ok ? "nothing to estimate" : first.message;
  } else if (!ml && options.optimizer == OptimizerType::kLevenbergMarquardt && residuals < n) {
    best.phi = phi0;
    best.message = "fewer samples (" + std::to_string(residuals) + ") than estimated parameters (" +
                   std::to_string(n) + ")";
  } else {
    std::mt19937 rng(options.seed);
    std::normal_distribution<double> normal(0.0, 1.0);
    for (int s = 0; s < options.starts; ++s) {
      Eigen::VectorXd start = phi0;
      if (s > 0) {
        for (int k = 0; k < n; ++k) start(k) += options.start_spread * normal(rng);
      }
      RunResult r;
      const Objective::Evaluation& e0 = pb.Eval(start, Need::kValue);
      if (!e0.ok) {
        r.phi = start;
        r.message = "the objective could not be evaluated at the start: " + e0.message;
      } else {
        switch (options.optimizer) {
          case OptimizerType::kLevenbergMarquardt: r = RunLm(&pb, residuals, start, options); break;
          case OptimizerType::kBfgs: r = RunNlopt(&pb, "LD_LBFGS", start, options); break;
          case OptimizerType::kNlopt: r = RunNlopt(&pb, options.nlopt_algorithm, start, options); break;
          case OptimizerType::kNewton: r = RunNewton(&pb, start, options); break;
        }
      }
      const Objective::Evaluation& end = pb.Eval(r.phi, Need::kValue);
      r.value = end.ok ? end.value : NAN;
      if (!end.ok) {
        r.termination = TerminationType::kFailure;
        if (r.message.empty()) r.message = end.message;
      }
      const bool better = std::isfinite(r.value) && (!std::isfinite(best.value) || r.value < best.value);
      if (s == 0 || better) {
        if (better || !std::isfinite(best.value)) summary.best_start = s;
        best = r;
      }
    }
  }

  summary.termination = best.termination;
  summary.message = best.message;
  summary.iterations = best.iterations;
  summary.objective = best.value;
  summary.values = pb.Values(best.phi);
  summary.gradient = pb.route();
  summary.propagator = pb.propagator();
  if (ml && n > 0 && std::isfinite(best.value)) {
    const Objective::Evaluation& end = pb.Eval(best.phi, Need::kValue);
    int structural = 0;
    for (const std::string& name : summary.estimated) structural += IsResidualErrorName(name) ? 0 : 1;
    std::string collapse;
    if (end.ok && CollapsedSigma(objective, summary.values, end.predictions, structural, &collapse)) {
      summary.termination = TerminationType::kUnbounded;
      summary.message = collapse;
    }
  }

  // Estimates, and the covariance at the optimum from the Jacobian or information.
  for (ParameterEstimate& est : summary.estimates) est.estimate = summary.values(objective.ParameterIndex(est.name));
  if (summary.termination == TerminationType::kUnbounded) {
    summary.covariance_message = "the likelihood has no maximum";
  } else if (n > 0 && std::isfinite(best.value)) {
    const Objective::Evaluation& ev = pb.Eval(best.phi, Need::kJacobian);
    // The standard errors need the Jacobian; say so when that route differs
    // from the one the optimiser used.
    if (summary.gradient == "none") {
      summary.gradient = pb.route();
    } else if (pb.route() != summary.gradient) {
      summary.gradient += " (SE: " + pb.route() + ")";
    }
    const int nobs = objective.num_samples();
    if (!ev.ok) {
      summary.covariance_message = "the Jacobian could not be evaluated at the estimate: " + ev.message;
    } else if (!ml && nobs <= n) {
      summary.covariance_message = "no degrees of freedom left for the residual variance";
    } else {
      // A σ gone to 0 at a finite likelihood (one part of a combined error: a
      // boundary estimate) carries no information, since ∂σ_k²/∂log σ ∝ σ² → 0.
      // The others' covariance is then the one with that σ held at 0, which is
      // the covariance of the fit with the simpler error model.
      std::vector<int> keep;
      std::vector<std::string> at_zero;
      for (int j = 0; j < n; ++j) {
        if (ml && SigmaAtZero(objective, summary.values, free[j])) {
          at_zero.push_back(objective.parameter_names()[free[j]]);
        } else {
          keep.push_back(j);
        }
      }
      const int nk = static_cast<int>(keep.size());
      Eigen::MatrixXd info(nk, nk);
      for (int a = 0; a < nk; ++a) {
        for (int b = 0; b < nk; ++b) info(a, b) = ev.information(keep[a], keep[b]);
      }
      Eigen::FullPivLU<Eigen::MatrixXd> lu;
      lu.setThreshold(1e-12);
      const bool finite = info.allFinite();
      if (finite) lu.compute(info);
      if (!finite) {
        summary.covariance_message = "the information matrix is not finite at the estimate";
      } else if (nk == 0 || lu.rank() < nk) {
        std::vector<std::string> kept_names;
        Eigen::VectorXd ds_dphi(nk);
        for (int a = 0; a < nk; ++a) {
          kept_names.push_back(summary.estimated[keep[a]]);
          ds_dphi(a) = tr[keep[a]].DsDphi(best.phi(keep[a]));
        }
        const std::string what = internal::Unidentified(info, nk - static_cast<int>(lu.rank()), kept_names, ds_dphi, options.log_scale);
        summary.covariance_message = "the information matrix is singular: " +
                                     (what.empty() ? std::string("some parameters are not identifiable") : what);
      } else {
        Eigen::MatrixXd kept = lu.inverse();
        if (!ml) {
          double v_data = 0.5 * ev.residuals.head(nobs).squaredNorm();
          kept *= 2 * v_data / (nobs - n);
        }
        const Eigen::VectorXd d = pb.Dtheta(best.phi);
        summary.covariance = Eigen::MatrixXd::Constant(n, n, NAN);
        summary.correlation = Eigen::MatrixXd::Constant(n, n, NAN);
        Eigen::VectorXd sd = Eigen::VectorXd::Constant(n, NAN);
        for (int a = 0; a < nk; ++a) {
          for (int b = 0; b < nk; ++b) summary.covariance(keep[a], keep[b]) = d(keep[a]) * kept(a, b) * d(keep[b]);
          sd(keep[a]) = std::sqrt(std::max(0.0, summary.covariance(keep[a], keep[a])));
        }
        for (int a : keep) {
          for (int b : keep) summary.correlation(a, b) = summary.covariance(a, b) / (sd(a) * sd(b));
        }
        int k = 0;
        for (ParameterEstimate& est : summary.estimates) {
          if (est.fixed) continue;
          est.se = sd(k++);
          est.rse_pct = 100 * est.se / std::fabs(est.estimate);
        }
        if (!at_zero.empty()) {
          summary.covariance_message = internal::Join(at_zero, " and ") +
                                       " went to 0, the edge of its range: it has no SE, and the other SEs are those "
                                       "of a fit without it";
        }
      }
    }
    // −2LL, AIC, BIC.
    if (ev.ok) {
      double m2ll = 0;
      int k = n;
      if (ml) {
        m2ll = 2 * best.value;
      } else {
        const double rss = ev.residuals.head(nobs).squaredNorm();
        double sum_log_w = 0;
        for (int j = 0; j < nobs; ++j) {
          if (objective.weights()(j) > 0) sum_log_w += std::log(objective.weights()(j));
        }
        m2ll = nobs * (std::log(2 * M_PI * rss / nobs) + 1) - sum_log_w;
        k = n + 1;  // the residual variance
      }
      summary.minus2ll = m2ll;
      summary.aic = m2ll + 2 * k;
      summary.bic = m2ll + k * std::log(static_cast<double>(nobs));
    }
  }
  if (!best.held.empty()) {
    std::vector<std::string> held;
    for (int k : best.held) held.push_back(pb.Name(k) + " at its initial value " + Num(summary.values(free[k])));
    const std::string what = "LM held " + internal::Join(held, " and ") +
                             (held.size() == 1 ? " (the Jacobian is singular along it)"
                                               : " (the Jacobian is singular along each of them)");
    summary.message += " (" + what + ")";
    if (!summary.covariance_message.empty()) summary.covariance_message += "; " + what;
  }
  summary.evaluations = pb.evaluations();
  summary.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  return summary;
}

std::string FitSummary::BriefReport() const {
  std::ostringstream out;
  const char* status = "failed";
  switch (termination) {
    case TerminationType::kConvergence: status = "converged"; break;
    case TerminationType::kNoConvergence: status = "did not converge"; break;
    case TerminationType::kUnbounded: status = "unbounded"; break;
    case TerminationType::kFailure: break;
  }
  out << optimizer << " (" << propagator << " propagator, " << gradient << " gradient): " << status << " after " << iterations
      << " iterations, objective " << Num(initial_objective) << " -> " << Num(objective) << ", "
      << Num(seconds * 1e3, "%.3g") << " ms (" << message << ")";
  return out.str();
}

std::string FitSummary::CovarianceNote() const {
  if (covariance_message.empty()) return "";
  const bool some = std::any_of(estimates.begin(), estimates.end(),
                                [](const ParameterEstimate& e) { return std::isfinite(e.se); });
  return (some ? "" : "no standard errors: ") + covariance_message;
}

std::string FitSummary::FullReport() const {
  std::ostringstream out;
  out << BriefReport() << "\n\n";
  char line[256];
  std::snprintf(line, sizeof line, "  %-12s %14s %14s %9s\n", "parameter", "estimate", "SE", "RSE%");
  out << line;
  for (const ParameterEstimate& e : estimates) {
    if (e.fixed) {
      std::snprintf(line, sizeof line, "  %-12s %14.6g %14s %9s\n", e.name.c_str(), e.estimate, "(fixed)", "");
    } else {
      std::snprintf(line, sizeof line, "  %-12s %14.6g %s %s\n", e.name.c_str(), e.estimate, Cell(e.se, "%.4g", 14).c_str(),
                    Cell(e.rse_pct, "%.3g", 9).c_str());
    }
    out << line;
  }
  if (!covariance_message.empty()) out << "  (" << CovarianceNote() << ")\n";
  if (correlation.size() > 0 && estimated.size() > 1) {
    out << "\n  correlation\n" << internal::LowerTriangle(estimated, correlation, 12);
  }
  out << "\n  samples " << num_samples << ", evaluations " << evaluations << ", best start " << best_start
      << "\n  -2LL " << Num(minus2ll) << ", AIC " << Num(aic) << ", BIC " << Num(bic) << "\n";
  return out.str();
}

}  // namespace pk
