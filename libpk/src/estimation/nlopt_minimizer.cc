// Any NLopt algorithm by name ("nlopt:LN_BOBYQA"), on the unbounded scale of the fit.
//
// Lukšan's gradient-based NLopt algorithms run in a box around their start on the unbounded
// scale, moved to the result when it ends on the box's edge. Without it, L-BFGS's first line
// search may extrapolate by factors of 1e100 into a region where the likelihood is flat
// (CL → 0 with V → ∞ and σ → ∞ fits a constant) and stop there "converged". The box is a factor
// of 1000 either way for log-scale parameters; a parameter that still runs to the edge after
// kBoxMoves moves is reported as not determined by the data.
#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

#include "estimation/minimizer.h"
#include "estimation/nlopt.h"

namespace pk {
namespace internal {
namespace {

using Need = Objective::Need;

constexpr double kBoxLogHalfWidth = 6.907755278982137;  // ln 1000
constexpr int kBoxMoves = 6;

// The box around the start and the search inside it.
class BoxedSearch {
 public:
  BoxedSearch(const Problem& pb, const std::string& algorithm, std::vector<double>* x) : n_(pb.n()), x_(*x) {
    global_ = algorithm.rfind("G", 0) == 0;
    // Lukšan's line-search methods (L-BFGS, the variable-metric and truncated-Newton ones) extrapolate
    // without limit; MMA, CCSAQ and SLSQP control their steps themselves, and their steps depend on the bounds.
    moving_ = algorithm.rfind("LD_LBFGS", 0) == 0 || algorithm.rfind("LD_VAR", 0) == 0 ||
              algorithm.rfind("LD_TNEWTON", 0) == 0;
    half_.resize(n_);
    lo_.resize(n_);
    hi_.resize(n_);
    for (int k = 0; k < n_; ++k) {
      // Global algorithms need a finite box: e^±5 around the start on the unbounded scale.
      half_[k] = global_ ? 5.0 : (pb.LogLike(k) ? kBoxLogHalfWidth : 1000 * std::max(1.0, std::fabs(x_[k])));
    }
  }
  bool boxed() const { return global_ || moving_; }
  void Center(Nlopt* opt) {
    for (int k = 0; k < n_; ++k) {
      lo_[k] = x_[k] - half_[k];
      hi_[k] = x_[k] + half_[k];
    }
    opt->SetBounds(lo_, hi_);
  }
  // The first parameter on the box's edge (and whether on its lower side), or -1.
  int AtEdge(bool* low) const {
    if (!moving_) return -1;
    for (int k = 0; k < n_; ++k) {
      const double tol = 1e-6 * half_[k];
      *low = x_[k] - lo_[k] <= tol;
      if (*low || hi_[k] - x_[k] <= tol) return k;
    }
    return -1;
  }

 private:
  int n_;
  std::vector<double>& x_;
  bool global_ = false, moving_ = false;
  std::vector<double> half_, lo_, hi_;
};

void Terminate(const Nlopt::Outcome& out, Nlopt* opt, RunResult* r) {
  switch (out.kind) {
    case Nlopt::Outcome::kConverged:
    case Nlopt::Outcome::kLimit:
      r->termination = out.kind == Nlopt::Outcome::kConverged ? TerminationType::kConvergence
                                                              : TerminationType::kNoConvergence;
      r->message = "NLopt " + opt->algorithm_name() + ": " + out.result;
      break;
    case Nlopt::Outcome::kRoundoff:
      r->termination = TerminationType::kConvergence;
      r->message = "NLopt stopped: roundoff-limited (the optimum is resolved to machine precision)";
      break;
    case Nlopt::Outcome::kFailure:
      r->termination = TerminationType::kFailure;
      r->message = "NLopt failed: " + out.error;
      break;
  }
}

class NloptMinimizer final : public Minimizer {
 public:
  explicit NloptMinimizer(std::string algorithm) : algorithm_(std::move(algorithm)) {}
  RunResult Minimize(Problem* problem, const Eigen::VectorXd& phi0, const FitOptions& options) const override {
    return RunNlopt(problem, algorithm_, phi0, options);
  }

 private:
  std::string algorithm_;
};

}  // namespace

RunResult RunNlopt(Problem* pb, const std::string& algorithm, const Eigen::VectorXd& phi0, const FitOptions& o) {
  RunResult r;
  const int n = pb->n();
  Nlopt opt(algorithm, n);
  const NloptFunction f = [pb](const double* x, double* grad) {
    const Eigen::VectorXd phi = Eigen::Map<const Eigen::VectorXd>(x, pb->n());
    const Objective::Evaluation& ev = pb->Eval(phi, grad ? Need::kGradient : Need::kValue);
    if (!ev.ok) {
      if (grad) std::fill(grad, grad + pb->n(), 0.0);
      return 1e300;
    }
    if (grad) Eigen::Map<Eigen::VectorXd>(grad, pb->n()) = ev.gradient;
    return ev.value;
  };
  opt.SetRelativeTolerances(o.function_tolerance, o.parameter_tolerance);
  std::vector<double> x(phi0.data(), phi0.data() + n);
  BoxedSearch box(*pb, algorithm, &x);
  if (box.boxed()) box.Center(&opt);
  int evaluations = 0, edge = -1;
  bool edge_low = false;
  Nlopt::Outcome out;
  for (int move = 0;; ++move) {
    opt.SetMaxEvaluations(std::max(1, o.max_iterations - evaluations));
    out = opt.Minimize(f, &x);
    evaluations += out.evaluations;
    edge = out.kind == Nlopt::Outcome::kFailure ? -1 : box.AtEdge(&edge_low);
    if (out.kind == Nlopt::Outcome::kRoundoff || out.kind == Nlopt::Outcome::kFailure) break;
    if (edge < 0 || move == kBoxMoves || evaluations >= o.max_iterations) break;
    box.Center(&opt);
  }
  Terminate(out, &opt, &r);
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

std::unique_ptr<Minimizer> MakeNloptMinimizer(const std::string& algorithm, std::string* why) {
  if (!Nlopt::Knows(algorithm)) {
    *why = "unknown NLopt algorithm '" + algorithm + "' (for example LD_LBFGS, LN_BOBYQA, LD_MMA)";
    return nullptr;
  }
  return std::make_unique<NloptMinimizer>(algorithm);
}

}  // namespace internal
}  // namespace pk
