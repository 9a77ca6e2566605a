// The nonparametric bootstrap of a population fit (pk/bootstrap.h).
#include "pk/bootstrap.h"

#include <algorithm>
#include <cmath>
#include <exception>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <sstream>

#include "internal_text.h"
#include "pk/error.h"
#include "pk/output.h"
#include "pk/vpc.h"
#include "population/conditional.h"
#include "population/problem_impl.h"
#include "simulation/normal_stream.h"

namespace pk {
namespace {

using internal::kNaN;

// The drawn subjects as a dataset of their own, renumbered 1…N in the order drawn.
std::shared_ptr<const Dataset> Resampled(const Dataset& data, const std::vector<int>& subjects, int replicate) {
  auto out = std::make_shared<Dataset>();
  out->source = data.source + " (bootstrap replicate " + std::to_string(replicate + 1) + ")";
  out->header_line = data.header_line;
  out->columns = data.columns;
  out->column_units = data.column_units;
  out->extra_columns = data.extra_columns;
  out->relative_times = data.relative_times;
  for (size_t k = 0; k < subjects.size(); ++k) {
    Subject s = data.subjects[static_cast<size_t>(subjects[k])];
    s.id = static_cast<double>(k + 1);
    s.occurrence = 1;
    for (Record& r : s.records) r.id = s.id;
    out->subjects.push_back(std::move(s));
  }
  return out;
}

// Replicate r: its subjects drawn within `strata` (one value for all when unstratified, which draws as
// BootstrapSample(seed, r, N) does), fitted again.
BootstrapReplicate FitReplicate(const PopulationProblem& problem, const PopulationSummary& fit,
                                const BootstrapOptions& options, const std::vector<double>& strata, int r) {
  BootstrapReplicate out;
  out.replicate = r;
  const std::vector<int> subjects = BootstrapSample(options.seed, r, strata);
  try {
    const auto& d = problem.impl();
    const PopulationProblem resampled(d.model, Resampled(*d.data, subjects, r), problem.eta_names(), problem.options());
    PopulationOptions o = options.fit;
    o.method = fit.method;
    o.covariance = false;
    o.tables = false;  // a replicate gives its estimates only
    o.threads = 1;
    o.progress = nullptr;
    o.distribution = nullptr;  // every subject here: the replicates, not the subjects, are spread
    const PopulationSummary f = FitPopulation(resampled, fit.parameters, o);
    out.converged = f.converged;
    out.message = f.message;
    out.ofv = f.ofv;
    out.estimates.resize(static_cast<Eigen::Index>(f.estimates.size()));
    for (size_t k = 0; k < f.estimates.size(); ++k) {
      out.estimates(static_cast<Eigen::Index>(k)) = f.estimates[k].estimate;
      out.boundary = out.boundary || f.estimates[k].at_boundary;
    }
    out.used = out.converged && !(options.skip_boundary && out.boundary);
  } catch (const std::exception& e) {
    out.converged = false;
    out.message = e.what();
  }
  return out;
}

// Each parameter's statistics over the converged replicates.
void Summarise(const PopulationSummary& fit, BootstrapSummary* b) {
  for (size_t k = 0; k < fit.estimates.size(); ++k) {
    BootstrapParameter p;
    p.name = fit.estimates[k].name;
    p.estimate = fit.estimates[k].estimate;
    const PopulationEstimate& e = fit.estimates[k];
    // A SAME element varies with its source, and is fixed with it.
    p.fixed = e.same && e.source >= 0 ? fit.estimates[static_cast<size_t>(e.source)].fixed : e.fixed;
    std::vector<double> v;
    for (const BootstrapReplicate& r : b->runs) {
      if (r.used && r.estimates.size() == static_cast<Eigen::Index>(fit.estimates.size())) {
        v.push_back(r.estimates(static_cast<Eigen::Index>(k)));
      }
    }
    double mean = 0, ss = 0;
    for (double x : v) mean += x / static_cast<double>(v.size());
    for (double x : v) ss += (x - mean) * (x - mean);
    p.se = v.size() > 1 ? std::sqrt(ss / static_cast<double>(v.size() - 1)) : kNaN;
    p.mean = v.empty() ? kNaN : mean;
    p.bias = p.mean - p.estimate;
    p.median = Percentile(&v, 50);
    p.lower = Percentile(&v, (100 - b->interval) / 2);
    p.upper = Percentile(&v, (100 + b->interval) / 2);
    b->parameters.push_back(p);
  }
}

}  // namespace

bool BootstrapOptions::IsValid(std::string* error) const {
  if (replicates < 1) {
    *error = "the bootstrap needs at least 1 replicate, not " + std::to_string(replicates);
    return false;
  }
  if (threads < 1) {
    *error = "threads must be at least 1, not " + std::to_string(threads);
    return false;
  }
  if (!(interval > 0 && interval < 100)) {
    *error = "the interval must lie in (0, 100) %, not " + FormatNumber(interval);
    return false;
  }
  if (fit.max_iterations < 1) {
    *error = "the replicates' fits must estimate (max_iterations > 0): at 0 each would stay at the estimates";
    return false;
  }
  return fit.IsValid(error);
}

std::vector<int> BootstrapSample(std::uint64_t seed, int replicate, int subjects) {
  internal::NormalStream stream(seed, replicate, 0, internal::kBootstrapStream);
  std::vector<int> out(static_cast<size_t>(std::max(subjects, 0)));
  // u in (0, 1) with 52 bits: ⌊u·N⌋ is uniform on 0…N−1 up to N·2⁻⁵² (any N a dataset has).
  for (int& k : out) k = std::min(subjects - 1, static_cast<int>(stream.NextUniform() * subjects));
  return out;
}

std::vector<int> BootstrapSample(std::uint64_t seed, int replicate, const std::vector<double>& strata) {
  std::map<double, std::vector<int>> members;  // each stratum's subjects, in subject order
  for (size_t i = 0; i < strata.size(); ++i) members[strata[i]].push_back(static_cast<int>(i));
  internal::NormalStream stream(seed, replicate, 0, internal::kBootstrapStream);
  std::vector<int> out(strata.size());
  for (size_t i = 0; i < strata.size(); ++i) {
    const std::vector<int>& m = members[strata[i]];
    const int n = static_cast<int>(m.size());
    out[i] = m[static_cast<size_t>(std::min(n - 1, static_cast<int>(stream.NextUniform() * n)))];
  }
  return out;
}

std::vector<double> BootstrapStrata(const Dataset& data, const std::string& column) {
  const int c = data.ExtraColumn(column);
  if (c < 0) {
    const std::string upper = internal::ToUpper(column);
    const bool standard = std::find(data.columns.begin(), data.columns.end(), upper) != data.columns.end();
    std::string columns;
    for (const std::string& e : data.extra_columns) columns += (columns.empty() ? "" : ", ") + e;
    throw InputError("bootstrap: stratify by '" + column + "': " + data.source +
                     (standard ? " has it as a PREDPP column (ID, TIME, CMT, DVID, ...); stratify by a covariate column"
                               : " has no such column") +
                     (columns.empty() ? "" : " (its covariate columns: " + columns + ")"));
  }
  const auto at = std::find(data.columns.begin(), data.columns.end(), data.extra_columns[static_cast<size_t>(c)]);
  const int file_column = at == data.columns.end() ? 0 : static_cast<int>(at - data.columns.begin()) + 1;
  std::vector<double> out;
  for (const Subject& s : data.subjects) {
    const double v = s.records.empty() ? kNaN : s.records.front().extra[static_cast<size_t>(c)];
    // A subject's stratum is one value (PsN refuses a column that changes within a subject).
    for (const Record& r : s.records) {
      const double x = r.extra[static_cast<size_t>(c)];
      if (std::isnan(x)) {
        throw InputError(data.source, r.line, file_column,
                         "bootstrap: stratify by '" + column + "': missing for ID " + FormatNumber(s.id));
      }
      if (x != v) {
        throw InputError(data.source, r.line, file_column, "bootstrap: stratify by '" + column + "': ID " + FormatNumber(s.id) +
                                                         " has " + FormatNumber(x) + " here and " + FormatNumber(v) +
                                                         " on its first record; a stratum is one value a subject");
      }
    }
    out.push_back(v);
  }
  return out;
}

BootstrapSummary BootstrapPopulation(const PopulationProblem& problem, const PopulationSummary& fit,
                                     const BootstrapOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw InputError("bootstrap: " + why);
  BootstrapSummary b;
  b.stratify = options.stratify;
  const std::vector<double> strata = options.stratify.empty()
                                         ? std::vector<double>(static_cast<size_t>(problem.num_subjects()), 0.0)
                                         : BootstrapStrata(problem.data(), options.stratify);
  if (!options.stratify.empty()) {
    std::map<double, int> sizes;
    for (double v : strata) ++sizes[v];
    b.strata = static_cast<int>(sizes.size());
    for (const auto& [value, n] : sizes) b.small_strata += n < 5 ? 1 : 0;
  }
  b.replicates = options.replicates;
  b.seed = options.seed;
  b.interval = options.interval;
  for (const PopulationEstimate& e : fit.estimates) b.names.push_back(e.name);
  b.original_converged = fit.converged;
  b.runs.resize(static_cast<size_t>(options.replicates));
  std::mutex progress;
  int done = 0;
  internal::ParallelFor(options.replicates, options.threads, [&](int r) {
    b.runs[static_cast<size_t>(r)] = FitReplicate(problem, fit, options, strata, r);
    const std::lock_guard<std::mutex> lock(progress);
    ++done;
    if (options.progress) options.progress(done);
  });
  for (const BootstrapReplicate& r : b.runs) {
    b.converged += r.converged ? 1 : 0;
    b.used += r.used ? 1 : 0;
  }
  Summarise(fit, &b);
  return b;
}

std::string BootstrapSummary::BriefReport() const {
  std::string s = "Bootstrap: " + std::to_string(replicates) + " replicates (seed " + std::to_string(seed) + "), " +
                  (stratify.empty() ? std::string()
                                    : "stratified on " + stratify + " (" + std::to_string(strata) + " strata), ") +
                  std::to_string(converged) + " converged, " + std::to_string(used) +
                  " of them with no estimate near a boundary; the statistics are over those " + std::to_string(used) + ".\n";
  if (!original_converged) s += "warning: the bootstrapped fit itself did not converge.\n";
  if (small_strata > 0) {
    s += "warning: " + std::to_string(small_strata) + " of the " + std::to_string(strata) + " strata of " + stratify +
         " hold fewer than 5 subjects, which resample little (a stratum of one, never): the bootstrap's spread "
         "shrinks; stratify on fewer, larger groups.\n";
  }
  if (used < 0.8 * replicates) s += "warning: fewer than 80% of the replicates are used (PsN's threshold).\n";
  return s;
}

std::string BootstrapSummary::FullReport() const {
  std::ostringstream out;
  out << BriefReport();
  const std::string pi = internal::Num(interval, "%g") + "% interval";
  out << "  parameter            estimate      median        mean        bias    bootstrap SE   " << pi << "\n";
  for (const BootstrapParameter& p : parameters) {
    std::string name = p.name;
    name.resize(std::max<size_t>(name.size(), 18), ' ');
    const auto shown = [&](double v) { return p.fixed ? kNaN : v; };
    out << "  " << name << internal::Cell(p.estimate, "%.6g", 12) << internal::Cell(shown(p.median), "%.6g", 12)
        << internal::Cell(shown(p.mean), "%.6g", 12) << internal::Cell(shown(p.bias), "%.4g", 12)
        << internal::Cell(shown(p.se), "%.4g", 15) << "   ";
    if (p.fixed || !std::isfinite(p.lower)) {
      out << (p.fixed ? "(fixed)" : "–");
    } else {
      out << internal::Num(p.lower, "%.4g") << " to " << internal::Num(p.upper, "%.4g");
    }
    out << "\n";
  }
  return out.str();
}

std::string BootstrapCsv(const BootstrapSummary& summary) {
  std::string out = "REPLICATE,CONVERGED,BOUNDARY,USED,OFV";
  for (const std::string& n : summary.names) out += "," + (n.find(',') == std::string::npos ? n : "\"" + n + "\"");
  out += "\n";
  for (const BootstrapReplicate& r : summary.runs) {
    out += std::to_string(r.replicate + 1) + (r.converged ? ",1" : ",0") + (r.boundary ? ",1" : ",0") +
           (r.used ? ",1," : ",0,");
    if (r.estimates.size() > 0) AppendNumber(&out, r.ofv);
    for (Eigen::Index k = 0; k < r.estimates.size(); ++k) {
      out += ',';
      AppendNumber(&out, r.estimates(k));
    }
    for (size_t k = static_cast<size_t>(r.estimates.size()); k < summary.names.size(); ++k) out += ',';
    out += "\n";
  }
  return out;
}

}  // namespace pk
