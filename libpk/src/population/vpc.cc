// Visual predictive checks (pk/vpc.h): bins, percentiles of the data and of each simulated
// replicate, and the replicates' intervals.
#include "pk/vpc.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <sstream>

#include "pk/error.h"
#include "pk/output.h"

namespace pk {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// The distinct times of one DVID's values and how many values each has.
struct Times {
  std::vector<double> time;
  std::vector<int> count;
};

// Jenks' natural breaks over distinct times with multiplicities: the split into k consecutive
// groups that minimises Σ over groups of Σ count·(t − group mean)², by dynamic programming
// (Fisher 1958), O(k·u²) for u distinct times. Returns the index of each group's first time.
std::vector<size_t> NaturalBreaks(const Times& t, int k) {
  const size_t u = t.time.size();
  // Prefix sums of count, count·t and count·t² give any group's squared deviation at once.
  std::vector<double> w(u + 1, 0), s(u + 1, 0), ss(u + 1, 0);
  for (size_t i = 0; i < u; ++i) {
    w[i + 1] = w[i] + t.count[i];
    s[i + 1] = s[i] + t.count[i] * t.time[i];
    ss[i + 1] = ss[i] + t.count[i] * t.time[i] * t.time[i];
  }
  const auto cost = [&](size_t a, size_t b) {  // times [a, b)
    const double n = w[b] - w[a], m = s[b] - s[a];
    return std::max(0.0, ss[b] - ss[a] - m * m / n);
  };
  const auto groups = static_cast<size_t>(k);
  const double inf = std::numeric_limits<double>::infinity();
  // best[g][b]: the least cost of the first b times in g + 1 groups; from[g][b]: its last group's start.
  std::vector<std::vector<double>> best(groups, std::vector<double>(u + 1, inf));
  std::vector<std::vector<size_t>> from(groups, std::vector<size_t>(u + 1, 0));
  for (size_t b = 1; b <= u; ++b) best[0][b] = cost(0, b);
  for (size_t g = 1; g < groups; ++g) {
    for (size_t b = g + 1; b <= u; ++b) {
      for (size_t a = g; a < b; ++a) {
        const double c = best[g - 1][a] + cost(a, b);
        if (c < best[g][b]) {
          best[g][b] = c;
          from[g][b] = a;
        }
      }
    }
  }
  std::vector<size_t> starts(groups, 0);
  size_t b = u;
  for (size_t g = groups; g-- > 1;) {
    starts[g] = from[g][b];
    b = starts[g];
  }
  return starts;
}

// Bin edges for one DVID's distinct times: given ones, or midpoints between the groups' times.
std::vector<double> AutomaticEdges(const Times& t, int max_bins) {
  const size_t u = t.time.size();
  std::vector<double> edges{t.time.front()};
  if (u <= static_cast<size_t>(max_bins)) {
    for (size_t i = 1; i < u; ++i) edges.push_back(0.5 * (t.time[i - 1] + t.time[i]));
  } else {
    const std::vector<size_t> starts = NaturalBreaks(t, max_bins);
    for (size_t g = 1; g < starts.size(); ++g) edges.push_back(0.5 * (t.time[starts[g] - 1] + t.time[starts[g]]));
  }
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
  return low + (h - static_cast<double>(k)) * (high - low);
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
  if (!std::isfinite(lower_bound)) return fail("the lower bound must be finite");
  if (threads < 1) return fail("threads must be at least 1, not " + std::to_string(threads));
  return true;
}

VpcAccumulator::VpcAccumulator(const SimulationDesign& design, const VpcOptions& options) : options_(options) {
  std::string why;
  if (!options.IsValid(&why)) throw InputError("VPC: " + why);
  summary_.percentiles = options.percentiles;
  summary_.interval = options.interval;
  summary_.prediction_corrected = options.prediction_corrected;
  summary_.seed = options.seed;
  // The values, and each DVID's distinct times.
  std::map<int, std::map<double, int>> times;
  for (size_t i = 0; i < design.subjects.size(); ++i) {
    const SimulationDesign::Subject& s = design.subjects[i];
    for (size_t j = 0; j < s.time.size(); ++j) {
      if (s.censored[j] != 0) {
        ++summary_.censored;
        continue;
      }
      ++times[s.dvid[j]][s.time[j]];
      samples_.push_back({static_cast<int>(i), static_cast<int>(j), -1, 1.0});
    }
  }
  if (samples_.empty()) throw InputError("VPC: the data have no observed values");
  // Bins per DVID.
  std::map<int, std::pair<int, std::vector<double>>> edges;  // DVID → (first bin, edges)
  for (const auto& [dvid, counts] : times) {
    Times t;
    for (const auto& [time, count] : counts) {
      t.time.push_back(time);
      t.count.push_back(count);
    }
    std::vector<double> e = options.bin_edges.empty() ? AutomaticEdges(t, options.max_bins) : options.bin_edges;
    edges[dvid] = {static_cast<int>(summary_.bins.size()), e};
    for (size_t b = 0; b + 1 < e.size(); ++b) {
      VpcBin bin;
      bin.dvid = dvid;
      bin.lower = e[b];
      bin.upper = e[b + 1];
      summary_.bins.push_back(bin);
    }
  }
  summary_.binning = options.bin_edges.empty()
                         ? "each distinct time a bin up to " + std::to_string(options.max_bins) +
                               " a DVID, else Jenks' natural breaks of the times into " + std::to_string(options.max_bins)
                         : "the given edges";
  // Each value's bin; values outside the given edges are left out.
  std::vector<std::vector<double>> bin_times(summary_.bins.size()), bin_preds(summary_.bins.size());
  std::vector<Sample> kept;
  for (Sample s : samples_) {
    const SimulationDesign::Subject& subject = design.subjects[static_cast<size_t>(s.subject)];
    const auto j = static_cast<size_t>(s.index);
    const auto& [first, e] = edges[subject.dvid[j]];
    const int b = BinOf(e, subject.time[j]);
    if (b < 0) continue;
    s.bin = first + b;
    bin_times[static_cast<size_t>(s.bin)].push_back(subject.time[j]);
    bin_preds[static_cast<size_t>(s.bin)].push_back(subject.pred(s.index));
    kept.push_back(s);
  }
  samples_ = std::move(kept);
  if (samples_.empty()) throw InputError("VPC: no observed value lies within the bin edges");
  for (size_t b = 0; b < summary_.bins.size(); ++b) {
    VpcBin& bin = summary_.bins[b];
    bin.observations = static_cast<int>(bin_times[b].size());
    bin.time = bin_times[b].empty() ? 0.5 * (bin.lower + bin.upper) : Median(bin_times[b]);
    if (options.prediction_corrected) bin.pred_median = Median(bin_preds[b]);
  }
  if (options.prediction_corrected) {
    const double lb = options.lower_bound;
    for (Sample& s : samples_) {
      const double pred = design.subjects[static_cast<size_t>(s.subject)].pred(s.index);
      const double pb = summary_.bins[static_cast<size_t>(s.bin)].pred_median;
      if (!(pred > lb) || !(pb > lb)) {
        throw InputError("pcVPC: a population prediction (PRED " + FormatNumber(pred) + ") is not above the lower bound " +
                         FormatNumber(lb) + "; give a lower --vpc-lower-bound, or leave prediction correction off");
      }
      s.pc_scale = (pb - lb) / (pred - lb);
    }
  }
  // The observed side.
  std::vector<std::vector<double>> by_bin(summary_.bins.size());
  for (const Sample& s : samples_) {
    const SimulationDesign::Subject& subject = design.subjects[static_cast<size_t>(s.subject)];
    const auto j = static_cast<size_t>(s.index);
    AddValue(s, subject.dv(s.index), &by_bin);
    summary_.observations.push_back({subject.id, subject.time[j], subject.dvid[j], by_bin[static_cast<size_t>(s.bin)].back(), s.bin});
  }
  for (size_t b = 0; b < summary_.bins.size(); ++b) {
    for (double p : options.percentiles) summary_.bins[b].observed.push_back(Percentile(&by_bin[b], p));
  }
  simulated_.assign(summary_.bins.size(), std::vector<std::vector<double>>(options.percentiles.size()));
  scratch_.assign(summary_.bins.size(), {});
}

void VpcAccumulator::AddValue(const Sample& s, double y, std::vector<std::vector<double>>* by_bin) const {
  const double lb = options_.lower_bound;
  (*by_bin)[static_cast<size_t>(s.bin)].push_back(options_.prediction_corrected ? lb + (y - lb) * s.pc_scale : y);
}

void VpcAccumulator::Add(const SimulatedReplicate& replicate) {
  std::vector<std::vector<double>> values(replicate.subjects.size());
  for (size_t i = 0; i < replicate.subjects.size(); ++i) {
    const SimulatedSubject& s = replicate.subjects[i];
    if (!s.ok) {
      ++summary_.failed_simulations;
      continue;
    }
    values[i].assign(s.dv.data(), s.dv.data() + s.dv.size());
  }
  Add(values);
}

void VpcAccumulator::Add(const std::vector<std::vector<double>>& values) {
  for (auto& v : scratch_) v.clear();
  for (const Sample& s : samples_) {
    const std::vector<double>& subject = values.at(static_cast<size_t>(s.subject));
    if (subject.empty()) continue;
    AddValue(s, subject.at(static_cast<size_t>(s.index)), &scratch_);
  }
  for (size_t b = 0; b < scratch_.size(); ++b) {
    for (size_t k = 0; k < options_.percentiles.size(); ++k) {
      simulated_[b][k].push_back(Percentile(&scratch_[b], options_.percentiles[k]));
    }
  }
  ++summary_.replicates;
}

VpcSummary VpcAccumulator::Finish() const {
  VpcSummary out = summary_;
  const double tail = (100 - options_.interval) / 2;
  for (size_t b = 0; b < out.bins.size(); ++b) {
    VpcBin& bin = out.bins[b];
    for (size_t k = 0; k < options_.percentiles.size(); ++k) {
      std::vector<double> v;  // the replicates' percentile where the bin held simulated values
      for (double x : simulated_[b][k]) {
        if (!std::isnan(x)) v.push_back(x);
      }
      bin.simulated_lower.push_back(Percentile(&v, tail));
      bin.simulated_median.push_back(Percentile(&v, 50));
      bin.simulated_upper.push_back(Percentile(&v, 100 - tail));
      const double o = bin.observed[k];
      if (std::isnan(o) || std::isnan(bin.simulated_lower.back())) continue;
      ++out.compared;
      if (o < bin.simulated_lower.back() || o > bin.simulated_upper.back()) ++out.outside;
    }
  }
  return out;
}

VpcSummary ComputeVpc(const PopulationProblem& problem, const PopulationParameters& parameters,
                      const VpcOptions& options) {
  VpcAccumulator vpc(MakeSimulationDesign(problem, parameters), options);
  PopulationSimulationOptions simulation;
  simulation.replicates = options.replicates;
  simulation.seed = options.seed;
  simulation.threads = options.threads;
  SimulatePopulation(problem, parameters, simulation, [&](const SimulatedReplicate& r) { vpc.Add(r); });
  return vpc.Finish();
}

std::string VpcSummary::BriefReport() const {
  std::ostringstream out;
  out << (prediction_corrected ? "Prediction-corrected VPC" : "VPC") << ": " << replicates << " replicates (seed "
      << seed << "), " << bins.size() << " bins (" << binning << "), " << observations.size() << " observed values";
  if (censored > 0) out << ", " << censored << " censored samples left out";
  out << ".\n";
  if (failed_simulations > 0) out << failed_simulations << " subject-replicates could not be simulated and are left out.\n";
  out << outside << " of " << compared << " observed percentiles lie outside their simulated " << FormatNumber(interval)
      << "% interval.\n";
  return out.str();
}

std::string VpcCsv(const VpcSummary& vpc) {
  std::string out = "DVID,BIN,TIME,TIME_LOWER,TIME_UPPER,N,PERCENTILE,OBSERVED,SIM_LOWER,SIM_MEDIAN,SIM_UPPER\n";
  int bin_in_dvid = 0, last_dvid = -1;
  for (const VpcBin& b : vpc.bins) {
    bin_in_dvid = b.dvid == last_dvid ? bin_in_dvid + 1 : 1;
    last_dvid = b.dvid;
    for (size_t k = 0; k < vpc.percentiles.size(); ++k) {
      out += std::to_string(b.dvid) + "," + std::to_string(bin_in_dvid);
      for (double v : {b.time, b.lower, b.upper}) out += "," + FormatNumber(v);
      out += "," + std::to_string(b.observations);
      for (double v : {vpc.percentiles[k], b.observed[k], b.simulated_lower[k], b.simulated_median[k], b.simulated_upper[k]}) {
        out += "," + FormatNumber(v);
      }
      out += "\n";
    }
  }
  return out;
}

}  // namespace pk
