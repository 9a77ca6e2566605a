// libpk: visual predictive checks (VPC), as PsN's vpc and the R packages vpc and xpose draw them.
//
// The observations are put in bins of time, one set of bins per output (DVID). In each bin the
// percentiles P (5, 50, 95 by default) of the observations are compared with the same percentiles
// of each of R replicates simulated from the model on the data's design (pk/population_simulation.h):
// their interval (90% by default: the 5th and 95th percentiles of the R simulated values) and median.
// A model that describes the data keeps each observed percentile inside its interval in most bins.
//
// Percentiles are R's quantile(type = 7): of n sorted values x₁…x_n, P% is x_k + (h − k)(x_{k+1} − x_k)
// with h = 1 + (n − 1)P/100 and k = ⌊h⌋.
//
// Prediction correction (pcVPC; Bergstrand et al., AAPS J 2011;13:143-151): each observed and
// simulated value y of a sample with population prediction PRED (f(θ, η = 0)) in bin b becomes
//
//   pcY = lb + (y − lb)·(PRED_b − lb)/(PRED − lb),   PRED_b the median PRED of the bin's samples,
//
// with lb the lower bound of the data (0 by default), which removes the spread that the design
// (doses, times, covariates) puts into a bin. A sample whose PRED is not above lb (a pre-dose
// sample, PRED 0) or cannot be evaluated is left out of a pcVPC, and counted.
//
// Censored data (CENS = 1: below the limit DV, NONMEM's M3 rows) stay in: such an observation,
// and any simulated value below its sample's limit, counts as −∞ (above an upper limit, CENS = −1,
// as +∞), so the observed and simulated percentiles see the same censoring. A percentile that falls
// among the censored values is "below the limit" (−∞: no number in the table, nothing drawn). A
// sample's lower limit is its own DV when it is censored, else the smallest limit of its DVID's
// censored samples, or VpcOptions::lloq when given. Each bin also gets the fraction of its values
// below the limit, observed against the simulated interval (PsN's BLQ panel). A subject of a
// replicate that could not be simulated is left out of that replicate.
//
// Bins: given edges (a sample at an edge belongs to the bin above it; the last edge closes the last
// bin), or automatic: each distinct time its own bin when a DVID has at most max_bins of them,
// else max_bins bins of the times that minimise the sum of squared deviations from each bin's
// mean time (Jenks' natural breaks, the binning of the vpc package's default and close to PsN's
// auto_bin), never splitting samples at one time; then a bin of fewer than min_bin_count values
// is merged into its neighbour across the smaller gap in time.
#ifndef PK_VPC_H_
#define PK_VPC_H_

#include <cstdint>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "pk/population.h"
#include "pk/population_simulation.h"

namespace pk {

struct VpcOptions {
  int replicates = 200;
  std::uint64_t seed = 1;
  std::vector<double> percentiles = {5, 50, 95};  ///< of the data in a bin, in (0, 100), increasing
  double interval = 90;                           ///< of each simulated percentile, % in (0, 100)
  std::vector<double> bin_edges;                  ///< increasing; empty: automatic
  int max_bins = 10;                              ///< automatic binning, per DVID
  /// Automatic binning: a bin of fewer values is merged into its neighbour across the smaller gap
  /// in time (1: none merged).
  int min_bin_count = 5;
  bool prediction_corrected = false;              ///< pcVPC
  /// pvcVPC (Bergstrand et al. 2011; PsN's -varcorr): each prediction-corrected value's deviation
  /// from PRED_b is also scaled by the bin's median spread over that sample's own (the standard
  /// deviations of its prediction-corrected values over the replicates), so that samples of unequal
  /// variability (a proportional error at unequal predictions, say) can share a bin. Needs
  /// prediction_corrected and at least 2 replicates; the replicates are simulated twice.
  bool variability_corrected = false;
  double lower_bound = 0;                         ///< pcVPC's lb
  /// A lower limit of quantification for every DVID (PsN's -lloq): values below it count as
  /// censored. NaN: the data's CENS = 1 rows give the limits.
  double lloq = std::numeric_limits<double>::quiet_NaN();
  /// A data column to stratify by (PsN's -stratify_on): bins and percentiles apart for each of its
  /// values (at most 20), as for each DVID. Empty: none. (ComputeVpc; the accumulator takes the
  /// design's strata.)
  std::string stratify;
  int threads = 1;

  bool IsValid(std::string* error) const;
};

/// One observation as a VPC shows it.
struct VpcObservation {
  double id = 0;
  double time = 0;
  int dvid = 1;
  double value = 0;  ///< DV, or its prediction- (and variability-) corrected value
  int bin = -1;      ///< index into VpcSummary::bins
};

struct VpcBin {
  int dvid = 1;
  double stratum = 0;  ///< the stratification column's value (0 when not stratified)
  double lower = 0, upper = 0;  ///< the bin's time range [lower, upper), the last of a DVID [lower, upper]
  double time = 0;              ///< the median time of its observations (where the plot puts it)
  int observations = 0;
  double pred_median = std::numeric_limits<double>::quiet_NaN();  ///< PRED_b (pcVPC)
  /// Per percentile (VpcOptions::percentiles order): the data's, and the simulated one's interval
  /// and median over the replicates (NaN where the bin holds no value; −∞ below the limit).
  std::vector<double> observed, simulated_lower, simulated_median, simulated_upper;
  /// The fraction of the bin's values below the limit: observed, and the simulated interval and
  /// median (0 without censoring).
  double censored_observed = 0, censored_lower = 0, censored_median = 0, censored_upper = 0;
};

struct VpcSummary {
  std::vector<double> percentiles;
  double interval = 90;
  bool prediction_corrected = false;
  bool variability_corrected = false;
  int replicates = 0;
  std::uint64_t seed = 0;
  std::string binning;  ///< how the bins were chosen
  std::string stratify;  ///< the column stratified by, or empty
  std::vector<VpcBin> bins;  ///< by stratum, then DVID, then time
  std::vector<VpcObservation> observations;
  int censored = 0;           ///< observations below or above a limit (CENS ≠ 0, or below VpcOptions::lloq)
  bool limits = false;        ///< some DVID has a limit: the bins' censored fractions mean something
  int outside_edges = 0;      ///< observations outside the given bin edges, left out
  int uncorrectable = 0;      ///< pcVPC: observations whose PRED is not above lb or not finite, left out
  /// pvcVPC: observations whose spread cannot be estimated (simulated in fewer than half the
  /// replicates, or without spread), shown prediction-corrected only (scale 1)
  int unscaled = 0;
  int failed_simulations = 0; ///< subject-replicates that could not be simulated
  /// Observed percentiles outside their simulated interval, of those with a value.
  int outside = 0, compared = 0;

  std::string BriefReport() const;
  /// "VPC", "Prediction-corrected VPC" or "Prediction- and variability-corrected VPC".
  std::string Kind() const;
};

/// Gathers a VPC: the observed side at construction, then replicates one at a time, each a
/// simulated value per observation (memory: the bins × percentiles × replicates statistics, not
/// the simulated values). Throws pk::InputError for invalid options or a design without values.
///
/// A pvcVPC (VpcOptions::variability_corrected) needs each sample's spread before any value can be
/// corrected: every replicate goes first to AddVariability, then EndVariability, then the same
/// replicates to Add (or Summarise and Append). The observed side is formed by EndVariability.
class VpcAccumulator {
 public:
  VpcAccumulator(const SimulationDesign& design, const VpcOptions& options);
  /// pvcVPC's first pass: a replicate's values (as Add takes them) join each sample's mean and
  /// variance of its prediction-corrected values (Welford's update; limits do not apply here).
  void AddVariability(const SimulatedReplicate& replicate);
  void AddVariability(const std::vector<std::vector<double>>& values);
  /// AddVariability in two steps, as Summarise and Append: a replicate's prediction-corrected value
  /// of each sample (NaN where it has none), which threads may form, then their addition in order.
  std::vector<double> VariabilityValues(const SimulatedReplicate& replicate) const;
  std::vector<double> VariabilityValues(const std::vector<std::vector<double>>& values) const;
  void AppendVariability(const std::vector<double>& values);
  /// Ends the first pass: the samples' scales sd_b/sd_ij (sd_b the median over the bin) and the
  /// observed side. A sample simulated in fewer than half the replicates (at least 2), or without
  /// spread, keeps scale 1 and is counted (VpcSummary::unscaled): a standard deviation from a few
  /// values would rescale it by noise. Throws std::logic_error without pvcVPC.
  void EndVariability();
  /// A replicate's simulated values, per subject and sample as in the design; subjects with
  /// ok = false are left out.
  void Add(const SimulatedReplicate& replicate);
  /// The same from plain values: values[i] are subject i's simulated samples (empty: left out).
  void Add(const std::vector<std::vector<double>>& values);
  VpcSummary Finish() const;

  /// Add in two steps, so that replicates can be summarised on several threads and appended in
  /// order: a replicate's statistics (per bin, its fraction below the limit, NaN for a bin that got
  /// no value, and its percentiles), then their addition.
  struct ReplicateStatistics {
    std::vector<double> censored;
    std::vector<std::vector<double>> percentiles;  ///< [bin][percentile]
    int failed = 0;                                 ///< subjects left out
  };
  ReplicateStatistics Summarise(const SimulatedReplicate& replicate) const;
  ReplicateStatistics Summarise(const std::vector<std::vector<double>>& values) const;
  void Append(const ReplicateStatistics& statistics);

 private:
  struct Sample {
    int subject, index, bin;
    double pc_scale;      // (PRED_b − lb)/(PRED − lb), 1 without prediction correction
    double lower, upper;  // the sample's limits (−∞, +∞ without)
    double observed;      // DV, ∓∞ when censored below (above) its limit
    double vc_scale;      // pvcVPC: sd_b/sd_ij, 1 without
    // pvcVPC's first pass: the count, mean and sum of squared deviations of its pc values.
    double n, mean, m2;
  };
  void Bin(const SimulationDesign& design);
  void Observe();  // the observed side, from the samples' `observed`
  void AddValue(const Sample& s, double y, std::vector<std::vector<double>>* by_bin) const;
  VpcOptions options_;
  VpcSummary summary_;
  std::vector<Sample> samples_;
  /// [bin][percentile] → the replicates' simulated percentile; [bin] → their censored fractions
  std::vector<std::vector<std::vector<double>>> simulated_;
  std::vector<std::vector<double>> simulated_censored_;
  bool corrections_ready_ = true;  // false until EndVariability, for a pvcVPC
  int variability_replicates_ = 0;  // replicates of pvcVPC's first pass
};

/// Throws pk::InputError unless `options` are valid for `problem`: IsValid, and a stratification
/// column that the data have, with at most 20 values at the samples. (What ComputeVpc checks first,
/// for a caller that would rather know before a fit.)
void CheckVpcOptions(const PopulationProblem& problem, const VpcOptions& options);

/// A VPC of `problem` at `parameters`: options.replicates simulations of its design
/// (PopulationSimulationOptions from options.seed and options.threads).
VpcSummary ComputeVpc(const PopulationProblem& problem, const PopulationParameters& parameters,
                      const VpcOptions& options);

/// R's quantile(x, p/100, type = 7) of unsorted values; NaN for none. Reorders `values`. Infinite
/// values (censored ones) sort to their ends, and a percentile that interpolates towards one is it.
double Percentile(std::vector<double>* values, double p);

/// The VPC as a table, one row per bin and percentile:
/// DVID,BIN,TIME,TIME_LOWER,TIME_UPPER,N,PERCENTILE,OBSERVED,SIM_LOWER,SIM_MEDIAN,SIM_UPPER, with the
/// stratification column first when stratified, the censored fractions (BLQ_OBSERVED, …) when the
/// data have limits, and last CORRECTION (none, pc or pvc).
std::string VpcCsv(const VpcSummary& vpc);

}  // namespace pk

#endif  // PK_VPC_H_
