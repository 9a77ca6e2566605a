// libpk: visual predictive checks (VPC), as PsN's vpc and the R packages vpc and xpose draw them.
//
// The observations are put in bins of time, one set of bins per output (DVID). In each bin the
// percentiles P (5, 50, 95 by default) of the observations are compared with the same percentiles
// of each of R replicates simulated from the model on the data's design (pk/population_simulation.h):
// their interval (90% by default: the 5th and 95th percentiles of the R simulated values) and median.
// A model that describes the data keeps each observed percentile inside its interval in most bins.
//
// Percentiles are R's quantile(type = 7): of n sorted values x₁…x_n, P% is x_k + (h − k + 1)(x_{k+1} −
// x_k) with h = 1 + (n − 1)P/100 and k = ⌊h⌋.
//
// Prediction correction (pcVPC; Bergstrand et al., AAPS J 2011;13:143-151): each observed and
// simulated value y of a sample with population prediction PRED (f(θ, η = 0)) in bin b becomes
//
//   pcY = lb + (y − lb)·(PRED_b − lb)/(PRED − lb),   PRED_b the median PRED of the bin's samples,
//
// with lb the lower bound of the data (0 by default), which removes the spread that the design
// (doses, times, covariates) puts into a bin. Censored samples (CENS ≠ 0) are left out of both
// sides; a subject of a replicate that could not be simulated is left out of that replicate.
//
// Bins: given edges (a sample at an edge belongs to the bin above it; the last edge closes the last
// bin), or automatic: each distinct time its own bin when a DVID has at most max_bins of them,
// else max_bins bins of the times that minimise the sum of squared deviations from each bin's
// mean time (Jenks' natural breaks, the binning of the vpc package's default and close to PsN's
// auto_bin), never splitting samples at one time.
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
  bool prediction_corrected = false;              ///< pcVPC
  double lower_bound = 0;                         ///< pcVPC's lb, below every value and PRED
  int threads = 1;

  bool IsValid(std::string* error) const;
};

/// One observation as a VPC shows it.
struct VpcObservation {
  double id = 0;
  double time = 0;
  int dvid = 1;
  double value = 0;  ///< DV, or its prediction-corrected value
  int bin = -1;      ///< index into VpcSummary::bins
};

struct VpcBin {
  int dvid = 1;
  double lower = 0, upper = 0;  ///< the bin's time range [lower, upper), the last of a DVID [lower, upper]
  double time = 0;              ///< the median time of its observations (where the plot puts it)
  int observations = 0;
  double pred_median = std::numeric_limits<double>::quiet_NaN();  ///< PRED_b (pcVPC)
  /// Per percentile (VpcOptions::percentiles order): the data's, and the simulated one's interval
  /// and median over the replicates (NaN where the bin holds no value).
  std::vector<double> observed, simulated_lower, simulated_median, simulated_upper;
};

struct VpcSummary {
  std::vector<double> percentiles;
  double interval = 90;
  bool prediction_corrected = false;
  int replicates = 0;
  std::uint64_t seed = 0;
  std::string binning;  ///< how the bins were chosen
  std::vector<VpcBin> bins;  ///< by DVID, then time
  std::vector<VpcObservation> observations;
  int censored = 0;           ///< samples left out (CENS ≠ 0)
  int failed_simulations = 0; ///< subject-replicates that could not be simulated
  /// Observed percentiles outside their simulated interval, of those with a value.
  int outside = 0, compared = 0;

  std::string BriefReport() const;
};

/// Gathers a VPC: the observed side at construction, then replicates one at a time, each a
/// simulated value per observation (memory: the bins × percentiles × replicates statistics, not
/// the simulated values). Throws pk::InputError for invalid options or a design without values.
class VpcAccumulator {
 public:
  VpcAccumulator(const SimulationDesign& design, const VpcOptions& options);
  /// A replicate's simulated values, per subject and sample as in the design; subjects with
  /// ok = false are left out.
  void Add(const SimulatedReplicate& replicate);
  /// The same from plain values: values[i] are subject i's simulated samples (empty: left out).
  void Add(const std::vector<std::vector<double>>& values);
  VpcSummary Finish() const;

 private:
  struct Sample {
    int subject, index, bin;
    double pc_scale;  // (PRED_b − lb)/(PRED − lb), 1 without prediction correction
  };
  void AddValue(const Sample& s, double y, std::vector<std::vector<double>>* by_bin) const;
  VpcOptions options_;
  VpcSummary summary_;
  std::vector<Sample> samples_;
  /// [bin][percentile] → the replicates' simulated percentile
  std::vector<std::vector<std::vector<double>>> simulated_;
  std::vector<std::vector<double>> scratch_;
};

/// A VPC of `problem` at `parameters`: options.replicates simulations of its design
/// (PopulationSimulationOptions from options.seed and options.threads).
VpcSummary ComputeVpc(const PopulationProblem& problem, const PopulationParameters& parameters,
                      const VpcOptions& options);

/// R's quantile(x, p/100, type = 7) of unsorted values; NaN for none. Reorders `values`.
double Percentile(std::vector<double>* values, double p);

/// The VPC as a table, one row per bin and percentile:
/// DVID,BIN,TIME,TIME_LOWER,TIME_UPPER,N,PERCENTILE,OBSERVED,SIM_LOWER,SIM_MEDIAN,SIM_UPPER.
std::string VpcCsv(const VpcSummary& vpc);

}  // namespace pk

#endif  // PK_VPC_H_
