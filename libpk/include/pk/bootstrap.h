// libpk: the nonparametric bootstrap of a population fit, as PsN's bootstrap: each replicate draws
// as many subjects as the data have, with replacement (Efron & Tibshirani 1993), renumbers them
// 1…N (a subject drawn twice is two subjects, as NONMEM would read it), and fits the model again
// from the original estimates with the original method and structure. Over the replicates whose fit
// converged (and, by default as PsN, with no estimate near a boundary), each parameter gets its
// median, mean and bias (mean − estimate), a percentile interval (R's quantile type 7; 2.5th and
// 97.5th by default) and the bootstrap SE (the replicates' SD, divisor R − 1), beside the original
// estimate.
//
// Stratified (PsN's -stratify_on), each subject position draws among the subjects of its own stratum,
// the value of a data column on the subject's first record, so every replicate keeps each stratum's
// size (a design of two studies, or of two dose groups, keeps its proportions).
//
// Replicate r draws its subjects from a stream of its own (seed, r), so the replicates depend on
// neither the threads nor how many follow; replicates' fits run on options.threads threads, each
// fit on one. A replicate whose fit fails or does not converge (or, by default, puts an estimate on
// a boundary) is counted and left out of the statistics; its estimates are still in
// BootstrapSummary::runs.
//
//   pk::BootstrapOptions options;
//   options.replicates = 200;
//   options.fit = fit_options;  // the original fit's method and structure
//   const pk::BootstrapSummary b = pk::BootstrapPopulation(problem, fit, options);
//   std::cout << b.FullReport();
#ifndef PK_BOOTSTRAP_H_
#define PK_BOOTSTRAP_H_

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pk/population.h"

namespace pk {

struct BootstrapOptions {
  int replicates = 200;  ///< PsN's -samples
  std::uint64_t seed = 1;
  int threads = 1;  ///< replicates fitted at once; no effect on the values
  double interval = 95;  ///< the percentile interval, % in (0, 100)
  /// Leave out replicates with an estimate near a boundary (PopulationEstimate::at_boundary: an Ω
  /// variance below 1e-6, a θ at a model file's bound), as PsN's skip_estimate_near_boundary.
  bool skip_boundary = true;
  /// A data column (a covariate column of the dataset) to stratify by, its value on each subject's
  /// first record; empty: no strata.
  std::string stratify;
  /// Each replicate's fit: the original's structure and tolerances (its method is the original
  /// fit's). Estimation must be on (max_iterations > 0). Its covariance step, threads, distribution
  /// and progress are not used (each replicate is fitted on one thread, without a covariance step).
  PopulationOptions fit;
  /// Called (from the fitting threads, one at a time) as each replicate is done, with the count done.
  std::function<void(int done)> progress;

  bool IsValid(std::string* error) const;
};

struct BootstrapReplicate {
  int replicate = 0;           ///< 0-based; its subjects are BootstrapSample(seed, replicate, N)
  bool converged = false;
  bool boundary = false;       ///< an estimate near a boundary
  bool used = false;           ///< in the statistics (converged, and not on a boundary when skip_boundary)
  std::string message;         ///< why not, when not
  double ofv = 0;
  Eigen::VectorXd estimates;   ///< natural values, in BootstrapSummary::names order (empty if the fit threw)
};

struct BootstrapParameter {
  std::string name;
  double estimate = 0;  ///< the original fit's
  double median = 0, lower = 0, upper = 0, se = 0;  ///< over the used replicates (NaN: none)
  double mean = 0;  ///< over the used replicates (NaN: none)
  /// mean − estimate, as PsN's bias: a bias large against the SE says the estimator is biased at
  /// this design (or that the estimate is poorly determined).
  double bias = 0;
  bool fixed = false;
};

struct BootstrapSummary {
  int replicates = 0, converged = 0, used = 0;
  bool original_converged = true;  ///< the bootstrapped fit's own
  std::uint64_t seed = 1;
  double interval = 95;
  std::string stratify;  ///< the column stratified by, or empty
  int strata = 1;        ///< its distinct values (1 without strata)
  int small_strata = 0;  ///< strata of fewer than 5 subjects (a warning: each resamples little or nothing)
  std::vector<std::string> names;  ///< the natural parameters (PopulationSummary::estimates' names)
  std::vector<BootstrapReplicate> runs;
  std::vector<BootstrapParameter> parameters;

  std::string BriefReport() const;
  std::string FullReport() const;  ///< with the table of intervals
};

/// The subjects replicate `replicate` draws from `subjects` (positions, with replacement).
std::vector<int> BootstrapSample(std::uint64_t seed, int replicate, int subjects);

/// The same within strata: position i draws among the subjects whose stratum equals strata[i]
/// (strata holds a value per subject, in subject order). With one stratum this is the sample above.
std::vector<int> BootstrapSample(std::uint64_t seed, int replicate, const std::vector<double>& strata);

/// Each subject's stratum for BootstrapOptions::stratify: the column's value on its first record.
/// Throws pk::InputError naming the dataset when it has no such column, or a value is missing.
std::vector<double> BootstrapStrata(const Dataset& data, const std::string& column);

/// Bootstraps `fit` of `problem`. Throws pk::InputError for invalid options (max_iterations 0
/// among them: every replicate would stay at the estimates).
BootstrapSummary BootstrapPopulation(const PopulationProblem& problem, const PopulationSummary& fit,
                                     const BootstrapOptions& options);

/// bootstrap.csv: REPLICATE,CONVERGED,BOUNDARY,USED,OFV and each natural parameter, a row per replicate.
std::string BootstrapCsv(const BootstrapSummary& summary);

}  // namespace pk

#endif  // PK_BOOTSTRAP_H_
