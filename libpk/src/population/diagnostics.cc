// Per-sample diagnostics and shrinkage at the estimate (engine.h).
//
//   PRED  = ŷ(θ, η = 0)                 IPRED = ŷ(θ, η̂)
//   RES   = y − f₀                      IWRES = (y − f(η̂))/√V(η̂)
//   WRES  = C₀^(−½)(y − f₀),            C₀ = G₀ΩG₀ᵀ + diag V₀   (the FO linearisation at η = 0)
//   CWRES = C^(−½)(y − f(η̂) + Gη̂),      C = GΩGᵀ + diag V       (at η̂; Hooker et al.,
//                                                                 Pharm Res 2007;24:2187-2197)
// with f on the error model's scale (log ŷ for the exponential error) and C^(−½) the symmetric
// inverse square root. A censored sample (M3) is a limit, not a value: its RES, WRES, CWRES and
// IWRES are NaN, and C is formed over the values alone. Shrinkage (Savic & Karlsson, AAPS J 2009;11:558-569) uses the sample SD
// (n − 1) over the subjects whose mode was found, as PsN and Xpose compute it.
#include <cmath>
#include <limits>

#include <Eigen/Eigenvalues>

#include "population/engine.h"
#include "population/problem_impl.h"

namespace pk {
namespace internal {
namespace {

Eigen::VectorXd Whiten(const Eigen::MatrixXd& c, const Eigen::VectorXd& r) {
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(c);
  const Eigen::VectorXd lambda = es.eigenvalues();
  if (es.info() != Eigen::Success || !(lambda.array() > 0).all()) {
    return Eigen::VectorXd::Constant(r.size(), std::numeric_limits<double>::quiet_NaN());
  }
  return es.eigenvectors() * (lambda.array().rsqrt() * (es.eigenvectors().transpose() * r).array()).matrix();
}

double SampleSd(const std::vector<double>& v) {
  if (v.size() < 2) return std::numeric_limits<double>::quiet_NaN();
  double mean = 0, ss = 0;
  for (double x : v) mean += x;
  mean /= static_cast<double>(v.size());
  for (double x : v) ss += (x - mean) * (x - mean);
  return std::sqrt(ss / static_cast<double>(v.size() - 1));
}

// C^(−½)(y − f + Gη) over the samples that are values (censored ones are limits: NaN there).
Eigen::VectorXd WeightedResiduals(const SubjectModel& s, const Conditional& c, const Eigen::MatrixXd& omega,
                                  const Eigen::VectorXd& eta) {
  const Eigen::Index n = s.y.size();
  std::vector<Eigen::Index> values;
  for (Eigen::Index j = 0; j < n; ++j) {
    if (s.censoring.size() != n || s.censoring(j) == 0) values.push_back(j);
  }
  const auto m = static_cast<Eigen::Index>(values.size());
  Eigen::MatrixXd g(m, omega.rows());
  Eigen::VectorXd r(m), v(m);
  for (Eigen::Index k = 0; k < m; ++k) {
    const Eigen::Index j = values[static_cast<size_t>(k)];
    g.row(k) = c.g.row(j);
    r(k) = s.y(j) - c.f(j) + c.g.row(j).dot(eta);
    v(k) = c.variance(j);
  }
  const Eigen::VectorXd w = Whiten(g * omega * g.transpose() + Eigen::MatrixXd(v.asDiagonal()), r);
  Eigen::VectorXd out = Eigen::VectorXd::Constant(n, std::numeric_limits<double>::quiet_NaN());
  for (Eigen::Index k = 0; k < m; ++k) out(values[static_cast<size_t>(k)]) = w(k);
  return out;
}

void SubjectRows(const SubjectModel& s, const PopulationPoint& point, const Eigen::MatrixXd& omega, double id,
                 int subject, const SubjectMode& m, std::vector<PopulationRow>* rows, std::vector<double>* iwres) {
  Conditional c0;
  std::string why;
  const Eigen::VectorXd zero = Eigen::VectorXd::Zero(omega.rows());
  const bool have0 = EvaluateConditional(s, point, zero, nullptr, true, &c0, &why);
  const Conditional& c = m.at_mode;
  const Eigen::Index n = s.y.size();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const Eigen::VectorXd wres = have0 ? WeightedResiduals(s, c0, omega, zero) : Eigen::VectorXd::Constant(n, nan);
  const Eigen::VectorXd cwres = WeightedResiduals(s, c, omega, m.eta);
  const std::vector<double> times = s.objective->sample_times();
  const std::vector<int> outputs = s.objective->sample_outputs();
  const std::vector<int> records = s.objective->sample_records();
  const ModelDeclarations& declared = s.objective->model().declarations();
  const Eigen::VectorXd phi = IndividualValues(s, point, m.eta);
  std::vector<double> dsigma(static_cast<size_t>(std::max<Eigen::Index>(point.sigma.size(), 1)));
  for (Eigen::Index j = 0; j < n; ++j) {
    PopulationRow r;
    r.id = id;
    r.subject = subject;
    r.time = times[static_cast<size_t>(j)];
    r.dv = s.objective->observations()(j);
    r.dvid = outputs[static_cast<size_t>(j)];
    r.censored = s.censoring.size() == n ? s.censoring(j) : 0;
    r.pred = have0 ? c0.yhat(j) : nan;
    r.ipred = c.yhat(j);
    r.res = have0 && r.censored == 0 ? s.y(j) - c0.f(j) : nan;
    r.wres = wres(j);
    r.cwres = cwres(j);
    double v = 0, dv = 0;
    OutputVariance(*point.error, s.outputs(j), c.yhat(j), point.sigma.data(), &v, &dv, dsigma.data());
    r.iwres = r.censored == 0 ? (s.y(j) - c.f(j)) / std::sqrt(v) : nan;
    if (r.censored == 0) iwres->push_back(r.iwres);  // ε-shrinkage over values only
    if (declared.pk_values) r.definitions = declared.pk_values(s.objective->RecordParameters(phi, records[static_cast<size_t>(j)]));
    rows->push_back(r);
  }
}

// What the summary says of Laplace's H at the estimate: exact, or differenced for some subjects.
std::string LaplaceHessian(const PopulationEngine& engine, const std::vector<SubjectMode>& modes) {
  if (engine.method() != PopulationMethod::kLaplace) return "";
  int differenced = 0, found = 0;
  std::string why;
  for (size_t i = 0; i < modes.size(); ++i) {
    if (!engine.included()[i] || !modes[i].ok) continue;
    ++found;
    if (modes[i].hessian_differenced.empty()) continue;
    if (why.empty()) why = modes[i].hessian_differenced;
    ++differenced;
  }
  if (differenced == 0) return "exact, from the second-order sensitivities";
  return differenced == found ? "central differences of the exact ∇l (" + why + ")"
                              : "central differences of the exact ∇l for " + std::to_string(differenced) + " of " +
                                    std::to_string(found) + " subjects (" + why + "), exact for the others";
}

}  // namespace

void PopulationDiagnostics(const PopulationEngine& engine, const PopulationParameters& p,
                           const std::vector<SubjectMode>& modes, PopulationSummary* summary) {
  const auto& d = engine.problem().impl();
  const PopulationPoint point = PopulationPoint::Make(p, *d.options.error_model, engine.method());
  const std::vector<PopulationSubject> failed = summary->subjects;
  summary->subjects.clear();
  summary->rows.clear();
  std::vector<double> iwres;
  const Eigen::Index q = p.omega.rows();
  std::vector<std::vector<double>> etas(static_cast<size_t>(q));
  summary->conditional_hessian = LaplaceHessian(engine, modes);
  for (size_t i = 0; i < d.subjects.size(); ++i) {
    const double id = d.data->subjects[i].id;
    if (!engine.included()[i]) {
      for (const PopulationSubject& f : failed) {
        if (f.subject == static_cast<int>(i)) summary->subjects.push_back(f);
      }
      continue;
    }
    const SubjectMode& m = modes[i];
    PopulationSubject s;
    s.id = id;
    s.subject = static_cast<int>(i);
    s.ok = m.ok;
    s.message = m.message;
    s.eta = m.eta;
    s.ofv = m.ofv;
    s.eta_covariance = EtaCovariance(m);
    DescribeIndividual(d.subjects[i], point, m.eta, &s);
    summary->subjects.push_back(s);
    if (!m.ok) continue;
    for (Eigen::Index k = 0; m.eta_estimated && k < q; ++k) etas[static_cast<size_t>(k)].push_back(m.eta(k));
    SubjectRows(d.subjects[i], point, p.omega, id, static_cast<int>(i), m, &summary->rows, &iwres);
  }
  summary->eta_shrinkage_sd.resize(q);
  summary->eta_shrinkage_variance.resize(q);
  for (Eigen::Index k = 0; k < q; ++k) {
    const double ratio = SampleSd(etas[static_cast<size_t>(k)]) / std::sqrt(p.omega(k, k));
    summary->eta_shrinkage_sd(k) = 1 - ratio;
    summary->eta_shrinkage_variance(k) = 1 - ratio * ratio;
  }
  const double sd = SampleSd(iwres);
  summary->epsilon_shrinkage_sd = 1 - sd;
  summary->epsilon_shrinkage_variance = 1 - sd * sd;
  // Each output's own ε (an error model per output): NONMEM's EPSSHRINK per EPS.
  summary->epsilon_shrinkage_sd_by_output.clear();
  summary->epsilon_shrinkage_variance_by_output.clear();
  for (int k = 1; k <= d.options.error_model->num_outputs(); ++k) {
    std::vector<double> own;
    for (const PopulationRow& r : summary->rows) {
      if (r.dvid == k && r.censored == 0) own.push_back(r.iwres);
    }
    const double sd_k = own.size() > 1 ? SampleSd(own) : std::numeric_limits<double>::quiet_NaN();
    summary->epsilon_shrinkage_sd_by_output.push_back(1 - sd_k);
    summary->epsilon_shrinkage_variance_by_output.push_back(1 - sd_k * sd_k);
  }
}

}  // namespace internal
}  // namespace pk
