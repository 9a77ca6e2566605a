// libpk: population (nonlinear mixed-effects) estimation by FO, FOCE, FOCEI and Laplace.
//
// Subject i's parameters vary about the typical values θ by random effects η_i ~ N(0, Ω):
//
//   φ_ik = θ_k · exp(η_ik)  for a parameter with an η (log-normal, NONMEM's CL=THETA(1)*EXP(ETA(1))),
//   φ_ik = θ_k              otherwise.
//
// A model file writes covariate relations itself (CL = TVCL*(WT/70)^0.75): an η on TVCL then gives
// NONMEM's CL=TVCL*(WT/70)**0.75*EXP(ETA(1)). Observations y_ij, on the scale T of the error model
// (y, or log y for the exponential error), have predictions f_ij(θ, η) and residual variances
// V_ij = v(ŷ_ij, σ) (pk/residual_error.h; σ are standard deviations, NONMEM's W=THETA·F with Σ
// fixed to 1). With
//
//   l_i(η) = Σ_j [ (y_ij − f_ij)²/V_ij + log V_ij ] + ηᵀΩ⁻¹η
//
// the objective is NONMEM's: OFV = Σ_i OFV_i, −2 log L without the n·log 2π constant, where
// (Wang, J Pharmacokinet Pharmacodyn 2007;34:575-593; docs/population.md derives them)
//
//   FOCEI    OFV_i = l_i(η̂_i) + log det Ω + log det H_i,
//            H_i = Ω⁻¹ + Σ_j [ g_j g_jᵀ/V_j + ½ v_j v_jᵀ/V_j² ],  g_j = ∂f_ij/∂η, v_j = ∂V_ij/∂η
//   FOCE     the same with V_ij evaluated at η = 0 (no interaction, v_j = 0); equal at the mode to
//            NONMEM's linearised form log det C_i + r̃ᵀC_i⁻¹r̃, C_i = G_iΩG_iᵀ + V_i
//   Laplace  H_i = ½ ∇²l_i(η̂_i), the full Hessian (with interaction)
//   FO       the linearisation at η = 0 instead of η̂: OFV_i = log det C_i + r_iᵀC_i⁻¹r_i with
//            C_i = G_iΩG_iᵀ + V_i, r_i = y_i − f_i, G_i, f_i and V_i at η = 0 (no search for a mode);
//            equal to FOCE's terms at η = 0 less ¼ ∇l_iᵀH_i⁻¹∇l_i. The η̂_i of its tables are post
//            hoc, FOCE's modes at the estimate (NONMEM's POSTHOC)
//
// and η̂_i = argmin l_i, the conditional mode, found for every evaluation to a step
// ‖Δη‖∞ < 1e-10 (on the ODE propagator, to the accuracy its tolerance allows).
//
//   pk::PopulationProblem problem = pk::MakePopulationProblem(model, data, {"CL", "V"}, error);
//   pk::PopulationOptions options;                 // FOCEI
//   pk::PopulationSummary fit = pk::FitPopulation(problem, initial, options);
//   std::cout << fit.FullReport();
//
// Outcomes (a subject whose mode cannot be found, an objective that cannot be evaluated, an
// optimiser that stops early) are reported in the summary, never thrown. Invalid input throws
// pk::InputError.
#ifndef PK_POPULATION_H_
#define PK_POPULATION_H_

#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pk/dataset.h"
#include "pk/model.h"
#include "pk/objective.h"

namespace pk {

enum class PopulationMethod {
  kFoce,     ///< NONMEM's METHOD=COND
  kFocei,    ///< METHOD=COND INTER
  kLaplace,  ///< METHOD=COND LAPLACIAN INTER
  kFo,       ///< METHOD=ZERO (first order, NONMEM's default), its tables' η̂ post hoc (POSTHOC)
};
const char* ToString(PopulationMethod m);
/// "fo", "foce", "focei" or "laplace" (case-insensitive); throws pk::InputError otherwise.
PopulationMethod ParsePopulationMethod(const std::string& text);

/// The population parameters: fixed effects θ (the model's estimated parameters), Ω over the
/// η in PopulationProblem::etas order, and the residual-error σ.
struct PopulationParameters {
  Eigen::VectorXd theta;
  Eigen::MatrixXd omega;
  Eigen::VectorXd sigma;
};

/// Which population parameters are estimated. Ω is block diagonal, as NONMEM's $OMEGA: each
/// η belongs to one block of consecutive η; a block of one is a variance alone. A block is
/// estimated whole (its variances and covariances) or fixed whole (FIX), or repeats the block
/// before it (SAME: NONMEM's BLOCK(n) SAME, inter-occasion variability), its values tied to that
/// block's: estimated with it, fixed with it, never apart.
struct PopulationStructure {
  std::vector<bool> theta_fixed;  ///< per θ; empty: none fixed
  std::vector<bool> sigma_fixed;  ///< per σ; empty: none fixed
  /// The size of each Ω block, in η order (summing to the number of η). Empty, with
  /// omega_block_fixed empty too: PopulationProblem::DeclaredStructure(), the model file's $OMEGA
  /// blocks and FIX (diagonal for a catalogue model).
  std::vector<int> omega_blocks;
  std::vector<bool> omega_block_fixed;  ///< per block; empty: none fixed
  /// Per block: whether it repeats the block before it (of its size; the first block cannot).
  /// Empty: none. A SAME block's own FIX flag is ignored: it follows its source's.
  std::vector<bool> omega_block_same;
};

/// A population problem: a model, a dataset, the parameters that carry an η, and the
/// residual-error model. The per-subject objectives are built once.
class PopulationProblem {
 public:
  /// Throws pk::InputError for an unknown η name, a covariate given an η, a dataset the model
  /// cannot take, or least squares as the error model.
  PopulationProblem(std::shared_ptr<const Model> model, std::shared_ptr<const Dataset> data,
                    std::vector<std::string> etas, const ObjectiveOptions& options);
  ~PopulationProblem();
  PopulationProblem(PopulationProblem&&) noexcept;

  /// The model's estimable parameters (covariates left out), in model order.
  const std::vector<std::string>& theta_names() const;
  /// The parameters with an η, in the order of Ω's rows.
  const std::vector<std::string>& eta_names() const;
  /// The error model's σ names (SIGMA_ADD, ...).
  const std::vector<std::string>& sigma_names() const;
  int num_subjects() const;
  int num_observations() const;
  /// Samples censored by a CENS column (below or above DV, the limit). Their likelihood is Beal's
  /// M3, −2 log Φ(CENS·(DV − f)/√V) in OFV_i, which only the Laplace method takes (as in NONMEM).
  int num_censored() const;
  const Model& model() const;
  const Dataset& data() const;
  const ObjectiveOptions& options() const;
  /// Starting values: θ the median over subjects of the data-driven starting values
  /// (pk/initial_estimates.h) for a model that declares the structure they need, else the
  /// model's defaults; Ω = 0.1·I; σ from the pooled observations.
  PopulationParameters DefaultParameters() const;
  /// Ω's structure as a model file's $OMEGA declares it: a block per $OMEGA line of more than one
  /// η (its η must be consecutive in eta_names()), blocks of one for the other η, and FIX lines
  /// fixed; θ and σ not fixed. For a catalogue model every η is a block of one. Throws
  /// pk::InputError when a declared block's η are not all in eta_names() or not consecutive there.
  PopulationStructure DeclaredStructure() const;

  /// Internal: the position of a model file's η in eta_names() (-1 when absent).
  int EtaPosition(const std::string& name) const;
  /// Internal: the per-subject machinery.
  struct Impl;
  const Impl& impl() const { return *impl_; }

 private:
  std::unique_ptr<Impl> impl_;
};

/// How the outer optimiser's gradient of the OFV is formed.
enum class PopulationGradient {
  /// kImplicit for every method, on every propagator. Where the exact derivatives do not reach (a
  /// hand-built model whose computed dose modifiers have no ComputedModifiers::evaluate_third, or
  /// Laplace's H differenced at the mode) it turns to kFiniteDifference from that point, and the
  /// summary says so.
  kAuto,
  /// By the implicit function theorem on each subject's conditional mode (Almquist et al. 2015):
  /// first- and second-order sensitivities of the predictions (Laplace: third-order too, since its
  /// OFV_i holds log det of the exact ½∇²l), exact on Φ/Γ, integrated with the ODEs on the ODE
  /// propagator (forward sensitivities of the sensitivity system), steady states included, and
  /// where a computed dose modifier reads an η'd parameter (the event engine on jets, on either
  /// propagator). For FOCE and FOCEI a subject whose higher orders fail takes
  /// Richardson-extrapolated differences of the exact first order instead, and the summary says
  /// so; Laplace's gradient then falls back to differences of the OFV there.
  kImplicit,
  /// Central differences of the OFV, the subjects' searches started from the centre's modes
  /// (what NONMEM does). Any method; the check on the others.
  kFiniteDifference,
};

/// Splits the subjects of a population problem across processes. Every process runs the same
/// outer optimisation on the same arguments; each solves the conditional modes of the subjects it
/// owns (subject i belongs to process i mod size()), and Sum() shares them. Since every other
/// process contributes exact zeros, the sums, and so every OFV and estimate, equal one process's
/// to the bit. pk/mpi.h implements it over MPI_COMM_WORLD (library pk::mpi, built with PK_MPI).
class SubjectDistribution {
 public:
  virtual ~SubjectDistribution() = default;
  virtual int rank() const = 0;
  virtual int size() const = 0;
  /// Element-wise sum over the processes, in place; every process receives it.
  virtual void Sum(double* values, int count) const = 0;
  /// `text` as process `root` has it, on every process.
  virtual std::string Broadcast(const std::string& text, int root) const = 0;
};

/// "auto", "implicit" or "fd" (case-insensitive); throws pk::InputError otherwise.
PopulationGradient ParsePopulationGradient(const std::string& text);

/// The covariance step's matrix, as NONMEM's `$COVARIANCE MATRIX=`: with R = ∇²OFV and
/// S = Σ_i ∇OFV_i ∇OFV_iᵀ (OFV = −2 log L),
enum class CovarianceMatrix {
  kSandwich,  ///< R⁻¹SR⁻¹, NONMEM's default (robust to a misspecified residual error)
  kR,         ///< 2R⁻¹ (MATRIX=R): the inverse Hessian of −log L
  kS,         ///< 4S⁻¹ (MATRIX=S): the inverse cross-product of the subjects' scores; needs more
              ///< subjects than estimated parameters
};
const char* ToString(CovarianceMatrix m);
/// "sandwich R⁻¹SR⁻¹ (NONMEM's default)", "2R⁻¹ (NONMEM's MATRIX=R)" or "4S⁻¹ (NONMEM's MATRIX=S)".
const char* Describe(CovarianceMatrix m);
/// "sandwich", "r" or "s" (case-insensitive); throws pk::InputError otherwise.
CovarianceMatrix ParseCovarianceMatrix(const std::string& text);

struct PopulationOptions {
  PopulationMethod method = PopulationMethod::kFocei;
  PopulationGradient gradient = PopulationGradient::kAuto;
  PopulationStructure structure;
  /// Outer objective evaluations, at most (a difference gradient's are not counted). 0: no
  /// estimation, the OFV, diagnostics and covariance step at the initial estimates (NONMEM's
  /// MAXEVAL=0), as when every parameter is fixed.
  int max_iterations = 1000;
  double function_tolerance = 1e-9;     ///< relative change of the OFV that ends the search
  double parameter_tolerance = 1e-7;    ///< relative change of the packed parameters that ends it
  int threads = 1;                      ///< subjects' inner problems in parallel
  /// Subjects split across processes (pk/mpi.h), each process using `threads`; null: all here.
  std::shared_ptr<const SubjectDistribution> distribution;
  /// ½∇²l from the predictions' second derivatives (Laplace's H at the mode; Newton's matrix on the
  /// ODE propagator); false: central differences of the exact ∇l, as NONMEM forms them (a check).
  bool exact_conditional_hessian = true;
  bool covariance = true;               ///< run the covariance step
  /// The tables after the fit: each subject's η̂ (under FO post hoc, FOCE's mode at the estimate)
  /// and OFV_i (PopulationSummary::subjects), its rows of PRED, IPRED, CWRES, … (rows) and the
  /// shrinkages. false: the estimates, the OFV and the covariance step only, as a bootstrap's
  /// replicates need (under FO the post hoc modes cost about a FOCE evaluation).
  bool tables = true;
  CovarianceMatrix covariance_matrix = CovarianceMatrix::kSandwich;
  /// Called after each outer evaluation that improves the OFV (for a progress line); may be empty.
  std::function<void(int evaluation, double ofv, double gradient_norm)> progress;

  bool IsValid(std::string* error) const;
};

/// One subject's conditional mode and its diagnostics.
struct PopulationSubject {
  double id = 0;
  /// Its position in the dataset's subjects (Dataset::subjects): an ID that comes back after
  /// another (1, 2, 1) is another subject with the same ID, as in NONMEM.
  int subject = -1;
  bool ok = true;
  std::string message;      ///< why the subject's mode could not be found, when !ok
  Eigen::VectorXd eta;      ///< η̂_i
  /// H_i⁻¹, H_i the method's approximation of ½∇²l_i at η̂_i, the one in OFV_i (Laplace's exact one,
  /// FOCE's and FOCEI's first-order H): η's conditional covariance, NONMEM's ETC in its .phi file
  /// (empty when !ok).
  Eigen::MatrixXd eta_covariance;
  double ofv = 0;           ///< OFV_i
  Eigen::VectorXd parameters;  ///< individual φ_i (theta_names order)
  /// A model file's $PK values (Model::declarations().pk_definitions order: CL_i, V_i, …) at the
  /// subject's first record, its covariates applied; empty for the catalogue.
  Eigen::VectorXd definitions;
};

/// One sample's predictions and residuals, as NONMEM's sdtab.
struct PopulationRow {
  double id = 0, time = 0, dv = 0;
  int subject = -1;  ///< the subject's position in the dataset (PopulationSubject::subject)
  int dvid = 1;
  double pred = 0;   ///< f(θ, η = 0)
  double ipred = 0;  ///< f(θ, η̂)
  double res = 0;    ///< DV − PRED, on the error model's scale (log DV − log PRED for the exponential)
  double wres = 0;   ///< FO weighted residual, C₀^(−½)(y − PRED), C₀ = G₀ΩG₀ᵀ + V₀ at η = 0
  double cwres = 0;  ///< conditional (Hooker 2007): C^(−½)(y − f(η̂) + Gη̂), C = GΩGᵀ + V (V at η̂; at η = 0 for FOCE)
  double iwres = 0;  ///< (y − IPRED)/√V at η̂
  /// CENS: 1 when the value lies below DV (BLQ), -1 above, 0 for a value. A censored row's
  /// RES, WRES, CWRES and IWRES are NaN: DV is a limit, not an observation.
  int censored = 0;
  /// A model file's $PK definitions (ModelDeclarations::pk_definitions: CL, V, …) at η̂ and this
  /// record's covariates, as NONMEM's $TABLE lists them per row; empty for a catalogue model.
  Eigen::VectorXd definitions;
};

/// The objective at fixed parameters, with every subject's mode.
struct PopulationEvaluation {
  bool ok = true;
  std::string message;
  double ofv = std::numeric_limits<double>::quiet_NaN();
  std::vector<PopulationSubject> subjects;
};

/// OFV at `parameters`, each subject's mode found from η = 0 (FO: at η = 0, no mode).
PopulationEvaluation EvaluatePopulation(const PopulationProblem& problem, const PopulationParameters& parameters,
                                        PopulationMethod method, int threads = 1);

/// An estimate with its standard error, as NONMEM's tables show it.
struct PopulationEstimate {
  std::string name;   ///< CL, OMEGA(CL), OMEGA(V,CL), SIGMA_PROP, ...
  double estimate = 0;
  double se = std::numeric_limits<double>::quiet_NaN();
  double rse_pct = std::numeric_limits<double>::quiet_NaN();
  bool fixed = false;
  /// An element of a SAME Ω block: its source block's value, not a parameter of its own (fixed is
  /// set too: it has no SE of its own).
  bool same = false;
  int source = -1;  ///< for a SAME element, the position of the estimate it repeats; else -1
  /// An estimated Ω variance below 1e-6, or a θ near a model file's bound (within 1e-3 of the
  /// bounds' width; with one bound, 1e-3 of the largest of |θ|, |bound| and |initial θ|).
  bool at_boundary = false;
  /// For Ω's variance of a log-normal parameter's η: the between-subject CV%, 100·√(exp(ω²) − 1).
  double cv_pct = std::numeric_limits<double>::quiet_NaN();
};

/// One line of the iteration history (NONMEM's .ext): the packed parameters' natural values.
struct PopulationIteration {
  int evaluation = 0;
  double ofv = 0;
  double gradient_norm = 0;
  Eigen::VectorXd values;  ///< in PopulationSummary::estimates order
};

struct PopulationSummary {
  PopulationMethod method = PopulationMethod::kFocei;
  bool converged = false;
  std::string message;
  double initial_ofv = std::numeric_limits<double>::quiet_NaN();
  double ofv = std::numeric_limits<double>::quiet_NaN();
  int evaluations = 0;
  double seconds = 0;
  std::string gradient;  ///< how the outer gradient was computed
  /// Laplace: how H_i (½∇²l at the modes) was formed at the estimate; empty for FOCE and FOCEI.
  std::string conditional_hessian;
  /// FO: where the subjects' η̂ (and IPRED, CWRES, shrinkage) come from, since its objective has
  /// none (post hoc modes); empty for the conditional methods, whose η̂ are their own.
  std::string eta_estimates;
  int processes = 1;     ///< processes the subjects were split across (PopulationOptions::distribution)

  PopulationParameters parameters;
  std::vector<PopulationEstimate> estimates;  ///< θ, then Ω's lower triangle by blocks, then σ
  /// Covariance of the estimated ones (natural scale): the sandwich R⁻¹SR⁻¹ (NONMEM's default),
  /// or 2R⁻¹ or 4S⁻¹ (PopulationOptions::covariance_matrix).
  Eigen::MatrixXd covariance;
  CovarianceMatrix covariance_matrix = CovarianceMatrix::kSandwich;
  Eigen::MatrixXd correlation;
  /// Of the estimates' correlation matrix, largest over smallest eigenvalue (as NONMEM prints it).
  double condition_number = std::numeric_limits<double>::quiet_NaN();
  std::string covariance_message;  ///< why there are no SEs, when there are none
  /// How R and S were formed: from the exact gradient (FOCE, FOCEI) or differences of the OFV.
  std::string covariance_derivatives;

  std::vector<PopulationSubject> subjects;
  std::vector<PopulationRow> rows;
  std::vector<std::string> eta_names;      ///< the parameters with an η, in Ω's order
  Eigen::VectorXd eta_shrinkage_sd;        ///< 1 − SD(η̂)/ω per η
  Eigen::VectorXd eta_shrinkage_variance;  ///< 1 − Var(η̂)/ω²
  double epsilon_shrinkage_sd = std::numeric_limits<double>::quiet_NaN();  ///< 1 − SD(IWRES)
  double epsilon_shrinkage_variance = std::numeric_limits<double>::quiet_NaN();
  /// With an error model per output (pk::MakePerOutputError): the ε-shrinkage of each output's
  /// IWRES, DVID 1, 2, … (NONMEM's EPSSHRINK per EPS); empty with one error model.
  std::vector<double> epsilon_shrinkage_sd_by_output, epsilon_shrinkage_variance_by_output;
  std::vector<PopulationIteration> history;
  int failed_subjects = 0;

  /// What the covariance step flags, one sentence each: every pair of estimates whose correlation
  /// exceeds 0.95 in absolute value (the data hardly separate them), and a condition number above
  /// 1000 (the rule of thumb NONMEM users apply to the eigenvalue ratio). Empty without SEs.
  std::vector<std::string> CovarianceWarnings() const;

  std::string BriefReport() const;
  std::string FullReport() const;
};

/// Estimates θ, Ω and σ from `initial`. Throws pk::InputError for invalid options or initial
/// values (a non-positive θ or σ, an Ω that is not positive definite, sizes that do not match).
PopulationSummary FitPopulation(const PopulationProblem& problem, const PopulationParameters& initial,
                                const PopulationOptions& options);

}  // namespace pk

#endif  // PK_POPULATION_H_
