// FO, FOCE, FOCEI and Laplace estimation: the outer problem over θ, Ω and σ (pk/population.h).
//
// The outer optimiser is NLopt's L-BFGS on the packed vector x (packing.h). Its gradient comes
// from the implicit function theorem on the conditional modes (outer_gradient.h): one pass over
// each subject's samples at its mode (FO: at η = 0, which does not move). Where the exact
// derivatives do not reach, or when asked, it is central differences of the OFV with every subject's search started from the
// centre's modes, so that the differences see the smooth objective and not the inner
// iteration's path (NONMEM differences its outer objective). The modes are found to
// ‖Δη‖∞ < 1e-10 on the exact propagator (100·rtol on the ODE propagator), which keeps the
// differences' noise near 1e-6 there.
#include <algorithm>
#include <chrono>
#include <cmath>

#include "estimation/nlopt.h"
#include "internal_text.h"
#include "pk/output.h"
#include "pk/error.h"
#include "pk/parameters.h"
#include "pk/propagator.h"
#include "population/engine.h"
#include "population/outer_gradient.h"
#include "population/problem_impl.h"

namespace pk {
namespace internal {

void CheckMethod(const PopulationProblem& problem, PopulationMethod method);

PopulationEngine::PopulationEngine(const PopulationProblem& problem, PopulationMethod method, int threads,
                                   std::shared_ptr<const SubjectDistribution> distribution)
    : problem_(problem), method_(method), threads_(threads), distribution_(std::move(distribution)),
      included_(static_cast<size_t>(problem.num_subjects()), true) {
  if (distribution_ && distribution_->size() == 1) distribution_.reset();
}

// The subjects this process solves: those taking part, and with `shared` only its own. Threads
// take every threads-th of them, so that both the processes and the threads share the work.
std::vector<int> PopulationEngine::Work(bool shared) const {
  std::vector<int> mine;
  for (int i = 0; i < problem_.num_subjects(); ++i) {
    if (included_[static_cast<size_t>(i)] && (!shared || Owns(i))) mine.push_back(i);
  }
  return mine;
}

// Each process has the modes of its own subjects; afterwards every process has every subject's
// ok, OFV_i and η̂_i (summed with the others' zeros, hence exact) and the failed ones' messages.
void PopulationEngine::Share(std::vector<SubjectMode>* modes) const {
  const int n = problem_.num_subjects();
  const Eigen::Index q = static_cast<Eigen::Index>(problem_.eta_names().size());
  const Eigen::Index width = 2 + q;
  Eigen::VectorXd packed = Eigen::VectorXd::Zero(n * width);
  for (int i = 0; i < n; ++i) {
    const SubjectMode& m = (*modes)[static_cast<size_t>(i)];
    if (!included_[static_cast<size_t>(i)] || !Owns(i)) continue;
    packed(i * width) = m.ok ? 1 : 0;
    packed(i * width + 1) = m.ok ? m.ofv : 0;
    if (m.ok) packed.segment(i * width + 2, q) = m.eta;
  }
  distribution_->Sum(packed.data(), static_cast<int>(packed.size()));
  for (int i = 0; i < n; ++i) {
    SubjectMode& m = (*modes)[static_cast<size_t>(i)];
    if (!included_[static_cast<size_t>(i)]) continue;
    const bool ok = packed(i * width) > 0.5;
    if (!ok) m.message = distribution_->Broadcast(m.message, Owner(i));
    if (Owns(i)) continue;
    m.ok = ok;
    m.ofv = packed(i * width + 1);
    m.eta = packed.segment(i * width + 2, q);
  }
}

PopulationEngine::Result PopulationEngine::Evaluate(const PopulationParameters& p,
                                                    const std::vector<Eigen::VectorXd>& starts,
                                                    bool keep_modes, bool here) const {
  const auto& d = problem_.impl();
  Result r;
  PopulationPoint point;
  try {
    point = PopulationPoint::Make(p, *d.options.error_model, method_);
    point.exact_hessian = exact_hessian_;
  } catch (const InputError& e) {  // Ω underflowed (a variance of 1e-300) on an optimiser's trial step
    r.message = e.message();
    r.ofv = HUGE_VAL;
    return r;
  }
  const int n = problem_.num_subjects();
  std::vector<SubjectMode> modes(static_cast<size_t>(n));
  const bool shared = distribution_ && !here;
  const std::vector<int> mine = Work(shared);
  ParallelFor(static_cast<int>(mine.size()), threads_, [&](int k) {
    const auto u = static_cast<size_t>(mine[static_cast<size_t>(k)]);
    try {
      modes[u] = SolveSubject(d.subjects[u], point, starts[u]);
    } catch (const std::exception& e) {  // a subject's failure, reported as such (and shared)
      modes[u].ok = false;
      modes[u].message = e.what();
    }
  });
  if (shared) Share(&modes);
  r.ok = true;
  r.per_subject = Eigen::VectorXd::Zero(n);
  for (int i = 0; i < n; ++i) {
    const auto u = static_cast<size_t>(i);
    if (!included_[u]) continue;
    if (!modes[u].ok && r.ok) {
      r.ok = false;
      r.message = "subject " + FormatNumber(d.data->subjects[u].id) + ": " + modes[u].message;
    }
    r.per_subject(i) = modes[u].ofv;
  }
  r.ofv = r.ok ? r.per_subject.sum() : HUGE_VAL;
  if (keep_modes) r.modes = std::move(modes);
  return r;
}

bool PopulationEngine::Gradient(const Packing& packing, const Eigen::VectorXd& x,
                                const std::vector<SubjectMode>& modes, Eigen::VectorXd* gradient,
                                Eigen::MatrixXd* per_subject, std::string* why, Differenced* differenced) const {
  const auto& d = problem_.impl();
  const PopulationPoint point = PopulationPoint::Make(packing.Unpack(x), *d.options.error_model, method_);
  const int n = problem_.num_subjects();
  Eigen::MatrixXd rows = Eigen::MatrixXd::Zero(n, x.size());
  std::vector<std::string> errors(static_cast<size_t>(n)), reasons(static_cast<size_t>(n));
  std::vector<char> ok(static_cast<size_t>(n), 1);
  const std::vector<int> mine = Work(distribution_ != nullptr);
  ParallelFor(static_cast<int>(mine.size()), threads_, [&](int k) {
    const int i = mine[static_cast<size_t>(k)];
    const auto u = static_cast<size_t>(i);
    Eigen::VectorXd g;
    try {
      ok[u] = SubjectOuterGradient(d.subjects[u], point, packing, x, modes[u], &g, &reasons[u], &errors[u]);
    } catch (const std::exception& e) {
      ok[u] = false;
      errors[u] = e.what();
    }
    if (ok[u]) rows.row(i) = g.transpose();
  });
  Eigen::VectorXd differ(n);  // 1 where a subject's second order was differenced
  for (int i = 0; i < n; ++i) differ(i) = reasons[static_cast<size_t>(i)].empty() ? 0 : 1;
  if (distribution_) {  // every row from its owner, exactly, and the failures
    Eigen::VectorXd failed(n);
    for (int i = 0; i < n; ++i) failed(i) = ok[static_cast<size_t>(i)] ? 0 : 1;
    distribution_->Sum(rows.data(), static_cast<int>(rows.size()));
    distribution_->Sum(failed.data(), n);
    distribution_->Sum(differ.data(), n);
    for (int i = 0; i < n; ++i) ok[static_cast<size_t>(i)] = failed(i) < 0.5;
  }
  if (differenced) {
    differenced->subjects = static_cast<int>(differ.sum() + 0.5);
    for (const std::string& r : reasons) {
      if (!r.empty()) {
        differenced->reason = r;
        break;
      }
    }
  }
  for (int i = 0; i < n; ++i) {
    const auto u = static_cast<size_t>(i);
    if (ok[u]) continue;
    const std::string error = distribution_ ? distribution_->Broadcast(errors[u], Owner(i)) : errors[u];
    *why = "subject " + FormatNumber(d.data->subjects[u].id) + ": the outer gradient: " + error;
    return false;
  }
  *gradient = rows.colwise().sum().transpose();  // in subject order, whatever the threads
  if (per_subject) *per_subject = std::move(rows);
  return true;
}

namespace {

constexpr double kOuterStep = 1e-4;  // central-difference step in x
// An NLopt failure at a point whose gradient is below this (OFV per unit of x, where x moves log θ,
// log σ and Ω's Cholesky factor) is convergence: a 1% change of a log-scaled parameter moves the OFV
// by less than 1e-4 there (a signed θ or an off-diagonal Cholesky entry, by 0.01 per unit).
constexpr double kGradientTolerance = 1e-2;

std::vector<Eigen::VectorXd> Etas(const std::vector<SubjectMode>& modes, Eigen::Index q) {
  std::vector<Eigen::VectorXd> out;
  for (const SubjectMode& m : modes) out.push_back(m.ok ? m.eta : Eigen::VectorXd::Zero(q));
  return out;
}

// The first evaluation: subjects whose mode cannot be found are left out and reported.
std::string StartingPoint(PopulationEngine* engine, const PopulationParameters& p, std::vector<Eigen::VectorXd>* eta,
                          PopulationSummary* summary) {
  const auto& d = engine->problem().impl();
  PopulationEngine::Result r = engine->Evaluate(p, *eta, true);
  for (size_t i = 0; i < r.modes.size(); ++i) {
    if (r.modes[i].ok) continue;
    engine->Exclude(static_cast<int>(i));
    ++summary->failed_subjects;
    PopulationSubject s;
    s.id = d.data->subjects[i].id;
    s.subject = static_cast<int>(i);
    s.ok = false;
    s.message = "left out: at the initial estimates, " + r.modes[i].message;
    summary->subjects.push_back(s);
  }
  if (summary->failed_subjects == engine->problem().num_subjects()) {
    return "no subject's OFV_i (FO) or conditional mode could be evaluated at the initial estimates (" + r.message +
           "): check the starting values";
  }
  if (!r.ok) r = engine->Evaluate(p, *eta, true);
  *eta = Etas(r.modes, p.omega.rows());
  summary->initial_ofv = r.ofv;
  return r.ok ? "" : r.message;
}

// ∇OFV at xc (where the OFV is `ofv`) by central differences, every perturbed search started from
// the centre's modes; one-sided where the OFV cannot be evaluated on one side.
Eigen::VectorXd DifferenceGradient(const PopulationEngine& engine, const Packing& packing, const Eigen::VectorXd& xc,
                                   double ofv, const std::vector<Eigen::VectorXd>& centre) {
  Eigen::VectorXd g(xc.size());
  for (Eigen::Index k = 0; k < xc.size(); ++k) {
    Eigen::VectorXd xk = xc;
    xk(k) += kOuterStep;
    const double up = engine.Evaluate(packing.Unpack(xk), centre, false).ofv;
    xk(k) = xc(k) - kOuterStep;
    const double down = engine.Evaluate(packing.Unpack(xk), centre, false).ofv;
    if (up != HUGE_VAL && down != HUGE_VAL) {
      g(k) = (up - down) / (2 * kOuterStep);
    } else {
      g(k) = up != HUGE_VAL ? (up - ofv) / kOuterStep : down != HUGE_VAL ? (ofv - down) / kOuterStep : HUGE_VAL;
    }
  }
  return g;
}

// kAuto: the implicit gradient for every method, on every propagator: its second- and (Laplace)
// third-order sensitivities are exact on Φ/Γ and integrated with the state on the ODE propagator
// (ode/second_order.h).
bool UsesImplicitGradient(const PopulationOptions& o) { return o.gradient != PopulationGradient::kFiniteDifference; }

// Whether an η moves the doses: a dose modifier with an η of its own (a catalogue's F1), or a
// parameter that a computed modifier reads (a model file's F1 = exp(ETA_F)).
bool EtaMovesDoses(const PopulationProblem& problem) {
  const Model& model = problem.model();
  const ParameterLayout layout(model);
  const std::vector<int>& computed = layout.computed_reads();
  for (const std::string& name : problem.eta_names()) {
    const int i = layout.Index(name);
    if (i >= model.num_parameters() || std::binary_search(computed.begin(), computed.end(), i)) return true;
  }
  return false;
}

// What the summary says of the gradient.
std::string GradientDescription(const PopulationProblem& problem, const PopulationOptions& o) {
  if (!UsesImplicitGradient(o)) {
    return o.method == PopulationMethod::kFo ? "central differences of the OFV"
                                             : "central differences of the OFV (modes warm-started from the centre)";
  }
  const bool exact = ResolvePropagator(problem.model(), problem.options().propagator) == Propagator::kExact;
  const std::string moves = EtaMovesDoses(problem) ? "; along η that move the doses, the event engine on hyper-dual jets)" : ")";
  if (o.method == PopulationMethod::kFo) {
    return std::string("exact, at η = 0 (first- and second-order sensitivities ") +
           (exact ? "exact on Φ/Γ" : "integrated with the ODEs") + moves;
  }
  const char* orders = o.method == PopulationMethod::kLaplace ? "first-, second- and third-order" : "first- and second-order";
  return std::string("implicit function theorem on the conditional modes (") + orders + " sensitivities " +
         (exact ? "exact on Φ/Γ" : "integrated with the ODEs") + moves;
}

}  // namespace

// The outer minimisation; leaves the best x in *x and the modes' η in *eta.
void Minimize(const PopulationEngine& engine, const Packing& packing, const PopulationOptions& options,
              Eigen::VectorXd* x, std::vector<Eigen::VectorXd>* eta, PopulationSummary* summary) {
  const int n = packing.size();
  bool implicit = UsesImplicitGradient(options);
  // Second derivatives differenced from the ODE propagator's J carry its error over the step (1e-4–1e-3
  // of the OFV's own differences, measured on CVODES): where they would be, `auto` differences the OFV.
  const bool switchable = options.gradient == PopulationGradient::kAuto &&
                          ResolvePropagator(engine.problem().model(), engine.problem().options().propagator) !=
                              Propagator::kExact;
  // Laplace's gradient fails where a subject's second and third order cannot be exact (a hand-built
  // model's computed modifier without HyperDual3, or H differenced at the mode), which the subject's `differenced`
  // reason marks: a property of the problem, not of the point, so `auto` stops asking for it there. A
  // numerical failure of the higher orders themselves (a steady state's Newton, Dormand–Prince's step
  // limit on a stiff segment) is marked the same way and treated so, conservatively. Other failures (H
  // not positive definite at a wild trial point) take differences at that point only.
  const bool laplace_switchable = options.gradient == PopulationGradient::kAuto && options.method == PopulationMethod::kLaplace;
  int differenced_points = 0, switched_at = 0;
  std::string differenced_reason;
  double best = HUGE_VAL;
  int fallbacks = 0;  // evaluations whose implicit gradient could not be formed
  double best_gradient = HUGE_VAL;  // ‖∇OFV‖∞ at the best point
  auto f = [&](const double* xp, double* grad) {
    const Eigen::VectorXd xc = Eigen::Map<const Eigen::VectorXd>(xp, n);
    PopulationEngine::Result c = engine.Evaluate(packing.Unpack(xc), *eta, true);
    ++summary->evaluations;
    if (!c.ok) return HUGE_VAL;
    const std::vector<Eigen::VectorXd> centre = Etas(c.modes, eta->front().size());
    Eigen::VectorXd g = Eigen::VectorXd::Zero(n);
    std::string why;
    bool have = false;
    if (grad && implicit) {
      PopulationEngine::Differenced dn;
      have = engine.Gradient(packing, xc, c.modes, &g, nullptr, &why, &dn);
      if (have && dn.subjects > 0) {
        ++differenced_points;
        if (differenced_reason.empty()) differenced_reason = dn.reason;
        if (switchable) {  // from here on, differences of the OFV
          implicit = have = false;
          switched_at = summary->evaluations;
        }
      }
      if (!have && implicit && laplace_switchable && dn.subjects > 0) {
        implicit = false;
        switched_at = summary->evaluations;
        differenced_reason = why;
      } else if (!have && implicit) {
        ++fallbacks;
      }
    }
    if (grad && !have) g = DifferenceGradient(engine, packing, xc, c.ofv, centre);
    for (int k = 0; grad && k < n; ++k) grad[k] = g(k);
    if (c.ofv < best) {
      best = c.ofv;
      if (grad) best_gradient = g.lpNorm<Eigen::Infinity>();
      *x = xc;
      *eta = centre;
      if (options.progress) options.progress(summary->evaluations, c.ofv, g.norm());
    }
    summary->history.push_back({summary->evaluations, c.ofv, g.norm(), packing.Natural(packing.Unpack(xc))});
    return c.ofv;
  };
  // L-BFGS's first step is the negative gradient, which for an OFV of hundreds can move log θ by
  // hundreds. The optimiser sees OFV·c, c making the initial gradient's largest entry 1. And it
  // can stop with a failure after a poor step from poor starting values; it is restarted from the
  // best point while that keeps improving the OFV.
  std::vector<double> g0(static_cast<size_t>(n));
  if (f(x->data(), g0.data()) == HUGE_VAL) return;
  double largest = 0;
  for (double v : g0) largest = std::max(largest, std::abs(v));
  const double c = 1 / std::max(1.0, largest);
  auto scaled = [&](const double* xp, double* grad) {
    const double v = f(xp, grad);
    for (int k = 0; grad && k < n; ++k) grad[k] *= c;
    return v == HUGE_VAL ? v : c * v;
  };
  Nlopt::Outcome out;
  for (int restart = 0; restart < 5; ++restart) {
    const double before = best;
    Nlopt opt("LD_LBFGS", n);
    opt.SetRelativeTolerances(options.function_tolerance, options.parameter_tolerance);
    opt.SetMaxEvaluations(options.max_iterations - summary->evaluations);
    std::vector<double> xv(x->data(), x->data() + n);
    out = opt.Minimize(scaled, &xv);
    if (out.kind != Nlopt::Outcome::kFailure || !(best < before - 1e-6) ||
        summary->evaluations >= options.max_iterations) {
      break;
    }
  }
  if (fallbacks > 0) {
    summary->gradient += "; at " + std::to_string(fallbacks) + " point(s) central differences instead";
  }
  if (switched_at > 0) {
    summary->gradient += "; from evaluation " + std::to_string(switched_at) +
                         " central differences of the OFV, since the exact derivatives of the predictions do not "
                         "cover this problem (" + differenced_reason + ")";
  } else if (differenced_points > 0) {
    summary->gradient += "; at " + std::to_string(differenced_points) +
                         " point(s) some subjects' second derivatives were differences of the exact first ones (" +
                         differenced_reason + ")";
  }
  summary->converged = out.kind == Nlopt::Outcome::kConverged || out.kind == Nlopt::Outcome::kRoundoff;
  summary->message = out.result;
  if (out.kind == Nlopt::Outcome::kLimit) summary->message = "the evaluation limit was reached (" + out.result + ")";
  if (out.kind == Nlopt::Outcome::kFailure && best_gradient <= kGradientTolerance) {
    // L-BFGS's line search often ends so at the minimum, where rounding hides any decrease.
    summary->converged = true;
    summary->message = "the line search could not decrease the OFV further, at a point where ‖∇OFV‖∞ = " +
                       Num(best_gradient, "%.2g") + " (NLopt: " + out.result + ")";
  } else if (out.kind == Nlopt::Outcome::kFailure) {
    summary->message = "the outer optimiser failed (NLopt: " + out.result + (out.error.empty() ? "" : ", " + out.error) +
                       "); the OFV went from " + Num(summary->initial_ofv, "%.6g") + " to " + Num(best, "%.6g") +
                       ". Starting values far from the estimates cause this: give initial θ and Ω closer to them";
  }
}

// FO's objective has no η̂: the tables take FOCE's modes at the estimate (NONMEM's POSTHOC), each
// subject keeping its FO OFV_i. A subject whose mode cannot be found keeps η = 0, with a note.
void PostHocDiagnostics(const PopulationEngine& fo, const PopulationEngine::Result& at, PopulationSummary* summary) {
  PopulationEngine foce(fo.problem(), PopulationMethod::kFoce, fo.threads());
  foce.set_exact_hessian(fo.exact_hessian());
  for (size_t i = 0; i < fo.included().size(); ++i) {
    if (!fo.included()[i]) foce.Exclude(static_cast<int>(i));
  }
  const std::vector<Eigen::VectorXd> zero(at.modes.size(), Eigen::VectorXd::Zero(summary->parameters.omega.rows()));
  PopulationEngine::Result modes = foce.Evaluate(summary->parameters, zero, true, true);
  int missing = 0;
  for (size_t i = 0; i < modes.modes.size(); ++i) {
    if (!fo.included()[i]) continue;
    SubjectMode& m = modes.modes[i];
    if (!m.ok) {
      ++missing;
      const std::string why = m.message;
      m = at.modes[i];  // η = 0, FO's linearisation
      m.eta_estimated = false;
      m.message = "no post hoc η̂ (FOCE's mode: " + why + "): η = 0 in the tables";
    }
    m.ofv = at.modes[i].ofv;
  }
  PopulationDiagnostics(foce, summary->parameters, modes.modes, summary);
  summary->eta_estimates = "post hoc: FOCE's conditional modes at the FO estimate (NONMEM's POSTHOC)";
  if (missing > 0) {
    summary->eta_estimates += "; for " + std::to_string(missing) + " subject(s) whose mode was not found, η = 0";
  }
}

}  // namespace internal

PopulationSummary FitPopulation(const PopulationProblem& problem, const PopulationParameters& given_initial,
                                const PopulationOptions& given) {
  // No Ω structure given: the model file's $OMEGA blocks and FIX (diagonal for a catalogue model).
  PopulationOptions options = given;
  if (options.structure.omega_blocks.empty() && options.structure.omega_block_fixed.empty()) {
    const PopulationStructure declared = problem.DeclaredStructure();
    options.structure.omega_blocks = declared.omega_blocks;
    options.structure.omega_block_fixed = declared.omega_block_fixed;
    options.structure.omega_block_same = declared.omega_block_same;
  }
  const auto start = std::chrono::steady_clock::now();
  std::string why;
  if (!options.IsValid(&why)) throw InputError("population options: " + why);
  internal::CheckSizes(problem, given_initial);
  internal::CheckMethod(problem, options.method);
  const internal::Packing packing(problem, options.structure, given_initial);
  // The start as the packing holds it: a SAME block's values are its source's, whatever was given.
  const PopulationParameters& initial = packing.initial();
  internal::PopulationEngine engine(problem, options.method, options.threads, options.distribution);
  engine.set_exact_hessian(options.exact_conditional_hessian);
  PopulationSummary summary;
  summary.method = options.method;
  summary.eta_names = problem.eta_names();
  summary.gradient = internal::GradientDescription(problem, options);
  std::vector<Eigen::VectorXd> eta(static_cast<size_t>(problem.num_subjects()),
                                   Eigen::VectorXd::Zero(initial.omega.rows()));
  const std::string failure = internal::StartingPoint(&engine, initial, &eta, &summary);
  if (!failure.empty()) {
    summary.message = failure;
    summary.parameters = initial;
    return summary;
  }
  Eigen::VectorXd x = packing.Pack(initial);
  const bool estimate = packing.size() > 0 && options.max_iterations > 0;
  if (estimate) {
    internal::Minimize(engine, packing, options, &x, &eta, &summary);
  } else {  // nothing to move: the objective, diagnostics and covariance step where it stands
    summary.converged = true;
    summary.evaluations = 1;
    summary.message = packing.size() == 0
                          ? "nothing to estimate (every θ, Ω block and σ fixed): evaluated at the given values"
                          : "no estimation (max_iterations 0, NONMEM's MAXEVAL=0): evaluated at the initial estimates";
  }
  summary.parameters = estimate ? packing.Unpack(x) : initial;  // not through the packing's log and exp
  // Every process forms the diagnostics from every subject's mode.
  internal::PopulationEngine::Result final_eval = engine.Evaluate(summary.parameters, eta, true, true);
  summary.ofv = final_eval.ofv;
  if (!final_eval.ok) {
    summary.converged = false;
    summary.message = "the OFV cannot be evaluated at the estimate: " + final_eval.message;
  }
  summary.estimates.clear();
  const Eigen::VectorXd z = packing.Natural(summary.parameters);
  for (size_t k = 0; k < packing.natural_names().size(); ++k) {
    PopulationEstimate e;
    e.name = packing.natural_names()[k];
    e.estimate = z(static_cast<Eigen::Index>(k));
    e.fixed = packing.natural_fixed()[k];
    e.same = packing.natural_same()[k];
    e.source = e.same ? packing.NaturalSource(k) : -1;
    summary.estimates.push_back(e);
  }
  for (size_t k = 0; k < static_cast<size_t>(summary.parameters.theta.size()); ++k) {
    PopulationEstimate& e = summary.estimates[k];  // the θ come first
    e.at_boundary = !e.fixed && packing.NearThetaBound(k, e.estimate);
  }
  const std::vector<int>& variances = packing.variance_positions();
  for (size_t m = 0; m < variances.size(); ++m) {
    auto& e = summary.estimates[static_cast<size_t>(variances[m])];
    e.at_boundary = !e.fixed && e.estimate < 1e-6;
    // φ = θ·exp(η) is log-normal; a model file's η enters through the file's own expression.
    if (problem.impl().eta_log_normal[m]) e.cv_pct = 100 * std::sqrt(std::expm1(e.estimate));
  }
  summary.processes = options.distribution ? options.distribution->size() : 1;
  if (final_eval.ok) {
    eta = internal::Etas(final_eval.modes, initial.omega.rows());
    if (options.tables) {
      if (options.method == PopulationMethod::kFo) {
        internal::PostHocDiagnostics(engine, final_eval, &summary);
      } else {
        internal::PopulationDiagnostics(engine, summary.parameters, final_eval.modes, &summary);
      }
    }
    if (options.covariance) {
      internal::PopulationCovariance(engine, packing, eta, internal::UsesImplicitGradient(options),
                                     options.covariance_matrix, &summary);
    }
  }
  summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

}  // namespace pk
