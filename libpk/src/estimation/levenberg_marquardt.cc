// Levenberg–Marquardt: MINPACK's lmder, through cminpack (libcminpack-dev), on the residual
// vector of least squares.
//
#include <algorithm>
#include <cmath>
#include <vector>

#include <cminpack.h>

#include "estimation/minimizer.h"
#include "identifiability.h"

namespace pk {
namespace internal {
namespace {

using Need = Objective::Need;

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
  if (!IntegratesOde(objective.propagator())) return kExact;
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
  const int j = NullCoordinate(jac(Eigen::all, moving), singular);
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

class LevenbergMarquardt final : public Minimizer {
 public:
  RunResult Minimize(Problem* problem, const Eigen::VectorXd& phi0, const FitOptions& options) const override {
    return RunLm(problem, problem->objective().num_residuals(), phi0, options);
  }
  bool needs_residuals() const override { return true; }
  bool needs_jacobian() const override { return true; }
};

}  // namespace

std::unique_ptr<Minimizer> MakeLevenbergMarquardt(const std::string&, std::string*) {
  return std::make_unique<LevenbergMarquardt>();
}

}  // namespace internal
}  // namespace pk
