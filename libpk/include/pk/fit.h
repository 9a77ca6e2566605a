// libpk: fitting one subject's parameters (the seed's §3).
//
//   pk::Objective objective(model, data, subject, objective_options);
//   std::vector<pk::ParameterSpec> params = {{"KA", 1.5}, {"CL", 3}, {"V", 30}};
//   pk::FitOptions options;                       // Levenberg–Marquardt, log scale
//   pk::FitSummary summary = pk::Fit(objective, params, options);
//   std::cout << summary.FullReport();
//
// Parameters are estimated on the log scale by default. A parameter with
// bounds is mapped onto an unbounded scale (a logistic map between the bounds,
// on the log scale when log_scale is on), so every optimiser works unbounded.
// Parameters not listed in `params` keep the objective's default values.
//
// Optimisers (FitOptions::optimizer), one file each in libpk/src/estimation/:
//   "lm"          MINPACK's lmder (cminpack, the C translation of the Fortran
//                 original); least squares only. Iterations are its Jacobian
//                 evaluations.
//   "bfgs"        NLopt's LD_LBFGS (limited-memory BFGS)
//   "newton"      Newton in a trust region with the Gauss–Newton matrix (least
//                 squares) or the expected Fisher information (ML)
//   "nlopt:NAME"  any NLopt algorithm by name, e.g. nlopt:LN_BOBYQA, nlopt:LD_MMA
//
// Numerical failure never throws: the summary says what happened.
#ifndef PK_FIT_H_
#define PK_FIT_H_

#include <limits>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pk/objective.h"

namespace pk {

/// More starts than this find nothing that fewer would not; a larger count is a typing error.
inline constexpr int kMaxStarts = 1000;

struct FitOptions {
  std::string optimizer = "lm";    ///< "lm", "bfgs", "newton" or "nlopt:NAME" (see above)
  int max_iterations = 1000;       ///< iterations (LM, Newton) or evaluations (NLopt)
  double function_tolerance = 1e-12;   ///< relative change of V that ends the search
  double parameter_tolerance = 1e-10;  ///< relative change of the parameters that ends it
  double gradient_tolerance = 1e-10;   ///< max |∂V/∂φ| that ends it (Newton)
  bool log_scale = true;           ///< estimate log θ (θ > 0)
  int starts = 1;                  ///< starts spread around the initial values; the best is kept
  double start_spread = 0.5;       ///< SD of the spread, on the log scale
  unsigned seed = 20261121;        ///< for the spread of the starts (reproducible)

  bool IsValid(std::string* error) const;
};

/// One parameter to estimate (or to hold fixed).
struct ParameterSpec {
  std::string name;
  double initial = 1;  ///< NaN: the objective's default (catalogue value, or σ from the data)
  bool fixed = false;
  double lower = -std::numeric_limits<double>::infinity();
  double upper = std::numeric_limits<double>::infinity();
};

struct ParameterEstimate {
  std::string name;
  double estimate = 0;
  double se = std::numeric_limits<double>::quiet_NaN();       ///< standard error
  double rse_pct = std::numeric_limits<double>::quiet_NaN();  ///< 100·SE/|estimate|
  bool fixed = false;
  /// A σ that went to 0, the edge of its range (one part of a combined error): its estimate is
  /// 0 to the optimiser's precision and it has no SE. Reports print it as "0 (bound)".
  bool at_bound = false;
};

enum class TerminationType {
  kConvergence,    ///< a convergence test was met
  kNoConvergence,  ///< the iteration or evaluation limit was reached
  kFailure,        ///< the objective could not be evaluated, or the optimiser failed
  /// Maximum likelihood only: the likelihood has no maximum. A residual σ
  /// collapsed towards 0 with its sample's residual (the curve passes through
  /// every sample, or a combined error's additive σ alone carries a sample
  /// predicted as 0). The estimates are where the optimiser stopped; the
  /// message says which σ and why; there are no standard errors or −2LL.
  kUnbounded,
};

struct FitSummary {
  TerminationType termination = TerminationType::kFailure;
  std::string message;           ///< the optimiser's reason for stopping, or what failed
  bool converged() const { return termination == TerminationType::kConvergence; }

  double initial_objective = std::numeric_limits<double>::quiet_NaN();
  double objective = std::numeric_limits<double>::quiet_NaN();  ///< the minimised V
  int iterations = 0;
  int evaluations = 0;
  int best_start = 0;            ///< which start gave the result (0 = the initial values)
  int num_samples = 0;
  double seconds = 0;            ///< wall time of the whole fit
  std::string optimizer;
  std::string gradient;          ///< the route that computed the derivatives
  std::string propagator;        ///< "exact" (Φ/Γ), "ode" (CVODES) or "rk" (Dormand–Prince)

  std::vector<ParameterEstimate> estimates;  ///< every ParameterSpec, in order (fixed included)
  std::vector<std::string> estimated;        ///< the names of the estimated ones
  Eigen::MatrixXd covariance;                ///< of the estimated ones, natural scale
  Eigen::MatrixXd correlation;
  /// False when the information matrix is singular at the estimate: the data do not determine
  /// some parameter (covariance_message names it), so the estimates are one point of a ridge,
  /// not the answer, even when the optimiser converged. pkfit counts such a fit as failed, and
  /// the two-stage population estimates leave it out.
  bool identifiable = true;
  /// Why SEs are missing, if they are. With maximum likelihood a σ that went
  /// to 0 (one part of a combined error) gets no SE, and the others' SEs hold
  /// it at 0; this message then names it.
  std::string covariance_message;

  /// −2 log-likelihood: exact for ML; for least squares, the Gaussian
  /// likelihood with the residual variance profiled out (weights known up to scale).
  double minus2ll = std::numeric_limits<double>::quiet_NaN();
  /// Maximum likelihood: NONMEM's objective function value, −2 log L without the constant
  /// N·log 2π of the N uncensored samples ("OBJECTIVE FUNCTION VALUE WITHOUT CONSTANT"); NaN for
  /// least squares.
  double ofv = std::numeric_limits<double>::quiet_NaN();
  /// Least squares: the (weighted) residual sum of squares, 2V; NaN for maximum likelihood.
  double rss = std::numeric_limits<double>::quiet_NaN();
  double aic = std::numeric_limits<double>::quiet_NaN();
  double bic = std::numeric_limits<double>::quiet_NaN();

  Eigen::VectorXd values;        ///< the objective's full parameter vector at the estimate

  /// covariance_message as a note for a report: prefixed by "no standard
  /// errors: " when none could be computed; empty when there is nothing to say.
  std::string CovarianceNote() const;
  std::string BriefReport() const;
  std::string FullReport() const;
};

/// Whether an optimiser can work with an objective's settings: Levenberg–Marquardt
/// needs least squares; LM and Newton need the residual Jacobian, which the
/// adjoint route does not give. Sets `why` when not. (An unknown optimiser is
/// FitOptions::IsValid's to report.)
bool IsCompatible(const FitOptions& fit, const ObjectiveOptions& objective, std::string* why);

/// Fits `params` (names from objective.parameter_names()). Throws
/// pk::InputError for an unknown parameter name, invalid options, or an
/// initial value outside its bounds or not positive on the log scale.
FitSummary Fit(const Objective& objective, const std::vector<ParameterSpec>& params, const FitOptions& options);

}  // namespace pk

#endif  // PK_FIT_H_
