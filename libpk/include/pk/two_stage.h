// libpk: population estimates from individual fits, in two stages.
//
// Stage one fits every subject on its own (pk/fit_subjects.h). Stage two
// combines the individual estimates θ̂_i of the structural parameters (the
// residual-error σs are left out) in two ways:
//
//  - The standard two-stage (STS) statistics: mean, SD, CV%, geometric mean
//    and geometric CV%, median and range over the subjects whose fit converged.
//    Their spread is the spread of the estimates: true between-subject
//    variability plus each fit's estimation error, so STS overstates it,
//    the more the sparser the data.
//
//  - The global two-stage (GTS) estimates (Steimer et al., Drug Metab Rev 1984):
//    the maximum-likelihood μ and Ω of
//
//        φ̂_i = φ_i + e_i,   φ_i ~ N(μ, Ω),   e_i ~ N(0, C_i),
//
//    where φ = log θ (log-normal between-subject variability, the default) or
//    θ, and C_i is fit i's covariance of φ̂_i (its inverse information). The
//    marginal likelihood of φ̂_i is N(μ, Ω + C_i):
//
//        ℓ(μ, Ω) = −½ Σ_i [ log det(Ω + C_i) + (φ̂_i − μ)ᵀ(Ω + C_i)⁻¹(φ̂_i − μ) + p log 2π ].
//
//    It is maximised first by the EM iteration (φ_i as the missing data)
//
//        E: K_i = Ω(Ω + C_i)⁻¹,  φ*_i = μ + K_i(φ̂_i − μ),  P_i = (I − K_i)Ω
//        M: μ = mean φ*_i,       Ω = mean [P_i + (φ*_i − μ)(φ*_i − μ)ᵀ]
//
//    which never decreases ℓ and keeps Ω positive definite, and then by
//    L-BFGS over μ and the Cholesky factor L of Ω = LLᵀ, in which an Ω at the
//    boundary (a variance of 0, a correlation of ±1), where EM creeps, is an
//    ordinary point. φ*_i are the subjects' shrunken (empirical Bayes) estimates. Standard errors come from
//    the expected information: Cov(μ̂) = [Σ_i (Ω + C_i)⁻¹]⁻¹, and for the
//    entries ω_a of Ω, I_ab = ½ Σ_i tr(Σ_i⁻¹ E_a Σ_i⁻¹ E_b), Σ_i = Ω + C_i,
//    E_a = ∂Σ_i/∂ω_a. The model is linearised: it takes each φ̂_i as normal
//    about φ_i with covariance C_i, which holds for well-determined fits.
//    A subject without a covariance (a singular information matrix) is left
//    out of GTS.
//
//   std::vector<pk::SubjectFit> fits = pk::FitSubjects(request);
//   pk::TwoStageSummary population = pk::EstimateTwoStage(fits, pk::TwoStageOptions());
//   std::cout << population.FullReport();
//
// Runtime outcomes (too few subjects, non-positive estimates under the
// log-normal model, an EM that does not converge) are reported in the summary,
// never thrown. Invalid options throw pk::InputError.
#ifndef PK_TWO_STAGE_H_
#define PK_TWO_STAGE_H_

#include <limits>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "pk/error.h"
#include "pk/fit_subjects.h"

namespace pk {

/// How the parameters vary between subjects.
enum class BetweenSubjectModel {
  kLogNormal,  ///< log θ is normal: Ω is on the log scale, the typical value is exp(μ)
  kNormal,     ///< θ is normal
};

const char* ToString(BetweenSubjectModel m);
/// "lognormal" (or "log-normal") or "normal"; throws pk::InputError otherwise.
BetweenSubjectModel ParseBetweenSubjectModel(const std::string& text);

struct TwoStageOptions {
  BetweenSubjectModel distribution = BetweenSubjectModel::kLogNormal;
  /// Estimate only the variances of Ω (NONMEM's default diagonal $OMEGA)
  /// instead of the full matrix.
  bool diagonal_omega = false;
  /// EM iterations plus L-BFGS evaluations, at most.
  int max_iterations = 10000;
  /// The maximisation stops when no parameter (μ and the Cholesky factor of Ω)
  /// moves by more than this relative amount (NLopt's xtol_rel).
  double tolerance = 1e-10;

  bool IsValid(std::string* error) const;
};

/// Standard two-stage statistics of one parameter over the subjects.
struct DescriptiveStatistics {
  std::string name;
  int n = 0;
  double mean = std::numeric_limits<double>::quiet_NaN();
  double sd = std::numeric_limits<double>::quiet_NaN();      ///< divisor n − 1
  double cv_pct = std::numeric_limits<double>::quiet_NaN();  ///< 100·SD/|mean|
  /// exp(mean of log θ) and 100·√(exp(s²) − 1), s the SD of log θ; NaN unless every θ > 0.
  double geometric_mean = std::numeric_limits<double>::quiet_NaN();
  double geometric_cv_pct = std::numeric_limits<double>::quiet_NaN();
  double median = std::numeric_limits<double>::quiet_NaN();
  double min = std::numeric_limits<double>::quiet_NaN();
  double max = std::numeric_limits<double>::quiet_NaN();
};

/// GTS estimates of one parameter.
struct PopulationParameter {
  std::string name;
  double typical = std::numeric_limits<double>::quiet_NaN();  ///< exp(μ) (log-normal) or μ
  double typical_se = std::numeric_limits<double>::quiet_NaN();  ///< by the delta method for exp(μ)
  double typical_rse_pct = std::numeric_limits<double>::quiet_NaN();
  double omega2 = std::numeric_limits<double>::quiet_NaN();  ///< Ω_jj (of log θ when log-normal)
  double omega2_se = std::numeric_limits<double>::quiet_NaN();
  double omega2_rse_pct = std::numeric_limits<double>::quiet_NaN();
  /// Between-subject CV%: 100·√(exp(Ω_jj) − 1) (log-normal) or 100·√Ω_jj/|μ|.
  double bsv_cv_pct = std::numeric_limits<double>::quiet_NaN();
  /// Ω_jj went to its bound of 0 (the estimates vary no more than their SEs explain): reports
  /// print it as "0 (bound)", with no SE and a BSV of 0.
  bool omega2_at_bound = false;
};

struct TwoStageSummary {
  BetweenSubjectModel distribution = BetweenSubjectModel::kLogNormal;
  bool diagonal_omega = false;
  std::vector<std::string> parameters;  ///< the structural parameters estimated in every included fit

  /// STS: the subjects whose fit converged, and the statistics per parameter.
  std::vector<double> sts_ids;
  std::vector<DescriptiveStatistics> descriptive;
  /// Subjects left out of STS or GTS, with the reason.
  std::vector<std::pair<double, std::string>> excluded;

  /// GTS. `gts_ok` when it ran (at least two subjects with covariances); then
  /// `gts_converged` tells whether EM met its tolerance, and `gts_message` says
  /// what else there is to know (an Ω variance at its bound of 0, say).
  bool gts_ok = false;
  bool gts_converged = false;
  std::string gts_message;
  int gts_iterations = 0;
  std::vector<double> gts_ids;
  Eigen::VectorXd mu;                 ///< population mean of φ
  Eigen::MatrixXd mu_covariance;      ///< [Σ_i (Ω + C_i)⁻¹]⁻¹
  Eigen::MatrixXd omega;              ///< between-subject covariance of φ
  /// Standard errors of Ω's entries (symmetric; NaN off the diagonal when
  /// diagonal_omega, and everywhere when the information about Ω is singular).
  Eigen::MatrixXd omega_se;
  Eigen::MatrixXd omega_correlation;
  std::vector<PopulationParameter> population;
  /// Per GTS subject (rows in gts_ids order): the shrunken estimates φ*_i, on the
  /// natural scale (exp φ*_i when log-normal).
  Eigen::MatrixXd shrunken;
  double minus2ll = std::numeric_limits<double>::quiet_NaN();  ///< −2ℓ at (μ̂, Ω̂)

  std::string BriefReport() const;
  std::string FullReport() const;
};

/// Stage two from the fits of pk::FitSubjects (those that ran and converged).
TwoStageSummary EstimateTwoStage(const std::vector<SubjectFit>& fits, const TwoStageOptions& options);

/// Stage two from estimates given directly: per subject an ID, the estimates
/// θ̂_i (natural scale, one per name) and their covariance (natural scale; an
/// empty matrix leaves the subject out of GTS). Under the log-normal model
/// C_i = D⁻¹ Cov(θ̂_i) D⁻¹ with D = diag(θ̂_i), which is exact when the fit
/// estimated log θ (FitOptions::log_scale) and a delta-method step otherwise.
TwoStageSummary EstimateTwoStage(const std::vector<std::string>& names, const std::vector<double>& ids,
                                 const std::vector<Eigen::VectorXd>& estimates,
                                 const std::vector<Eigen::MatrixXd>& covariances, const TwoStageOptions& options);

}  // namespace pk

#endif  // PK_TWO_STAGE_H_
