// Normalised prediction distribution errors (pk/npde.h). Boost.Math's normal quantile is sealed here.
#include "pk/npde.h"

#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

#include <Eigen/Cholesky>
#include <boost/math/distributions/normal.hpp>

#include "pk/error.h"
#include "pk/output.h"
#include "pk/population_simulation.h"
#include "internal_text.h"
#include "population/conditional.h"
#include "population/simulator.h"

namespace pk {
namespace {

using internal::kNaN;

// #{k : values(k) < x} / K, with 0 and 1 moved to 1/(2K) and 1 − 1/(2K).
double BoundedFraction(const Eigen::Ref<const Eigen::RowVectorXd>& values, double x) {
  const double k = static_cast<double>(values.size());
  const double p = static_cast<double>((values.array() < x).count()) / k;
  return p == 0 ? 1 / (2 * k) : p == 1 ? 1 - 1 / (2 * k) : p;
}

std::string Figure(double v, const char* format) { return std::isfinite(v) ? internal::Num(v, format) : "–"; }

std::string Moment(const char* name, double value, double se = kNaN) {
  std::ostringstream out;
  out << name << " " << Figure(value, "%.3g");
  if (std::isfinite(se)) out << " (SE " << Figure(se, "%.2g") << ")";
  return out.str();
}

std::string Moments(const NpdeMoments& m) {
  return Moment("mean", m.mean, m.mean_se) + ", " + Moment("variance", m.variance, m.variance_se) + ", " +
         Moment("skewness", m.skewness) + ", " + Moment("kurtosis", m.kurtosis);
}

// The rows of one subject of the design, NaN until computed.
void AppendRows(const SimulationDesign::Subject& d, std::vector<NpdeRow>* rows) {
  for (size_t j = 0; j < d.time.size(); ++j) {
    NpdeRow r;
    r.subject = d.subject;
    r.id = d.id;
    r.time = d.time[j];
    r.dvid = d.dvid[j];
    r.dv = d.dv(static_cast<Eigen::Index>(j));
    r.censored = d.censored[j] != 0;
    r.epred = r.pd = r.npd = r.pde = r.npde = kNaN;
    rows->push_back(r);
  }
}

// Subject i's NPDE into its rows (first..), or a note when it is left out or has no NPDE.
void SubjectRows(const internal::PopulationSimulator& simulator, const SimulationDesign::Subject& d, int simulations,
                 NpdeRow* rows, std::string* note) {
  std::vector<Eigen::Index> keep;
  for (size_t j = 0; j < d.censored.size(); ++j) {
    if (d.censored[j] == 0) keep.push_back(static_cast<Eigen::Index>(j));
  }
  if (keep.empty()) return;
  const Eigen::Index n = static_cast<Eigen::Index>(keep.size());
  Eigen::VectorXd observed(n);
  Eigen::MatrixXd simulated(n, simulations);
  for (Eigen::Index j = 0; j < n; ++j) observed(j) = d.dv(keep[static_cast<size_t>(j)]);
  for (int k = 0; k < simulations; ++k) {
    const SimulatedSubject s = simulator.Subject(k, d.subject);
    if (!s.ok) {
      *note = "ID " + FormatNumber(d.id) + " is left out: its simulation " + std::to_string(k + 1) +
              " could not be evaluated (" + s.message + ")";
      return;
    }
    for (Eigen::Index j = 0; j < n; ++j) simulated(j, k) = s.dv(keep[static_cast<size_t>(j)]);
  }
  const SubjectNpde npde = ComputeSubjectNpde(observed, simulated);
  if (!npde.message.empty()) *note = "ID " + FormatNumber(d.id) + " has no NPDE (its PD are given): " + npde.message;
  for (Eigen::Index j = 0; j < n; ++j) {
    NpdeRow& r = rows[keep[static_cast<size_t>(j)]];
    r.epred = npde.epred(j);
    r.pd = npde.pd(j);
    r.npd = NormalQuantile(r.pd);
    if (npde.pde.size() == 0) continue;
    r.pde = npde.pde(j);
    r.npde = NormalQuantile(r.pde);
  }
}

}  // namespace

bool NpdeOptions::IsValid(std::string* error) const {
  if (simulations < 2) {
    *error = "the NPDE need at least 2 simulations, not " + std::to_string(simulations);
    return false;
  }
  if (threads < 1) {
    *error = "threads must be at least 1, not " + std::to_string(threads);
    return false;
  }
  return true;
}

double NormalQuantile(double p) {
  if (!(p > 0 && p < 1)) throw std::domain_error("NormalQuantile: p must lie in (0, 1), not " + FormatNumber(p));
  return boost::math::quantile(boost::math::normal_distribution<double>(), p);
}

SubjectNpde ComputeSubjectNpde(const Eigen::VectorXd& observed, const Eigen::MatrixXd& simulated) {
  const Eigen::Index n = observed.size(), k = simulated.cols();
  if (simulated.rows() != n || k < 2) {
    throw std::invalid_argument("ComputeSubjectNpde: expected " + std::to_string(n) + " × K simulations, K ≥ 2");
  }
  if (!observed.allFinite() || !simulated.allFinite()) {
    throw std::invalid_argument("ComputeSubjectNpde: an observed or simulated value is not finite");
  }
  SubjectNpde out;
  out.epred = simulated.rowwise().mean();
  out.pd.resize(n);
  for (Eigen::Index j = 0; j < n; ++j) out.pd(j) = BoundedFraction(simulated.row(j), observed(j));
  // One n × K matrix besides the caller's: centred, then decorrelated in place.
  Eigen::MatrixXd centred = simulated.colwise() - out.epred;
  const Eigen::MatrixXd v = centred * centred.transpose() / static_cast<double>(k - 1);
  const Eigen::LLT<Eigen::MatrixXd> llt(v);
  // A pivot L_jj² is y_j's variance given the values before it: one lost to rounding (a sample
  // that repeats another, as R's chol() refuses with a pivot ≤ 0) would divide by noise.
  const Eigen::ArrayXd pivots = llt.matrixLLT().diagonal().array().square();
  if (llt.info() != Eigen::Success || !v.allFinite() || (pivots <= 1e-13 * v.diagonal().array()).any()) {
    out.message = "the covariance of its " + std::to_string(n) + " simulated values over " + std::to_string(k) +
                  " simulations has no Cholesky factor (more simulations may give one)";
    return out;
  }
  const auto l = llt.matrixL();
  l.solveInPlace(centred);
  const Eigen::VectorXd decorrelated_observed = l.solve(observed - out.epred);
  out.pde.resize(n);
  for (Eigen::Index j = 0; j < n; ++j) out.pde(j) = BoundedFraction(centred.row(j), decorrelated_observed(j));
  return out;
}

NpdeMoments ComputeNpdeMoments(const std::vector<double>& values) {
  NpdeMoments m;
  double sum = 0;
  for (double v : values) {
    if (std::isfinite(v)) sum += v, ++m.count;
  }
  if (m.count == 0) return m;  // every moment NaN
  const double n = m.count;
  m.mean = sum / n;
  double m2 = 0, m3 = 0, m4 = 0;  // Σd², Σd³, Σd⁴
  for (double v : values) {
    if (!std::isfinite(v)) continue;
    const double d = v - m.mean, d2 = d * d;
    m2 += d2, m3 += d2 * d, m4 += d2 * d2;
  }
  if (m.count < 2) return m;
  m.variance = m2 / (n - 1);
  m.mean_se = std::sqrt(m.variance / n);
  m.variance_se = m.variance * std::sqrt(2 / (n - 1));
  // The npde package's moment estimators: g1 = (Σd³/n)/(Σd²/n)^{3/2}, g2 = n Σd⁴/(Σd²)² − 3.
  m.skewness = m2 > 0 ? (m3 / n) / std::pow(m2 / n, 1.5) : kNaN;
  m.kurtosis = m2 > 0 ? n * m4 / (m2 * m2) - 3 : kNaN;
  return m;
}

NpdeSummary ComputeNpde(const PopulationProblem& problem, const PopulationParameters& parameters,
                        const NpdeOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw InputError("NPDE: " + why);
  PopulationSimulationOptions simulation;
  simulation.seed = options.seed;
  const internal::PopulationSimulator simulator(problem, parameters, simulation);
  const SimulationDesign design = MakeSimulationDesign(problem, parameters);
  NpdeSummary out;
  out.simulations = options.simulations;
  out.seed = options.seed;
  std::vector<size_t> first;  // each subject's first row
  for (const SimulationDesign::Subject& d : design.subjects) {
    first.push_back(out.rows.size());
    AppendRows(d, &out.rows);
  }
  std::vector<std::string> notes(design.subjects.size());
  internal::ParallelFor(static_cast<int>(design.subjects.size()), options.threads, [&](int i) {
    const auto s = static_cast<size_t>(i);
    SubjectRows(simulator, design.subjects[s], options.simulations, out.rows.data() + first[s], &notes[s]);
  });
  for (std::string& note : notes) {
    if (!note.empty()) out.notes.push_back(std::move(note));
  }
  std::vector<double> npde, npd;
  for (const NpdeRow& r : out.rows) {
    out.censored += r.censored ? 1 : 0;
    npde.push_back(r.npde);
    npd.push_back(r.npd);
  }
  out.npde = ComputeNpdeMoments(npde);
  out.npde_tests = TestNpde(npde);
  out.npd = ComputeNpdeMoments(npd);
  return out;
}

std::string NpdeSummary::BriefReport() const {
  std::string s = "NPDE of " + std::to_string(npde.count) + " of " + std::to_string(rows.size()) + " samples from " +
                  std::to_string(simulations) + " simulations: " + Moments(npde) + " (N(0, 1): 0, 1, 0, 0)";
  const auto p = [](double v) { return Figure(v, "%.2g"); };
  s += ". Tests: mean (t) p = " + p(npde_tests.mean_p) + " (Wilcoxon signed rank: " + p(npde_tests.mean_wilcoxon_p) +
       "), variance (Fisher) p = " + p(npde_tests.variance_p) + ", normality (Shapiro–Wilk) p = " +
       p(npde_tests.normality_p) + ", global (Bonferroni) p = " + p(npde_tests.global_p);
  if (censored > 0) s += "; " + std::to_string(censored) + " censored samples left out";
  if (!notes.empty()) s += "; " + std::to_string(notes.size()) + " subjects without NPDE (see the notes)";
  return s + "\n";
}

std::string NpdeSummary::FullReport() const {
  std::string s = BriefReport();
  s += "NPD (not decorrelated) of " + std::to_string(npd.count) + " samples: " + Moments(npd) + "\n";
  s += "seed " + std::to_string(seed) + "\n";
  for (const std::string& note : notes) s += "note: " + note + "\n";
  return s;
}

std::string NpdeCsv(const NpdeSummary& npde) {
  std::string out = "ID,TIME,DVID,DV,CENS,EPRED,PD,NPD,PDE,NPDE\n";
  const auto field = [&out](double v) {
    out += ',';
    if (std::isfinite(v)) AppendNumber(&out, v);
  };
  for (const NpdeRow& r : npde.rows) {
    AppendNumber(&out, r.id);
    field(r.time);
    out += ',' + std::to_string(r.dvid);
    field(r.dv);
    out += r.censored ? ",1" : ",0";
    field(r.epred);
    field(r.pd);
    field(r.npd);
    field(r.pde);
    field(r.npde);
    out += '\n';
  }
  return out;
}

}  // namespace pk
