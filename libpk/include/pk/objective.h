// libpk: the loss V(θ) of one subject and its gradient.
//
// Following the seed, V(θ) = ½∫(y − ŷ)ᵀ dF (y − ŷ): sampled measurements are
// jumps of F with weights W_k, so V is a sum of per-sample terms ℓ_k(ŷ_k, θ),
// plus optional prior terms in θ alone:
//
//   least squares (default)   ℓ_k = ½ W_k (y_k − ŷ_k)²
//                             W_k = 1, 1/DV², 1/DV, or a data column
//   maximum likelihood        ℓ_k = ½ [log(2π σ_k²) + (y_k − ŷ_k)²/σ_k²]
//                             σ_k² = SIGMA_ADD² + (SIGMA_PROP·ŷ_k)²  (additive,
//                             proportional or combined), the σ estimated jointly
//   exponential error (ML)    ℓ_k = ½ [log(2π σ²) + (log y_k − log ŷ_k)²/σ²] + log y_k
//                             σ = SIGMA_LOG: y = ŷ·e^ε, NONMEM's log-transform-
//                             both-sides; DV must be > 0 and ŷ > 0 at samples.
//                             The log y_k term (constant) makes V the likelihood
//                             of y, comparable with the other error models'.
//   censored sample (ML)      ℓ_k = −log Φ(s_k (y_k − ŷ_k)/σ_k), Beal's M3 (with
//                             log y_k and log ŷ_k for the exponential error)
//   prior (optional)          ½ ((log θ − log median) / sd)²
//
// Censored samples (a CENS column, as in Monolix and nlmixr2): CENS=1 says the
// value lies below DV, which holds the limit (a sample below the limit of
// quantification, BLQ, with DV = LLOQ); CENS=-1 says it lies above DV. Such a
// sample adds the log-probability of lying beyond its limit (s_k = CENS) under
// the error model, so it needs maximum likelihood; least squares refuses it
// (give MDV=1 to leave it out instead, Beal's M1). A LIMIT column (interval
// censoring, M4) is refused.
//
// The gradient routes need only ∂ℓ_k/∂ŷ_k and ∂ℓ_k/∂θ, so adding a loss never
// touches them (docs/gradients.md). Records with MDV=1 or without a DV are not
// samples.
//
// Continuous records (the seed's continuous dF/dt, ODE propagator only):
// observations with CONT=1 in a data column form a continuous record of their
// output (DVID), y_m linearly interpolated between consecutive CONT rows, and
// add ½∫ w (y − y_m)² ds to V, w per unit time from the weighting option (also
// interpolated). They are not samples and give no residuals, so they need a
// gradient optimiser (bfgs or an NLopt algorithm), not LM or Newton.
#ifndef PK_OBJECTIVE_H_
#define PK_OBJECTIVE_H_

#include <array>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "pk/dataset.h"
#include "pk/model.h"
#include "pk/ode_options.h"
#include "pk/propagator.h"
#include "pk/residual_error.h"

namespace pk {
namespace internal {
struct ObjectiveState;
}  // namespace internal

enum class Weighting { kUniform, kInverseDvSquared, kInverseDv, kColumn };
/// How the gradient (or residual Jacobian) is computed.
enum class GradientRoute {
  kAuto,              ///< forward when a Jacobian is needed; else the adjoint (exact), or forward
                      ///< sensitivities up to kOdeAdjointThreshold parameters and the adjoint beyond (ode)
  kForward,           ///< sensitivities: block exponentials (exact), or forward sensitivities (ode, rk)
  kAdjoint,           ///< discrete adjoint (exact, rk) or CVODES's adjoint (ode): gradient only, one backward
                      ///< pass whatever the parameter count
  kFiniteDifference,  ///< central differences
  kCompanion,         ///< tf<n> models: two companion filters give every ∂y/∂a_i, ∂y/∂b_i
};

const char* ToString(Weighting w);
const char* ToString(GradientRoute r);
/// The route of this name (as ToString spells it); throws pk::InputError listing the names otherwise.
GradientRoute ParseGradientRoute(const std::string& text);

struct ObjectiveOptions;
/// "uniform", "dv2", "dv" or "column:NAME" into options->weighting (and weight_column); throws
/// pk::InputError otherwise.
void ParseWeighting(const std::string& text, ObjectiveOptions* options);

struct ObjectiveOptions {
  Weighting weighting = Weighting::kUniform;  ///< least squares only
  std::string weight_column;                  ///< the data column for Weighting::kColumn
  /// Least squares, or a likelihood (pk/residual_error.h: MakeResidualError("additive"), ...).
  std::shared_ptr<const ResidualErrorModel> error_model = LeastSquares();
  GradientRoute gradient = GradientRoute::kAuto;
  /// Central-difference step relative to |θ| (floor 1e-8). 0 (the default)
  /// picks it: 1e-5 for the exact propagator; for the ODE propagator
  /// rtol^(1/3), which balances the solver's noise (≈ rtol/step) against the
  /// truncation error (≈ step²).
  double fd_relative_step = 0;
  Propagator propagator = Propagator::kAuto;  ///< exact (Φ/Γ, linear models), ode (CVODES) or rk
  OdeOptions ode;                             ///< tolerances etc. of the ODE propagator
  /// Linear models, exact propagator: evaluate the loss and its derivatives in
  /// eigen-coordinates (Φ = V e^{Λh} V⁻¹) when A(θ) has real eigenvalues and a
  /// well-conditioned eigenbasis, which costs n scalar exponentials per step
  /// instead of a matrix exponential. Otherwise, or when false, the Padé
  /// exponentials are used. Both are exact; they agree to rounding (docs/gradients.md).
  bool modal_propagation = true;
  /// Least squares only: take censored samples (CENS ≠ 0) as samples, with DV their limit,
  /// instead of refusing them. For a caller that forms its own likelihood from the predictions
  /// and censoring() (the population methods' M3); a fit by least squares must not set it.
  bool keep_censored = false;

  bool IsValid(std::string* error) const;
};

/// With the ODE propagator and GradientRoute::kAuto, gradients over more free
/// model parameters than this use the adjoint (measured by pkbench; docs/performance.md).
constexpr int kOdeAdjointThreshold = 3;

/// Maximum likelihood: a prediction at or below this fraction of the subject's
/// largest |prediction| counts as 0 (rounding gives about 1e-15 where the drug
/// has not arrived). With a proportional error alone its variance is then 0 and
/// the evaluation fails, naming the sample; Fit's unbounded-likelihood check
/// uses the same level.
constexpr double kZeroPredictionLevel = 1e-12;

/// A normal prior on log θ: adds ½((log θ − log median)/sd_log)² to V.
struct LogNormalPrior {
  std::string parameter;
  double median = 1;
  double sd_log = 1;
};

class Objective {
 public:
  /// What an evaluation must produce.
  enum class Need { kValue, kGradient, kJacobian };

  struct Evaluation {
    bool ok = true;
    std::string message;          ///< why the evaluation failed, when !ok
    double value = 0;             ///< V(θ)
    Eigen::VectorXd gradient;     ///< ∂V/∂θ over the free parameters (Need::kGradient and above)
    Eigen::VectorXd predictions;  ///< ŷ_k
    /// Least squares: r_k = √W_k (y_k − ŷ_k) and ∂r/∂θ (Need::kJacobian).
    Eigen::VectorXd residuals;
    Eigen::MatrixXd jacobian;
    /// Gauss–Newton matrix (least squares) or expected Fisher information (ML;
    /// the Tobit model's for a censored sample), plus the prior's Hessian, over
    /// the free parameters (Need::kJacobian).
    Eigen::MatrixXd information;
    const char* route = "";       ///< the route that computed the derivatives
    const char* propagator = "";  ///< "exact", "ode" (CVODES) or "rk" (Dormand–Prince)
    /// Exact propagator: whether Φ/Γ ran in eigen-coordinates (ObjectiveOptions::modal_propagation).
    bool modal = false;
    OdeStatistics ode_statistics;  ///< the ODE propagator's work (ode only)
  };

  /// Binds subject `subject` of `data` to `model`. Throws pk::InputError for a
  /// dataset the model cannot take, an unknown weight column or prior parameter,
  /// or a non-positive weight.
  Objective(std::shared_ptr<const Model> model, std::shared_ptr<const Dataset> data, int subject,
            const ObjectiveOptions& options, std::vector<LogNormalPrior> priors = {});
  ~Objective();
  Objective(Objective&&) noexcept;

  /// The model's layout names (parameters, then F/ALAG/R/D per compartment),
  /// then SIGMA_ADD and/or SIGMA_PROP for maximum likelihood (SIGMA_LOG for the exponential error).
  const std::vector<std::string>& parameter_names() const;
  int ParameterIndex(const std::string& name) const;
  /// Catalogue defaults, F=1, ALAG=0, and σ starting values from the data.
  Eigen::VectorXd DefaultValues() const;
  /// The model's parameter vector (num_parameters() of the model) that governs record `record` of
  /// the subject at `values`: data columns and covariates of that record applied, as a prediction
  /// sees them.
  Eigen::VectorXd RecordParameters(const Eigen::VectorXd& values, int record) const;

  int num_samples() const;
  /// True when the subject has continuous records (CONT=1).
  bool has_continuous_records() const;
  /// The propagator in use (exact, ode or rk).
  Propagator propagator() const;
  /// Rows of Evaluation::residuals (least squares): the samples, then one per prior.
  int num_residuals() const;
  const Eigen::VectorXd& observations() const;
  const Eigen::VectorXd& weights() const;
  /// Per sample: 0 for a value, 1 when the value lies below DV, -1 above (CENS).
  const Eigen::VectorXi& censoring() const;
  int num_censored() const;
  std::vector<double> sample_times() const;
  /// Per sample: the index of its record in the subject's Subject::records (its covariates).
  std::vector<int> sample_records() const;
  /// The output each sample measures: its DVID for a nonlinear model, else 1.
  std::vector<int> sample_outputs() const;
  double subject_id() const;
  const Model& model() const;
  const ObjectiveOptions& options() const;
  /// The residual-error model (options().error_model) and the positions of its σ in parameter_names().
  const ResidualErrorModel& error_model() const;
  std::vector<int> sigma_indices() const;

  /// Evaluates at `values` (natural scale, one per parameter_names()),
  /// differentiating with respect to the parameters listed in `free`.
  /// Numerical failure is reported in the result, never thrown.
  Evaluation Evaluate(const Eigen::VectorXd& values, const std::vector<int>& free, Need need) const;
  /// The same with an explicit route (overriding options().gradient).
  Evaluation Evaluate(const Eigen::VectorXd& values, const std::vector<int>& free, Need need,
                      GradientRoute route) const;

  /// The predictions ŷ at `values` and, when `jacobian` is not null, ∂ŷ/∂p (samples × free, by
  /// forward sensitivities; zero columns for σ), without the loss: what a population engine needs
  /// of a subject at each step of its conditional problem. False with `why` on numerical failure,
  /// or for a subject with continuous records (CONT=1), whose loss is not a sum over samples.
  bool Sensitivities(const Eigen::VectorXd& values, const std::vector<int>& free, Eigen::VectorXd* predictions,
                     Eigen::MatrixXd* jacobian, std::string* why) const;

  /// Second derivatives of the predictions: (*second)[i] = ∂²ŷ/∂p_a∂p_b over the samples for
  /// pairs[i] = (a, b), positions in `free`: layout parameters (model parameters and dose
  /// modifiers; not σ). A linear model's are exact: the state's second derivatives run through the
  /// block-triangular exponential as the first ones do (docs/gradients.md), or, where a free
  /// parameter moves a dose (F, ALAG, R, D, X0 or K0 estimated, or a parameter a computed modifier
  /// reads), through the event engine on hyper-dual jets, a pass per pair. A nonlinear model's are
  /// forward sensitivities of the sensitivity system, integrated with x to the ODE tolerances
  /// (docs/ode_routes.md), steady states included, and a jet state integrated with the ODEs where
  /// a dose moves. False, with `why`, for continuous records (ODE), a computed modifier without an
  /// evaluation on HyperDual3, or on numerical failure.
  bool SecondDerivatives(const Eigen::VectorXd& values, const std::vector<int>& free,
                         const std::vector<std::pair<int, int>>& pairs, std::vector<Eigen::VectorXd>* second,
                         std::string* why) const;

  /// Third derivatives of the predictions: (*third)[i] = ∂³ŷ/∂p_a∂p_b∂p_c over the samples for
  /// triples[i] = {a, b, c}, positions in `free`, with SecondDerivatives' restrictions. The
  /// population's Laplace gradient needs them (the exact ½∇²l in its OFV holds ∂²ŷ). Exact on
  /// Φ/Γ (the state's truncated Taylor series in the free parameters, through the block-triangular
  /// exponential) and integrated with x on the ODE propagator. False, with `why`, otherwise or on
  /// numerical failure.
  bool ThirdDerivatives(const Eigen::VectorXd& values, const std::vector<int>& free,
                        const std::vector<std::array<int, 3>>& triples, std::vector<Eigen::VectorXd>* third,
                        std::string* why) const;

  /// Throws pk::InputError (file, line, column) when a dose needs a modifier
  /// these values do not supply or supply out of range (R<n>, D<n>, F<n>, ALAG<n>).
  void CheckValues(const Eigen::VectorXd& values) const;

  /// Each sample's residual on the scale of its error: √W_k (y_k − ŷ_k) for
  /// least squares; (y_k − ŷ_k)/σ_k for maximum likelihood, or
  /// (log y_k − log ŷ_k)/SIGMA_LOG for the exponential error; NaN for a
  /// censored sample. `predictions` are Evaluate's at `values`.
  Eigen::VectorXd ScaledResiduals(const Eigen::VectorXd& values, const Eigen::VectorXd& predictions) const;

  /// Predictions at arbitrary times (for plots): the subject's records with
  /// EVID 2 records added at `times`; returns the central concentration, or
  /// output `output` (1-based) of a nonlinear model.
  std::vector<double> PredictAt(const Eigen::VectorXd& values, const std::vector<double>& times,
                                int output = 1) const;

 private:
  std::unique_ptr<internal::ObjectiveState> impl_;
};

}  // namespace pk

#endif  // PK_OBJECTIVE_H_
