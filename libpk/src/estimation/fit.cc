// Fit: the parameters onto the optimiser's scale, the starts, the chosen minimiser
// (minimizer.h), the collapse check and the covariance step (covariance.h).
#include "pk/fit.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <random>
#include <sstream>

#include "estimation/covariance.h"
#include "estimation/minimizer.h"
#include "estimation/problem.h"
#include "internal_text.h"
#include "pk/error.h"

namespace pk {

bool FitOptions::IsValid(std::string* error) const {
  auto fail = [&](const std::string& why) {
    if (error) *error = why;
    return false;
  };
  if (max_iterations < 1) return fail("max_iterations must be at least 1");
  if (!(function_tolerance >= 0) || !(parameter_tolerance >= 0) || !(gradient_tolerance >= 0)) {
    return fail("tolerances must not be negative");
  }
  if (starts < 1 || starts > kMaxStarts) return fail("starts must be from 1 to " + std::to_string(kMaxStarts));
  if (!(start_spread >= 0)) return fail("start_spread must not be negative");
  std::string why;
  if (!internal::MakeMinimizer(optimizer, &why)) return fail(why);
  return true;
}

bool IsCompatible(const FitOptions& fit, const ObjectiveOptions& objective, std::string* why) {
  std::string unused;
  const auto minimizer = internal::MakeMinimizer(fit.optimizer, &unused);
  if (!minimizer) return true;  // FitOptions::IsValid says why
  if (objective.error_model->is_likelihood() && minimizer->needs_residuals()) {
    if (why) *why = fit.optimizer + " minimises a sum of squares; for maximum likelihood use bfgs, newton or nlopt:NAME";
    return false;
  }
  if (objective.gradient == GradientRoute::kAdjoint && minimizer->needs_jacobian()) {
    if (why) {
      *why = fit.optimizer +
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
using internal::Problem;
using internal::RunResult;
using internal::Transform;

// The estimated parameters' transforms and the full starting vector, with summary->estimates and
// summary->estimated filled in. Throws pk::InputError for an unknown name or a bad initial value.
Problem SetUp(const Objective& objective, const std::vector<ParameterSpec>& params, const FitOptions& options,
              FitSummary* summary) {
  Eigen::VectorXd base = objective.DefaultValues();
  std::vector<int> free;
  std::vector<Transform> tr;
  for (const ParameterSpec& p : params) {
    const int i = objective.ParameterIndex(p.name);
    if (i < 0) {
      throw InputError(objective.model().UnknownParameter(p.name, objective.parameter_names()));
    }
    if (!std::isnan(p.initial)) base(i) = p.initial;  // NaN: the objective's default
    ParameterEstimate est;
    est.name = objective.parameter_names()[i];
    const double initial = base(i);
    est.estimate = initial;
    est.fixed = p.fixed;
    summary->estimates.push_back(est);
    if (p.fixed) continue;
    if (!(p.lower < p.upper) || !(initial > p.lower) || !(initial < p.upper)) {
      throw InputError("initial value of " + est.name + " (" + Num(initial) + ") must lie strictly within its bounds");
    }
    Transform t;
    t.log = options.log_scale;
    if (t.log && !(initial > 0)) {
      throw InputError(est.name + " is estimated on the log scale, so its initial value must be positive");
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
    summary->estimated.push_back(est.name);
  }
  objective.CheckValues(base);
  return Problem(objective, free, tr, base);
}

// The best of options.starts runs (the first from φ0, the others spread around it).
RunResult BestOfStarts(Problem* pb, const internal::Minimizer& minimizer, const Eigen::VectorXd& phi0,
                       const FitOptions& options, FitSummary* summary) {
  RunResult best;
  std::mt19937 rng(options.seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  for (int s = 0; s < options.starts; ++s) {
    Eigen::VectorXd start = phi0;
    if (s > 0) {
      for (int k = 0; k < pb->n(); ++k) start(k) += options.start_spread * normal(rng);
    }
    RunResult r;
    const Objective::Evaluation& e0 = pb->Eval(start, Need::kValue);
    if (!e0.ok) {
      r.phi = start;
      r.message = "the objective could not be evaluated at the start: " + e0.message;
    } else {
      r = minimizer.Minimize(pb, start, options);
    }
    const Objective::Evaluation& end = pb->Eval(r.phi, Need::kValue);
    r.value = end.ok ? end.value : NAN;
    if (!end.ok) {
      r.termination = TerminationType::kFailure;
      if (r.message.empty()) r.message = end.message;
    }
    const bool better = std::isfinite(r.value) && (!std::isfinite(best.value) || r.value < best.value);
    if (s == 0 || better) {
      if (better || !std::isfinite(best.value)) summary->best_start = s;
      best = r;
    }
  }
  return best;
}

// Maximum likelihood: whether a σ collapsed with its residual (covariance.h).
void CheckCollapse(Problem* pb, const RunResult& best, FitSummary* summary) {
  const Objective::Evaluation& end = pb->Eval(best.phi, Need::kValue);
  int structural = 0;
  for (const std::string& name : summary->estimated) structural += IsResidualErrorName(name) ? 0 : 1;
  std::string collapse;
  if (end.ok && internal::CollapsedSigma(pb->objective(), summary->values, end.predictions, structural, &collapse)) {
    summary->termination = TerminationType::kUnbounded;
    summary->message = collapse;
  }
}

// LM held coordinates at their start (levenberg_marquardt.cc): say which, in the message and the note.
void NoteHeld(const Problem& pb, const RunResult& best, FitSummary* summary) {
  if (best.held.empty()) return;
  std::vector<std::string> held;
  for (int k : best.held) held.push_back(pb.Name(k) + " at its initial value " + Num(summary->values(pb.free()[k])));
  const std::string what = "LM held " + internal::Join(held, " and ") +
                           (held.size() == 1 ? " (the Jacobian is singular along it)"
                                             : " (the Jacobian is singular along each of them)");
  summary->message += " (" + what + ")";
  if (!summary->covariance_message.empty()) summary->covariance_message += "; " + what;
}

}  // namespace

FitSummary Fit(const Objective& objective, const std::vector<ParameterSpec>& params, const FitOptions& options) {
  const auto t0 = Clock::now();
  std::string why;
  if (!options.IsValid(&why)) throw InputError(why);
  if (!IsCompatible(options, objective.options(), &why)) throw InputError(why);
  const auto minimizer = internal::MakeMinimizer(options.optimizer, &why);
  FitSummary summary;
  summary.optimizer = options.optimizer;
  summary.num_samples = objective.num_samples();
  const bool ml = objective.error_model().is_likelihood();
  Problem pb = SetUp(objective, params, options, &summary);
  const int n = pb.n();
  const Eigen::VectorXd phi0 = pb.PhiOf(pb.base());

  // LM and Newton start by asking for the Jacobian here, so ask for it now.
  const bool jacobian_first = n > 0 && minimizer->needs_jacobian();
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
  } else if (minimizer->needs_residuals() && residuals < n) {
    best.phi = phi0;
    best.message = "fewer samples (" + std::to_string(residuals) + ") than estimated parameters (" +
                   std::to_string(n) + ")";
  } else {
    best = BestOfStarts(&pb, *minimizer, phi0, options, &summary);
  }

  summary.termination = best.termination;
  summary.message = best.message;
  summary.iterations = best.iterations;
  summary.objective = best.value;
  summary.values = pb.Values(best.phi);
  summary.gradient = pb.route();
  summary.propagator = pb.propagator();
  if (ml && n > 0 && std::isfinite(best.value)) CheckCollapse(&pb, best, &summary);
  for (ParameterEstimate& est : summary.estimates) est.estimate = summary.values(objective.ParameterIndex(est.name));
  if (summary.termination == TerminationType::kUnbounded) {
    summary.covariance_message = "the likelihood has no maximum";
  } else if (n > 0 && std::isfinite(best.value)) {
    internal::CovarianceStep(&pb, best.phi, options.log_scale, &summary);
  }
  NoteHeld(pb, best, &summary);
  summary.evaluations = pb.evaluations();
  summary.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  return summary;
}

std::string FitSummary::BriefReport() const {
  std::ostringstream out;
  const char* status = "failed";
  switch (termination) {
    case TerminationType::kConvergence: status = identifiable ? "converged" : "converged, not identifiable"; break;
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
    // Estimates to 4 significant digits, SE and RSE% to 3, as in every libpk table.
    if (e.fixed) {
      std::snprintf(line, sizeof line, "  %-12s %14.4g %14s %9s\n", e.name.c_str(), e.estimate, "(fixed)", "");
    } else if (e.at_bound) {
      std::snprintf(line, sizeof line, "  %-12s %14s %14s %9s\n", e.name.c_str(), "0 (bound)", "–", "–");
    } else {
      std::snprintf(line, sizeof line, "  %-12s %14.4g %s %s\n", e.name.c_str(), e.estimate, Cell(e.se, "%.3g", 14).c_str(),
                    Cell(e.rse_pct, "%.3g", 9).c_str());
    }
    out << line;
  }
  if (!covariance_message.empty()) out << "  (" << CovarianceNote() << ")\n";
  if (correlation.size() > 0 && estimated.size() > 1) {
    out << "\n  correlation\n" << internal::LowerTriangle(estimated, correlation, 12);
  }
  out << "\n  samples " << num_samples << ", evaluations " << evaluations << ", best start " << best_start
      << "\n  " << (std::isnan(ofv) ? "RSS " + Num(rss) : "OFV " + Num(ofv) + " (−2LL without N·log 2π)") << ", −2LL "
      << Num(minus2ll) << ", AIC " << Num(aic) << ", BIC " << Num(bic) << "\n";
  return out.str();
}

}  // namespace pk
