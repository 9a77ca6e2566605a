// One subject's conditional problem in a population model (not installed): the individual
// objective l_i(η), its conditional mode η̂_i, and OFV_i for FOCE, FOCEI and Laplace (and FO's at η = 0)
// (pk/population.h has the formulas; docs/population.md derives them).
#ifndef PK_SRC_POPULATION_CONDITIONAL_H_
#define PK_SRC_POPULATION_CONDITIONAL_H_

#include <memory>
#include <string>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Core>

#include "pk/objective.h"
#include "pk/population.h"

namespace pk {
namespace internal {

/// A subject bound to the model: its least-squares objective, which gives the predictions ŷ and
/// their exact sensitivities ∂ŷ/∂φ (forward route), and where θ and the η'd parameters sit in it.
struct SubjectModel {
  std::unique_ptr<Objective> objective;
  Eigen::VectorXd base;          ///< the objective's full value vector (modifiers at their defaults)
  Eigen::VectorXd y;             ///< observations on the error model's scale (y or log y)
  std::vector<int> theta_index;  ///< objective position of each θ
  /// The individual parameters φ the predictions are differentiated in: the θ positions, then
  /// the positions of a model file's η parameters (pk::RandomEffects::kParameters).
  std::vector<int> phi_index;
  std::vector<int> eta_phi;   ///< per η: the φ it acts on (index into phi_index)
  /// Per η: φ = θ·exp(η), a log-normal η on a θ (the catalogue's CL_i = CL·exp(η_CL)); else
  /// φ = η, a model file's η parameter, which the file's own expressions transform.
  std::vector<bool> eta_log;
  std::vector<int> eta_free;  ///< objective position of each η's φ (the free list)
  /// Per sample: CENS (0 a value; 1 below DV, the limit; -1 above). A censored sample adds
  /// −2 log Φ(CENS·(y − f)/√V) to l(η) (Beal's M3).
  Eigen::VectorXi censoring;
  /// Per sample: the output it measures (its error model: pk::ResidualErrorModel::ForOutput), and
  /// whether that model compares log y (then y holds log DV).
  Eigen::VectorXi outputs;
  Eigen::Array<bool, Eigen::Dynamic, 1> logs;
  bool any_logs = false;
  /// ‖Δη‖∞ at which the mode counts as found: 1e-10 where the predictions are exact to rounding
  /// (Φ/Γ); on the ODE propagator l and ∇l carry the solver's error (about rtol relative), below
  /// which Newton's steps only wander, so 100·rtol there.
  double step_tolerance = 1e-10;
  /// l's error relative to its scale (number of samples + |l|): 1e-10 on Φ/Γ, whose predictions
  /// are accurate to about 1e-12 and enter l through 2r·δŷ/V; 10·rtol on the ODE propagator. A
  /// line search that cannot decrease l along a step whose predicted decrease is below it has
  /// found the mode to the accuracy the predictions allow.
  double relative_noise = 1e-10;
  /// Newton's ½∇²l in the mode search: exact (ExactConditionalHessian) on the ODE propagator, where
  /// differences of ∇l carry the solver's error over the step; on Φ/Γ one central difference, which
  /// costs 2q first-order passes against the second order's q(q+1)/2 pairs, and only sets the
  /// rate of convergence. Laplace's H at the mode is exact on both.
  bool newton_exact_hessian = false;
};

/// The population parameters as the conditional problems use them.
struct PopulationPoint {
  Eigen::VectorXd theta;
  Eigen::MatrixXd omega_inverse;
  double log_det_omega = 0;
  Eigen::VectorXd sigma;
  const ResidualErrorModel* error = nullptr;
  PopulationMethod method = PopulationMethod::kFocei;
  bool exact_hessian = true;  ///< PopulationOptions::exact_conditional_hessian

  /// Throws pk::InputError when Ω is not positive definite.
  static PopulationPoint Make(const PopulationParameters& p, const ResidualErrorModel& error, PopulationMethod m);
};

/// l(η) and what the approximations need at one η.
struct Conditional {
  Eigen::VectorXd yhat;      ///< ŷ
  Eigen::VectorXd f;         ///< T(ŷ): ŷ, or log ŷ for the exponential error
  Eigen::VectorXd variance;  ///< V_j
  Eigen::MatrixXd g;         ///< ∂f/∂η (n×q)
  Eigen::MatrixXd dv;        ///< ∂V/∂η (n×q); 0 without interaction
  double l = 0;              ///< l(η)
  Eigen::VectorXd gradient;  ///< ∇l (with derivatives)
  Eigen::MatrixXd h;         ///< Ω⁻¹ + Σ_j [g gᵀ/V + ½ v vᵀ/V²] (with derivatives)
};

/// The individual parameters φ at η.
Eigen::VectorXd IndividualValues(const SubjectModel& s, const PopulationPoint& p, const Eigen::VectorXd& eta);
/// The same into `out` (its storage reused).
void IndividualValues(const SubjectModel& s, const PopulationPoint& p, const Eigen::VectorXd& eta,
                      Eigen::VectorXd* out);

/// PopulationSubject::parameters and ::definitions at η.
void DescribeIndividual(const SubjectModel& s, const PopulationPoint& p, const Eigen::VectorXd& eta,
                        PopulationSubject* out);

/// Evaluates l at η, with ∇l and H when `derivatives`. `fixed_variance` (FOCE: V at η = 0) holds
/// the residual variances fixed when non-null. False with `why` when the model cannot be
/// evaluated there or a variance or prediction is not positive where it must be.
bool EvaluateConditional(const SubjectModel& s, const PopulationPoint& p, const Eigen::VectorXd& eta,
                         const Eigen::VectorXd* fixed_variance, bool derivatives, Conditional* out, std::string* why);

/// One subject's result at a population point.
struct SubjectMode {
  bool ok = false;
  std::string message;
  Eigen::VectorXd eta;
  double ofv = 0;
  Conditional at_mode;
  Eigen::VectorXd fixed_variance;  ///< FOCE and FO: V at η = 0 (empty otherwise)
  /// False where eta is not an estimate: FO's tables take FOCE's post hoc modes, and a subject whose
  /// mode cannot be found keeps η = 0 (PostHocDiagnostics); η-shrinkage leaves it out.
  bool eta_estimated = true;
  int iterations = 0;
  /// Laplace: why its H at the mode is differences of the exact ∇l (empty when it is exact).
  std::string hessian_differenced;
  Eigen::MatrixXd hessian;  ///< the H_i of OFV_i (the method's) at η̂

};

/// Finds η̂ from `start` (damped Fisher scoring, then Newton with the exact ½∇²l, or central
/// differences of the exact gradient where the route has no second derivatives, to
/// ‖step‖∞ < s.step_tolerance) and forms OFV_i for p.method.
SubjectMode SolveSubject(const SubjectModel& s, const PopulationPoint& p, const Eigen::VectorXd& start);

/// ½∇²l at η by central differences of the exact gradient: Richardson-extrapolated (error
/// O(h⁴); Laplace's H at the mode) when `extrapolate`, else one central difference (Newton's
/// iteration matrix, which sets only the rate of convergence).
bool ConditionalHessian(const SubjectModel& s, const PopulationPoint& p, const Eigen::VectorXd& eta,
                        const Eigen::VectorXd* fixed_variance, bool extrapolate, Eigen::MatrixXd* half_hessian,
                        std::string* why);

/// ½∇²l at η, exact given the predictions' second derivatives in the η'd parameters
/// (Objective::SecondDerivatives: Φ/Γ's block-triangular exponential, or the ODE propagator's
/// second-order sensitivities), `at` being EvaluateConditional's result at η with derivatives.
/// Censored samples (M3) enter with their full second derivatives. False, with `why`, where the
/// subject's route has no second derivatives (a hand-built model's computed dose modifier without
/// an evaluation on HyperDual3, a numerical failure): ConditionalHessian's differences then serve.
bool ExactConditionalHessian(const SubjectModel& s, const PopulationPoint& p, const Eigen::VectorXd& eta,
                             const Eigen::VectorXd* fixed_variance, const Conditional& at,
                             Eigen::MatrixXd* half_hessian, std::string* why);

/// H_i⁻¹ of a found mode (PopulationSubject::eta_covariance); empty when !mode.ok.
Eigen::MatrixXd EtaCovariance(const SubjectMode& mode);

/// Runs work(i) for i in [0, n) on `threads` threads (each takes every threads-th item, so the
/// assignment, and hence every result, does not depend on timing).
void ParallelFor(int n, int threads, const std::function<void(int)>& work);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_POPULATION_CONDITIONAL_H_
