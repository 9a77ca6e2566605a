// libpk: normalised prediction distribution errors (NPDE) and prediction discrepancies (PD), the
// simulation-based residuals of NONMEM's $TABLE NPDE and NPD and of the R package npde (Brendel et
// al., Pharm Res 2006;23:2036-2049; Comets, Brendel and Mentré, Comput Methods Programs Biomed
// 2008;90:154-166).
//
// Subject i's observations y_i (n_i values) are compared with K simulations y_i^(k) of its own
// design from the model at the estimates (η and ε drawn; pk/population_simulation.h). With the
// simulations' mean E_i (EPRED) and covariance V_i (divisor K − 1), and L_i the lower Cholesky
// factor of V_i (V_i = L_i L_iᵀ):
//
//   pd_ij  = #{k : y_ij^(k) < y_ij} / K                            (no decorrelation)
//   y*_i   = L_i⁻¹ (y_i − E_i),   y*_i^(k) = L_i⁻¹ (y_i^(k) − E_i)  (decorrelated, every k)
//   pde_ij = #{k : y*_ij^(k) < y*_ij} / K
//
// A value of 0 becomes 1/(2K) and one of 1 becomes 1 − 1/(2K) (the npde package's default, ties =
// TRUE), and NPD = Φ⁻¹(pd), NPDE = Φ⁻¹(pde). Under the model the NPDE are independent N(0, 1), within
// a subject too; the NPD are N(0, 1) but correlated within a subject. The npde package's summary
// statistics (mean, variance, skewness, kurtosis) and its tests (TestNpde) come with the NPDE.
//
// Simulation k of subject i draws from the streams of replicate k (0-based) of
// pk::SimulatePopulation with the same seed, so it is that replicate's subject i (the VPC's and
// pkpop --simulate's). Censored samples (CENS ≠ 0) are left out of a subject's vectors, observed
// and simulated alike (the npde package's cens.method = "omit"); they get no PD or NPDE. A subject
// any of whose simulations cannot be evaluated is left out and reported. A subject whose simulated
// covariance has no Cholesky factor (K ≤ n_i, or a degenerate design) keeps its PD and gets no NPDE,
// reported. (The npde package then gives no NPDE for any subject; libpk keeps the others', but the
// subjects it loses are those with the most samples, which biases the pooled tests: choose K well
// above the largest n_i.)
#ifndef PK_NPDE_H_
#define PK_NPDE_H_

#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pk/population.h"

namespace pk {

struct NpdeOptions {
  int simulations = 1000;  ///< K (NONMEM's ESAMPLE, the npde package's nrep)
  std::uint64_t seed = 1;
  int threads = 1;  ///< subjects on this many threads; no effect on the values

  bool IsValid(std::string* error) const;
};

/// One subject's NPDE and PD from its observations and simulations (the formulas above).
struct SubjectNpde {
  Eigen::VectorXd epred;  ///< E_i, per observation
  Eigen::VectorXd pd;     ///< after the 1/(2K) bounds
  Eigen::VectorXd pde;    ///< empty when V_i has no Cholesky factor
  std::string message;    ///< why pde is empty
};

/// `observed` (n) against `simulated` (n × K, a simulation per column, K ≥ 2). Throws
/// std::invalid_argument for other sizes or values that are not finite.
SubjectNpde ComputeSubjectNpde(const Eigen::VectorXd& observed, const Eigen::MatrixXd& simulated);

/// Φ⁻¹(p) for p in (0, 1); throws std::domain_error otherwise.
double NormalQuantile(double p);

/// The moments the npde package reports, of the finite values given.
/// NaN where undefined (no values; one value for all but the mean).
struct NpdeMoments {
  static constexpr double kNone = std::numeric_limits<double>::quiet_NaN();
  int count = 0;
  double mean = kNone, variance = kNone, skewness = kNone, kurtosis = kNone;  ///< kurtosis: excess (0 for a normal)
  double mean_se = kNone, variance_se = kNone;  ///< √(s²/n) and s²√(2/(n − 1))
};
NpdeMoments ComputeNpdeMoments(const std::vector<double>& values);

/// The npde package's tests that values are N(0, 1) (its gof.test), each p-value as R computes it:
/// the mean by Student's t-test (t.test; the package's default since version 2, parametric = TRUE)
/// and by Wilcoxon's signed-rank test (wilcox.test, its version 1 and parametric = FALSE: exact below
/// 50 values without ties or zeros, else the normal approximation with continuity and ties'
/// corrections), the variance by (n − 1)s² against χ²(n − 1) two-sided ("Fisher variance test"),
/// normality by Shapiro–Wilk (shapiro.test, Royston's AS R94; 3 to 5000 values), and the global test
/// min(1, 3 min p) over the t, variance and Shapiro–Wilk tests (Bonferroni). NaN where a test cannot
/// be made; the global test then counts the others. Values that are not finite are left out.
struct NpdeTests {
  static constexpr double kNone = std::numeric_limits<double>::quiet_NaN();
  double mean_p = kNone, mean_wilcoxon_p = kNone, variance_p = kNone, normality_w = kNone, normality_p = kNone,
         global_p = kNone;
};
NpdeTests TestNpde(const std::vector<double>& values);

struct NpdeRow {
  int subject = 0;  ///< position in the dataset
  double id = 0, time = 0;
  int dvid = 1;
  double dv = 0;
  bool censored = false;
  /// NaN where not computed (censored, a subject left out, or for NPDE a subject without V_i's factor).
  double epred = NpdeMoments::kNone, pd = NpdeMoments::kNone, npd = NpdeMoments::kNone, pde = NpdeMoments::kNone,
         npde = NpdeMoments::kNone;
};

struct NpdeSummary {
  int simulations = 0;
  std::uint64_t seed = 1;
  std::vector<NpdeRow> rows;  ///< every sample of every subject, in the data's order
  NpdeMoments npde, npd;
  NpdeTests npde_tests;
  int censored = 0;                  ///< samples left out for censoring
  std::vector<std::string> notes;    ///< subjects left out, or without NPDE, and why

  std::string BriefReport() const;
  std::string FullReport() const;
};

/// NPDE and PD of every sample of `problem` at `parameters`. Throws pk::InputError for invalid
/// options or parameters (as pk::SimulatePopulation).
NpdeSummary ComputeNpde(const PopulationProblem& problem, const PopulationParameters& parameters,
                        const NpdeOptions& options);

/// npde.csv: ID,TIME,DVID,DV,CENS,EPRED,PD,NPD,PDE,NPDE (empty fields where not computed).
std::string NpdeCsv(const NpdeSummary& npde);

}  // namespace pk

#endif  // PK_NPDE_H_
