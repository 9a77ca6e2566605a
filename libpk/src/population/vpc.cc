// Visual predictive checks (pk/vpc.h): bins, percentiles of the data and of each simulated
// replicate, and the replicates' intervals.
#include "pk/vpc.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <functional>
#include <limits>
#include <map>
#include <set>
#include <sstream>
#include <stdexcept>

#include "internal_text.h"
#include "ordered_parallel.h"
#include "pk/error.h"
#include "pk/output.h"

namespace pk {
namespace {

using internal::kNaN;

// The distinct times of one DVID's values and how many values each has.
struct Times {
  std::vector<double> time;
  std::vector<int> count;
};

// Jenks' natural breaks over distinct times with multiplicities: the split into k consecutive
// groups that minimises Σ over groups of Σ count·(t − group mean)² (Fisher 1958), by dynamic
// programming over the groups. This cost satisfies the quadrangle inequality, so the best start of
// the last group does not decrease with the number of times it covers (Wang & Song, R Journal
// 2011, Ckmeans.1d.dp): each layer is filled by divide and conquer, O(k·u·log u) for u distinct
// times. Returns the index of each group's first time.
class NaturalBreaks {
 public:
  explicit NaturalBreaks(const Times& t) : u_(t.time.size()), w_(u_ + 1, 0), s_(u_ + 1, 0), ss_(u_ + 1, 0) {
    // Prefix sums of count, count·t and count·t² give any group's squared deviation at once.
    for (size_t i = 0; i < u_; ++i) {
      w_[i + 1] = w_[i] + t.count[i];
      s_[i + 1] = s_[i] + t.count[i] * t.time[i];
      ss_[i + 1] = ss_[i] + t.count[i] * t.time[i] * t.time[i];
    }
  }

  std::vector<size_t> Starts(size_t groups) {
    const double inf = std::numeric_limits<double>::infinity();
    // best[g][b]: the least cost of the first b times in g + 1 groups; from[g][b]: its last group's start.
    best_.assign(groups, std::vector<double>(u_ + 1, inf));
    from_.assign(groups, std::vector<size_t>(u_ + 1, 0));
    for (size_t b = 1; b <= u_; ++b) best_[0][b] = Cost(0, b);
    for (size_t g = 1; g < groups; ++g) Layer(g, g + 1, u_, g, u_ - 1);
    std::vector<size_t> starts(groups, 0);
    size_t b = u_;
    for (size_t g = groups; g-- > 1;) {
      starts[g] = from_[g][b];
      b = starts[g];
    }
    return starts;
  }

 private:
  double Cost(size_t a, size_t b) const {  // times [a, b)
    const double n = w_[b] - w_[a], m = s_[b] - s_[a];
    return std::max(0.0, ss_[b] - ss_[a] - m * m / n);
  }
  // best[g][b] for b in [lo, hi], whose last groups start in [a_lo, a_hi].
  void Layer(size_t g, size_t lo, size_t hi, size_t a_lo, size_t a_hi) {
    if (lo > hi) return;
    const size_t mid = lo + (hi - lo) / 2;
    size_t arg = a_lo;
    for (size_t a = a_lo; a <= std::min(a_hi, mid - 1); ++a) {
      const double c = best_[g - 1][a] + Cost(a, mid);
      if (c < best_[g][mid]) {
        best_[g][mid] = c;
        arg = a;
      }
    }
    from_[g][mid] = arg;
    if (mid > lo) Layer(g, lo, mid - 1, a_lo, arg);
    Layer(g, mid + 1, hi, arg, a_hi);
  }
  size_t u_;
  std::vector<double> w_, s_, ss_;
  std::vector<std::vector<double>> best_;
  std::vector<std::vector<size_t>> from_;
};

// Bin edges for one DVID's distinct times: given ones, or midpoints between the groups' times.
// Groups of distinct times (each by its first index) with fewer than `min_count` values merged, the
// smallest first, into the neighbour across the smaller gap in time, until every group has enough or
// one is left: a percentile of one or two values says little, and such a bin counts as much as any.
std::vector<size_t> MergeSmall(const Times& t, std::vector<size_t> starts, int min_count) {
  const auto end = [&](size_t g) { return g + 1 < starts.size() ? starts[g + 1] : t.time.size(); };
  for (;;) {
    size_t smallest = starts.size();
    int fewest = min_count;
    for (size_t g = 0; g < starts.size(); ++g) {
      int n = 0;
      for (size_t i = starts[g]; i < end(g); ++i) n += t.count[i];
      if (n < fewest) fewest = n, smallest = g;
    }
    if (smallest == starts.size() || starts.size() == 1) return starts;
    const size_t g = smallest;
    const double left = g > 0 ? t.time[starts[g]] - t.time[starts[g] - 1] : HUGE_VAL;
    const double right = g + 1 < starts.size() ? t.time[starts[g + 1]] - t.time[starts[g + 1] - 1] : HUGE_VAL;
    starts.erase(starts.begin() + static_cast<std::ptrdiff_t>(left <= right ? g : g + 1));
  }
}

std::vector<double> AutomaticEdges(const Times& t, int max_bins, int min_count) {
  const size_t u = t.time.size();
  std::vector<size_t> starts;
  if (u <= static_cast<size_t>(max_bins)) {
    for (size_t i = 0; i < u; ++i) starts.push_back(i);
  } else {
    starts = NaturalBreaks(t).Starts(static_cast<size_t>(max_bins));
  }
  starts = MergeSmall(t, starts, min_count);
  std::vector<double> edges{t.time.front()};
  for (size_t g = 1; g < starts.size(); ++g) edges.push_back(0.5 * (t.time[starts[g] - 1] + t.time[starts[g]]));
  edges.push_back(t.time.back());  // the last bin is closed: [lower, upper]
  return edges;
}

// The bin of time x among edges e (−1 outside [e₀, e_last]; the last edge closes the last bin).
int BinOf(const std::vector<double>& e, double x) {
  if (!(x >= e.front()) || x > e.back()) return -1;
  if (x == e.back()) return static_cast<int>(e.size()) - 2;
  return static_cast<int>(std::upper_bound(e.begin(), e.end(), x) - e.begin()) - 1;
}

double Median(std::vector<double> v) { return Percentile(&v, 50); }

}  // namespace

double Percentile(std::vector<double>* values, double p) {
  std::vector<double>& v = *values;
  if (v.empty()) return kNaN;
  const double h = (static_cast<double>(v.size()) - 1) * p / 100;
  const auto k = static_cast<size_t>(std::floor(h));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  const double low = v[k];
  if (k + 1 >= v.size()) return low;
  const double high = *std::min_element(v.begin() + static_cast<std::ptrdiff_t>(k) + 1, v.end());
  const double fraction = h - static_cast<double>(k);
  if (fraction == 0 || low == high) return low;
  if (std::isinf(low)) return low;    // towards censored values below: below the limit
  if (std::isinf(high)) return high;  // towards censored values above
  return low + fraction * (high - low);
}

bool VpcOptions::IsValid(std::string* error) const {
  const auto fail = [&](const std::string& why) {
    *error = why;
    return false;
  };
  if (replicates < 1) return fail("replicates must be at least 1, not " + std::to_string(replicates));
  if (percentiles.empty()) return fail("at least one percentile is needed");
  for (size_t k = 0; k < percentiles.size(); ++k) {
    if (!(percentiles[k] > 0 && percentiles[k] < 100)) return fail("percentile " + FormatNumber(percentiles[k]) + " is not in (0, 100)");
    if (k > 0 && !(percentiles[k] > percentiles[k - 1])) return fail("the percentiles must increase");
  }
  if (!(interval > 0 && interval < 100)) return fail("the interval " + FormatNumber(interval) + "% is not in (0, 100)");
  for (size_t k = 0; k < bin_edges.size(); ++k) {
    if (!std::isfinite(bin_edges[k])) return fail("bin edge " + FormatNumber(bin_edges[k]) + " is not finite");
    if (k > 0 && !(bin_edges[k] > bin_edges[k - 1])) return fail("the bin edges must increase");
  }
  if (bin_edges.size() == 1) return fail("one bin edge makes no bin: give at least two");
  if (max_bins < 1) return fail("max_bins must be at least 1, not " + std::to_string(max_bins));
  if (min_bin_count < 1) return fail("min_bin_count must be at least 1, not " + std::to_string(min_bin_count));
  if (!std::isfinite(lower_bound)) return fail("the lower bound must be finite");
  if (variability_corrected && !prediction_corrected) {
    return fail("the variability correction (pvcVPC) applies to prediction-corrected values: it needs the prediction correction");
  }
  if (variability_corrected && replicates < 2) return fail("the variability correction needs at least 2 replicates");
  if (std::isinf(lloq)) return fail("the LLOQ must be finite (or NaN: none)");
  if (threads < 1) return fail("threads must be at least 1, not " + std::to_string(threads));
  return true;
}

namespace {

constexpr size_t kMaxStrata = 20;

// Throws unless every per-sample vector of the design's subjects has one entry per sample, and the
// design has at most kMaxStrata strata.
void CheckDesign(const SimulationDesign& design) {
  std::set<double> strata;
  for (const SimulationDesign::Subject& s : design.subjects) {
    const size_t n = s.time.size();
    if (s.dvid.size() != n || s.censored.size() != n || static_cast<size_t>(s.dv.size()) != n ||
        static_cast<size_t>(s.pred.size()) != n || (!design.stratify.empty() && s.stratum.size() != n)) {
      throw InputError("VPC: subject " + FormatNumber(s.id) + " of the design has per-sample vectors of unequal sizes");
    }
    for (double v : s.stratum) {
      if (std::isnan(v)) throw InputError("VPC: " + design.stratify + " is missing at a sample of ID " + FormatNumber(s.id));
      strata.insert(v);
    }
  }
  if (strata.size() > kMaxStrata) {
    throw InputError("VPC: " + design.stratify + " has " + std::to_string(strata.size()) + " values; stratify by a "
                     "categorical column (at most " + std::to_string(kMaxStrata) + " values: group a continuous "
                     "covariate in a column of its own)");
  }
}

// A sample's panel: (stratum, DVID).
using Panel = std::pair<double, int>;

Panel PanelOf(const SimulationDesign& design, const SimulationDesign::Subject& s, size_t j) {
  return {design.stratify.empty() ? 0.0 : s.stratum[j], s.dvid[j]};
}

// Per DVID, the limits the data's censored samples give: the smallest lower, the largest upper.
struct Limits {
  double lower = -std::numeric_limits<double>::infinity(), upper = std::numeric_limits<double>::infinity();
};

std::map<int, Limits> DataLimits(const SimulationDesign& design, double lloq) {
  std::map<int, Limits> out;
  for (const SimulationDesign::Subject& s : design.subjects) {
    for (size_t j = 0; j < s.time.size(); ++j) {
      Limits& l = out[s.dvid[j]];
      const double dv = s.dv(static_cast<Eigen::Index>(j));
      if (s.censored[j] > 0) l.lower = std::isinf(l.lower) ? dv : std::min(l.lower, dv);
      if (s.censored[j] < 0) l.upper = std::isinf(l.upper) ? dv : std::max(l.upper, dv);
    }
  }
  if (!std::isnan(lloq)) {
    for (auto& entry : out) entry.second.lower = lloq;
  }
  return out;
}

}  // namespace

namespace {

// A replicate's simulated values as Add takes them: each subject's, empty for one that failed
// (counted in *failed when given).
std::vector<std::vector<double>> SimulatedValues(const SimulatedReplicate& replicate, int* failed = nullptr) {
  std::vector<std::vector<double>> values(replicate.subjects.size());
  for (size_t i = 0; i < replicate.subjects.size(); ++i) {
    const SimulatedSubject& s = replicate.subjects[i];
    if (s.ok) {
      values[i].assign(s.dv.data(), s.dv.data() + s.dv.size());
    } else if (failed) {
      ++*failed;
    }
  }
  return values;
}

}  // namespace

VpcAccumulator::VpcAccumulator(const SimulationDesign& design, const VpcOptions& options) : options_(options) {
  std::string why;
  if (!options.IsValid(&why)) throw InputError("VPC: " + why);
  CheckDesign(design);
  summary_.percentiles = options.percentiles;
  summary_.interval = options.interval;
  summary_.prediction_corrected = options.prediction_corrected;
  summary_.variability_corrected = options.variability_corrected;
  summary_.seed = options.seed;
  summary_.stratify = design.stratify;
  const std::map<int, Limits> limits = DataLimits(design, options.lloq);
  for (size_t i = 0; i < design.subjects.size(); ++i) {
    const SimulationDesign::Subject& s = design.subjects[i];
    for (size_t j = 0; j < s.time.size(); ++j) {
      Limits l = limits.at(s.dvid[j]);
      const double dv = s.dv(static_cast<Eigen::Index>(j));
      if (s.censored[j] > 0) l.lower = dv;  // its own limit
      if (s.censored[j] < 0) l.upper = dv;
      summary_.limits = summary_.limits || std::isfinite(l.lower);
      const double inf = std::numeric_limits<double>::infinity();
      const double observed = s.censored[j] > 0 ? -inf : s.censored[j] < 0 ? inf : dv;
      samples_.push_back({static_cast<int>(i), static_cast<int>(j), -1, 1.0, l.lower, l.upper, observed, 1.0, 0, 0, 0});
    }
  }
  if (samples_.empty()) throw InputError("VPC: the data have no observations");
  Bin(design);
  for (const Sample& s : samples_) {
    const SimulationDesign::Subject& subject = design.subjects[static_cast<size_t>(s.subject)];
    const auto j = static_cast<size_t>(s.index);
    summary_.observations.push_back({subject.id, subject.time[j], subject.dvid[j], kNaN, s.bin});
  }
  // A pvcVPC's observed side waits for the spreads (EndVariability).
  corrections_ready_ = !options.variability_corrected;
  if (corrections_ready_) Observe();
  simulated_.assign(summary_.bins.size(), std::vector<std::vector<double>>(options.percentiles.size()));
  simulated_censored_.assign(summary_.bins.size(), {});
}

// The observed side: censored observations at ∓∞, as simulated values beyond their limits.
void VpcAccumulator::Observe() {
  std::vector<std::vector<double>> by_bin(summary_.bins.size());
  for (size_t k = 0; k < samples_.size(); ++k) {
    const Sample& s = samples_[k];
    AddValue(s, s.observed, &by_bin);
    const double shown = by_bin[static_cast<size_t>(s.bin)].back();
    if (std::isinf(shown)) ++summary_.censored;
    summary_.observations[k].value = shown;
  }
  for (size_t b = 0; b < summary_.bins.size(); ++b) {
    VpcBin& bin = summary_.bins[b];
    bin.censored_observed = by_bin[b].empty() ? 0 : static_cast<double>(std::count(by_bin[b].begin(), by_bin[b].end(),
                                                                      -std::numeric_limits<double>::infinity())) /
                                                        static_cast<double>(by_bin[b].size());
    for (double p : options_.percentiles) bin.observed.push_back(Percentile(&by_bin[b], p));
  }
}

// Each DVID's bins, each sample's bin (those outside given edges left out), the bins' times, and
// the prediction correction's scales (samples it cannot scale left out).
void VpcAccumulator::Bin(const SimulationDesign& design) {
  std::map<Panel, std::map<double, int>> times;  // (stratum, DVID) → distinct time → count
  for (const Sample& s : samples_) {
    const SimulationDesign::Subject& subject = design.subjects[static_cast<size_t>(s.subject)];
    ++times[PanelOf(design, subject, static_cast<size_t>(s.index))][subject.time[static_cast<size_t>(s.index)]];
  }
  std::map<Panel, std::pair<int, std::vector<double>>> edges;  // (stratum, DVID) → (first bin, edges)
  for (const auto& [panel, counts] : times) {
    Times t;
    for (const auto& [time, count] : counts) {
      t.time.push_back(time);
      t.count.push_back(count);
    }
    const std::vector<double> e =
        options_.bin_edges.empty() ? AutomaticEdges(t, options_.max_bins, options_.min_bin_count) : options_.bin_edges;
    edges[panel] = {static_cast<int>(summary_.bins.size()), e};
    for (size_t b = 0; b + 1 < e.size(); ++b) {
      VpcBin bin;
      bin.stratum = panel.first;
      bin.dvid = panel.second;
      bin.lower = e[b];
      bin.upper = e[b + 1];
      summary_.bins.push_back(bin);
    }
  }
  summary_.binning = options_.bin_edges.empty()
                         ? "each distinct time a bin up to " + std::to_string(options_.max_bins) +
                               " a DVID, else Jenks' natural breaks of the times into " + std::to_string(options_.max_bins) +
                               (options_.min_bin_count > 1
                                    ? ", bins of fewer than " + std::to_string(options_.min_bin_count) + " values merged"
                                    : "")
                         : "the given edges";
  if (!design.stratify.empty()) summary_.binning += ", apart for each value of " + design.stratify;
  const double lb = options_.lower_bound;
  std::vector<Sample> kept;
  for (Sample s : samples_) {
    const SimulationDesign::Subject& subject = design.subjects[static_cast<size_t>(s.subject)];
    const auto& [first, e] = edges[PanelOf(design, subject, static_cast<size_t>(s.index))];
    const int b = BinOf(e, subject.time[static_cast<size_t>(s.index)]);
    if (b < 0) {
      ++summary_.outside_edges;
      continue;
    }
    if (options_.prediction_corrected && !(subject.pred(s.index) > lb && std::isfinite(subject.pred(s.index)))) {
      ++summary_.uncorrectable;
      continue;
    }
    s.bin = first + b;
    kept.push_back(s);
  }
  samples_ = std::move(kept);
  if (samples_.empty()) {
    throw InputError(summary_.uncorrectable > 0 ? "pcVPC: no observation has a PRED above the lower bound " + FormatNumber(lb)
                                                : "VPC: no observation lies within the bin edges");
  }
  std::vector<std::vector<double>> bin_times(summary_.bins.size()), bin_preds(summary_.bins.size());
  for (const Sample& s : samples_) {
    const SimulationDesign::Subject& subject = design.subjects[static_cast<size_t>(s.subject)];
    bin_times[static_cast<size_t>(s.bin)].push_back(subject.time[static_cast<size_t>(s.index)]);
    bin_preds[static_cast<size_t>(s.bin)].push_back(subject.pred(s.index));
  }
  for (size_t b = 0; b < summary_.bins.size(); ++b) {
    VpcBin& bin = summary_.bins[b];
    bin.observations = static_cast<int>(bin_times[b].size());
    bin.time = bin_times[b].empty() ? 0.5 * (bin.lower + bin.upper) : Median(bin_times[b]);
    if (options_.prediction_corrected) bin.pred_median = Median(bin_preds[b]);
  }
  if (!options_.prediction_corrected) return;
  for (Sample& s : samples_) {
    const double pred = design.subjects[static_cast<size_t>(s.subject)].pred(s.index);
    s.pc_scale = (summary_.bins[static_cast<size_t>(s.bin)].pred_median - lb) / (pred - lb);
  }
}

// y as the bin sees it: ∓∞ beyond the sample's limits, else prediction-corrected when asked.
void VpcAccumulator::AddValue(const Sample& s, double y, std::vector<std::vector<double>>* by_bin) const {
  const double inf = std::numeric_limits<double>::infinity();
  const double lb = options_.lower_bound;
  double v = y < s.lower ? -inf : y > s.upper ? inf : y;
  if (std::isfinite(v) && options_.prediction_corrected) v = lb + (v - lb) * s.pc_scale;
  if (std::isfinite(v) && options_.variability_corrected) {
    const double pred_b = summary_.bins[static_cast<size_t>(s.bin)].pred_median;
    v = pred_b + (v - pred_b) * s.vc_scale;
  }
  (*by_bin)[static_cast<size_t>(s.bin)].push_back(v);
}

void VpcAccumulator::AddVariability(const SimulatedReplicate& replicate) {
  AppendVariability(VariabilityValues(replicate));
}

void VpcAccumulator::AddVariability(const std::vector<std::vector<double>>& values) {
  AppendVariability(VariabilityValues(values));
}

std::vector<double> VpcAccumulator::VariabilityValues(const SimulatedReplicate& replicate) const {
  return VariabilityValues(SimulatedValues(replicate));
}

std::vector<double> VpcAccumulator::VariabilityValues(const std::vector<std::vector<double>>& values) const {
  if (!options_.variability_corrected || corrections_ready_) {
    throw std::logic_error("VpcAccumulator::AddVariability: not a pvcVPC, or after EndVariability");
  }
  const double lb = options_.lower_bound;
  std::vector<double> out(samples_.size(), kNaN);
  for (size_t k = 0; k < samples_.size(); ++k) {
    const Sample& s = samples_[k];
    const std::vector<double>& subject = values.at(static_cast<size_t>(s.subject));
    if (subject.empty()) continue;
    const double y = subject.at(static_cast<size_t>(s.index));
    if (std::isfinite(y)) out[k] = lb + (y - lb) * s.pc_scale;
  }
  return out;
}

void VpcAccumulator::AppendVariability(const std::vector<double>& values) {
  if (!options_.variability_corrected || corrections_ready_ || values.size() != samples_.size()) {
    throw std::logic_error("VpcAccumulator::AppendVariability: not a pvcVPC, after EndVariability, or another VPC's values");
  }
  ++variability_replicates_;
  for (size_t k = 0; k < samples_.size(); ++k) {  // Welford's update of the sample's mean and squared deviations
    if (std::isnan(values[k])) continue;
    Sample& s = samples_[k];
    s.n += 1;
    const double d = values[k] - s.mean;
    s.mean += d / s.n;
    s.m2 += d * (values[k] - s.mean);
  }
}

void VpcAccumulator::EndVariability() {
  if (!options_.variability_corrected || corrections_ready_) {
    throw std::logic_error("VpcAccumulator::EndVariability: not a pvcVPC, or called twice");
  }
  // sd_ij over the replicates, from at least half of them; sd_b the median of a bin's.
  const double needed = std::max(2.0, 0.5 * variability_replicates_);
  std::vector<double> sd(samples_.size(), kNaN);
  std::vector<std::vector<double>> by_bin(summary_.bins.size());
  for (size_t k = 0; k < samples_.size(); ++k) {
    const Sample& s = samples_[k];
    if (s.n >= needed) sd[k] = std::sqrt(s.m2 / (s.n - 1));
    if (sd[k] > 0) by_bin[static_cast<size_t>(s.bin)].push_back(sd[k]);
  }
  std::vector<double> median(by_bin.size(), kNaN);
  for (size_t b = 0; b < by_bin.size(); ++b) median[b] = Median(by_bin[b]);
  for (size_t k = 0; k < samples_.size(); ++k) {
    Sample& s = samples_[k];
    const double sd_b = median[static_cast<size_t>(s.bin)];
    const double scale = sd[k] > 0 ? sd_b / sd[k] : kNaN;  // NaN or ∞: not estimable
    s.vc_scale = std::isfinite(scale) ? scale : 1.0;
    if (!std::isfinite(scale)) ++summary_.unscaled;
  }
  corrections_ready_ = true;
  Observe();
}

VpcAccumulator::ReplicateStatistics VpcAccumulator::Summarise(const SimulatedReplicate& replicate) const {
  int failed = 0;
  ReplicateStatistics out = Summarise(SimulatedValues(replicate, &failed));
  out.failed = failed;
  return out;
}

VpcAccumulator::ReplicateStatistics VpcAccumulator::Summarise(const std::vector<std::vector<double>>& values) const {
  if (!corrections_ready_) throw std::logic_error("VpcAccumulator: a pvcVPC takes its replicates after EndVariability");
  std::vector<std::vector<double>> by_bin(summary_.bins.size());
  for (const Sample& s : samples_) {
    const std::vector<double>& subject = values.at(static_cast<size_t>(s.subject));
    if (subject.empty()) continue;
    AddValue(s, subject.at(static_cast<size_t>(s.index)), &by_bin);
  }
  const double below = -std::numeric_limits<double>::infinity();
  ReplicateStatistics out;
  for (std::vector<double>& v : by_bin) {
    out.censored.push_back(v.empty() ? std::numeric_limits<double>::quiet_NaN()
                                     : static_cast<double>(std::count(v.begin(), v.end(), below)) /
                                           static_cast<double>(v.size()));
    out.percentiles.emplace_back();
    for (double p : options_.percentiles) out.percentiles.back().push_back(Percentile(&v, p));
  }
  return out;
}

void VpcAccumulator::Append(const ReplicateStatistics& statistics) {
  if (statistics.censored.size() != simulated_.size() || statistics.percentiles.size() != simulated_.size()) {
    throw std::invalid_argument("VpcAccumulator::Append: statistics of another VPC");
  }
  for (size_t b = 0; b < simulated_.size(); ++b) {
    simulated_censored_[b].push_back(statistics.censored[b]);
    for (size_t k = 0; k < options_.percentiles.size(); ++k) simulated_[b][k].push_back(statistics.percentiles[b].at(k));
  }
  summary_.failed_simulations += statistics.failed;
  ++summary_.replicates;
}

void VpcAccumulator::Add(const SimulatedReplicate& replicate) { Append(Summarise(replicate)); }

void VpcAccumulator::Add(const std::vector<std::vector<double>>& values) { Append(Summarise(values)); }

VpcSummary VpcAccumulator::Finish() const {
  if (!corrections_ready_) throw std::logic_error("VpcAccumulator::Finish: a pvcVPC before EndVariability");
  VpcSummary out = summary_;
  const double tail = (100 - options_.interval) / 2;
  const auto interval = [&](std::vector<double> v, double* lower, double* median, double* upper) {
    v.erase(std::remove_if(v.begin(), v.end(), [](double x) { return std::isnan(x); }), v.end());
    *lower = Percentile(&v, tail);
    *median = Percentile(&v, 50);
    *upper = Percentile(&v, 100 - tail);
  };
  for (size_t b = 0; b < out.bins.size(); ++b) {
    VpcBin& bin = out.bins[b];
    interval(simulated_censored_[b], &bin.censored_lower, &bin.censored_median, &bin.censored_upper);
    for (size_t k = 0; k < options_.percentiles.size(); ++k) {
      double lower = 0, median = 0, upper = 0;
      interval(simulated_[b][k], &lower, &median, &upper);
      bin.simulated_lower.push_back(lower);
      bin.simulated_median.push_back(median);
      bin.simulated_upper.push_back(upper);
      // Against an interval below or above a limit too (comparisons of ∓∞ are exact); not for an empty bin.
      const double o = bin.observed[k];
      if (std::isnan(o) || std::isnan(lower)) continue;
      ++out.compared;
      if (o < lower || o > upper) ++out.outside;
    }
  }
  return out;
}

void CheckVpcOptions(const PopulationProblem& problem, const VpcOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw InputError("VPC: " + why);
  if (options.stratify.empty()) return;
  const Dataset& data = problem.data();
  const int column = data.ExtraColumn(options.stratify);
  if (column < 0) {
    std::string columns;
    for (const std::string& c : data.extra_columns) columns += (columns.empty() ? "" : ", ") + c;
    throw InputError("stratify by '" + options.stratify + "': " + data.source + " has no such column" +
                     (columns.empty() ? "" : " (its covariate columns: " + columns + ")"));
  }
  std::set<double> values;
  for (const Subject& s : data.subjects) {
    for (const Record& r : s.records) {
      if (r.IsSample()) values.insert(r.extra[static_cast<size_t>(column)]);
    }
  }
  if (values.size() > kMaxStrata) {
    throw InputError("VPC: " + data.extra_columns[static_cast<size_t>(column)] + " has " + std::to_string(values.size()) +
                     " values; stratify by a categorical column (at most " + std::to_string(kMaxStrata) +
                     " values: group a continuous covariate in a column of its own)");
  }
}

namespace {

// make(r) for r = 0…n−1 on `threads` workers, each result handed to take in the order of r. In chunks:
// a replicate of a small design takes tens of microseconds, about what handing it between threads costs.
template <typename T>
void InOrder(int n, int threads, const std::function<T(int)>& make, const std::function<void(T&&)>& take) {
  const int chunk = std::max(1, std::min(16, n / (8 * threads)));
  internal::OrderedParallel<std::vector<T>>(
      (n + chunk - 1) / chunk, threads, 4 * threads,
      [&](int c) {
        std::vector<T> out;
        for (int r = c * chunk; r < std::min(n, (c + 1) * chunk); ++r) out.push_back(make(r));
        return out;
      },
      [&](int, std::vector<T>&& items) {
        for (T& item : items) take(std::move(item));
      });
}

}  // namespace

VpcSummary ComputeVpc(const PopulationProblem& problem, const PopulationParameters& parameters,
                      const VpcOptions& options) {
  CheckVpcOptions(problem, options);
  VpcAccumulator vpc(MakeSimulationDesign(problem, parameters, options.stratify), options);
  PopulationSimulationOptions simulation;
  simulation.replicates = options.replicates;
  simulation.seed = options.seed;
  simulation.threads = 1;  // a replicate's subjects on one thread; the replicates on options.threads
  const int n = options.replicates;
  if (options.variability_corrected) {  // the samples' spreads over the same replicates, first
    InOrder<std::vector<double>>(
        n, options.threads,
        [&](int r) { return vpc.VariabilityValues(SimulateReplicate(problem, parameters, simulation, r)); },
        [&](std::vector<double>&& values) { vpc.AppendVariability(values); });
    vpc.EndVariability();
  }
  InOrder<VpcAccumulator::ReplicateStatistics>(
      n, options.threads, [&](int r) { return vpc.Summarise(SimulateReplicate(problem, parameters, simulation, r)); },
      [&](VpcAccumulator::ReplicateStatistics&& statistics) { vpc.Append(statistics); });
  return vpc.Finish();
}

std::string VpcSummary::Kind() const {
  if (variability_corrected) return "Prediction- and variability-corrected VPC";
  return prediction_corrected ? "Prediction-corrected VPC" : "VPC";
}

std::string VpcSummary::BriefReport() const {
  std::ostringstream out;
  out << Kind() << ": " << replicates << " replicates (seed "
      << seed << "), " << bins.size() << " bins (" << binning << "), " << observations.size() << " observed values";
  if (censored > 0) out << ", " << censored << " of them beyond a limit of quantification (counted as censored on both sides)";
  out << ".\n";
  if (outside_edges > 0) out << outside_edges << " observations outside the bin edges are left out.\n";
  if (uncorrectable > 0) {
    out << uncorrectable << " observations whose PRED is not above the lower bound (or cannot be evaluated) are left out "
                            "of the prediction correction.\n";
  }
  if (unscaled > 0) {
    out << unscaled << " observations whose spread over the replicates cannot be estimated (simulated in fewer than half "
                       "of them, or without spread) are prediction-corrected only.\n";
  }
  if (failed_simulations > 0) out << failed_simulations << " subject-replicates could not be simulated and are left out.\n";
  out << outside << " of " << compared << " observed percentiles lie outside their simulated " << FormatNumber(interval)
      << "% interval.\n";
  return out.str();
}

std::string VpcCsv(const VpcSummary& vpc) {
  // A percentile below (or above) the limit, or of an empty bin, is an empty field.
  const auto number = [](double v) { return std::isfinite(v) ? FormatNumber(v) : std::string(); };
  const bool strata = !vpc.stratify.empty();
  std::string out = (strata ? vpc.stratify + "," : "") +
                    "DVID,BIN,TIME,TIME_LOWER,TIME_UPPER,N,PERCENTILE,OBSERVED,SIM_LOWER,SIM_MEDIAN,SIM_UPPER";
  out += vpc.limits ? ",BLQ_OBSERVED,BLQ_SIM_LOWER,BLQ_SIM_MEDIAN,BLQ_SIM_UPPER" : "";
  // Which values these are, on every row, so that a table read alone says it: none, pc (prediction-
  // corrected, Bergstrand et al. 2011) or pvc (prediction- and variability-corrected).
  out += ",CORRECTION\n";
  const std::string correction =
      vpc.variability_corrected ? "pvc" : vpc.prediction_corrected ? "pc" : "none";
  int bin_in_panel = 0;
  const VpcBin* last = nullptr;
  for (const VpcBin& b : vpc.bins) {
    bin_in_panel = last && last->dvid == b.dvid && last->stratum == b.stratum ? bin_in_panel + 1 : 1;
    last = &b;
    for (size_t k = 0; k < vpc.percentiles.size(); ++k) {
      if (strata) out += FormatNumber(b.stratum) + ",";
      out += std::to_string(b.dvid) + "," + std::to_string(bin_in_panel);
      for (double v : {b.time, b.lower, b.upper}) out += "," + FormatNumber(v);
      out += "," + std::to_string(b.observations);
      for (double v : {vpc.percentiles[k], b.observed[k], b.simulated_lower[k], b.simulated_median[k], b.simulated_upper[k]}) {
        out += "," + number(v);
      }
      for (double v : {b.censored_observed, b.censored_lower, b.censored_median, b.censored_upper}) {
        if (vpc.limits) out += "," + number(v);
      }
      out += "," + correction + "\n";
    }
  }
  return out;
}

}  // namespace pk
