#include "estimation/covariance.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <vector>

#include <Eigen/LU>

#include "identifiability.h"
#include "internal_text.h"

namespace pk {
namespace internal {
namespace {

using Need = Objective::Need;

constexpr double kCollapse = 1e-6;

// Which σ of the error model parameter `i` is, or -1.
int SigmaOf(const Objective& objective, int i) {
  const std::vector<int> sigma = objective.sigma_indices();
  const auto it = std::find(sigma.begin(), sigma.end(), i);
  return it == sigma.end() ? -1 : static_cast<int>(it - sigma.begin());
}

// The largest |DV| of the samples σ_q's output measures (every sample for a single error model).
double SigmaScale(const Objective& objective, int q) {
  const ResidualErrorModel& error = objective.error_model();
  const Eigen::VectorXd& y = objective.observations();
  const std::vector<int> outputs = objective.sample_outputs();
  double scale = 0;
  for (Eigen::Index k = 0; k < y.size(); ++k) {
    int first = 0;
    const ResidualErrorModel& e = error.ForOutput(outputs[static_cast<size_t>(k)], &first);
    if (q >= first && q < first + static_cast<int>(e.sigma_names().size())) scale = std::max(scale, std::fabs(y(k)));
  }
  return scale;
}

// Whether parameter `i` is a σ gone to 0: below 1e-6 of its output's largest |DV| for a σ in the
// units of DV, below 1e-6 for a relative one.
bool SigmaAtZero(const Objective& objective, const Eigen::VectorXd& values, int i) {
  const int q = i < 0 ? -1 : SigmaOf(objective, i);
  if (q < 0) return false;
  if (!objective.error_model().sigma_in_dv_units(q)) return std::fabs(values(i)) < kCollapse;
  if (objective.observations().size() == 0) return false;
  return std::fabs(values(i)) < kCollapse * SigmaScale(objective, q);
}

// The σ of each output's error model (one group for a single model), as positions among the σ.
std::vector<std::vector<int>> SigmaGroups(const ResidualErrorModel& error) {
  std::vector<std::vector<int>> groups;
  for (int k = 1; k <= std::max(1, error.num_outputs()); ++k) {
    int first = 0;
    const ResidualErrorModel& e = error.ForOutput(k, &first);
    groups.emplace_back();
    for (int j = 0; j < static_cast<int>(e.sigma_names().size()); ++j) groups.back().push_back(first + j);
  }
  return groups;
}

// What collapsed, or "" when nothing did. When every σ of an output's error model fell to 0: that
// they fell. Otherwise some did, and a sample predicted as 0 may have only those in its variance
// (a combined error's SIGMA_ADD alone may go to 0 at a finite likelihood: data with a constant CV, a
// boundary estimate; a sample predicted as 0 then has a σ of 0). Sets `at` to that sample and
// `alone` to the name of the σ that was all its variance.
std::string Collapse(const Objective& objective, const Eigen::VectorXd& values, const Eigen::VectorXd& yhat, int* at,
                     std::string* alone) {
  const std::vector<int> sigma = objective.sigma_indices();
  const Eigen::VectorXd& y = objective.observations();
  const auto& names = objective.parameter_names();
  const auto of_dv = [&](int q, double v) {
    return objective.error_model().sigma_in_dv_units(q)
               ? ", " + Num(v / SigmaScale(objective, q), "%.2g") + " of the largest DV"
               : "";
  };
  std::vector<char> gone(sigma.size(), 0);
  bool any = false;
  for (size_t q = 0; q < sigma.size(); ++q) any |= (gone[q] = SigmaAtZero(objective, values, sigma[q]));
  if (!any) return "";
  for (const std::vector<int>& group : SigmaGroups(objective.error_model())) {
    bool all = !group.empty();
    for (int q : group) all = all && gone[static_cast<size_t>(q)];
    if (!all) continue;
    std::string what;
    for (size_t g = 0; g < group.size(); ++g) {
      const int q = group[g];
      const double v = std::fabs(values(sigma[static_cast<size_t>(q)]));
      what += (g == 0 ? names[sigma[static_cast<size_t>(q)]] + " fell to " : " and " + names[sigma[static_cast<size_t>(q)]] + " to ") +
              Num(v, "%.3g") + (group.size() == 1 ? of_dv(q, v) : "");
    }
    return what;
  }
  // The variance of a prediction of 0 with the fallen σ at 0: when it vanishes, a sample predicted as 0
  // has a σ of 0. (A censored sample predicted as 0 is not one: its probability goes to 1, not its
  // density to ∞.)
  std::vector<double> rest(sigma.size()), dv_dsigma(sigma.size());
  for (size_t q = 0; q < sigma.size(); ++q) rest[q] = gone[q] ? 0.0 : values(sigma[q]);
  const std::vector<int> outputs = objective.sample_outputs();
  // Zero to rounding relative to the largest prediction of the sample's own output, as the loss takes it.
  std::map<int, double> largest;
  for (int k = 0; k < yhat.size(); ++k) {
    double& l = largest[outputs[static_cast<size_t>(k)]];
    l = std::max(l, std::fabs(yhat(k)));
  }
  for (int k = 0; k < y.size() && *at < 0; ++k) {
    const double zero = kZeroPredictionLevel * largest[outputs[static_cast<size_t>(k)]];
    if (!(std::fabs(yhat(k)) <= zero) || objective.censoring()(k) != 0) continue;
    double v0, dv0;
    OutputVariance(objective.error_model(), outputs[static_cast<size_t>(k)], 0.0, rest.data(), &v0, &dv0,
                   dv_dsigma.data());
    if (!(v0 > 0)) *at = k;
  }
  if (*at < 0) return "";
  int q = 0;
  while (!gone[static_cast<size_t>(q)]) ++q;
  const double v = std::fabs(values(sigma[static_cast<size_t>(q)]));
  *alone = names[sigma[static_cast<size_t>(q)]];
  return "the sample at TIME " + Num(objective.sample_times()[*at]) + " (DV " + Num(y(*at)) + ", prediction " +
         Num(yhat(*at), "%.3g") + ") has a σ of " + Num(v, "%.3g") + of_dv(q, v);
}

}  // namespace

// Optimisers stop wherever their tests happen to hold when the likelihood has no maximum, at σ of
// 1e-6 to 1e-150 and objectives of −20 to −500, and would report convergence. That happens when
// the curve can pass through every sample (typically no more samples than model parameters), or
// when a combined error's additive part is a sample's whole σ_k because the sample is predicted
// as 0 (a DV of 0 at an oral dose's time). A σ below 1e-6 of the largest |DV| (in DV units) or
// below 1e-6 (relative), far below any assay's precision, is taken as collapsed; the prediction
// level is the loss's own (kZeroPredictionLevel).
bool CollapsedSigma(const Objective& objective, const Eigen::VectorXd& values, const Eigen::VectorXd& yhat,
                    int structural, std::string* why) {
  const int nobs = static_cast<int>(objective.observations().size());
  if (nobs == 0 || yhat.size() != nobs || objective.sigma_indices().empty()) return false;
  int at = -1;
  std::string alone;
  const std::string what = Collapse(objective, values, yhat, &at, &alone);
  if (what.empty()) return false;
  std::string cause;
  if (nobs <= structural) {
    cause = "with " + std::to_string(nobs) + " samples for " + std::to_string(structural) +
            " model parameters the curve passes through every sample; fix some parameters or σ, or fit the population";
  } else if (at >= 0) {
    cause = "its prediction is 0, so its σ is " + alone + " alone; give it MDV=1, or fix " + alone;
  } else {
    cause = "the curve passes through the samples; fix σ, or use least squares";
  }
  *why = "the likelihood has no maximum: " + what + " (" + cause + ")";
  return true;
}

namespace {

// The covariance from the information matrix (least squares: scaled by σ̂² = 2V/(N − p)). A σ gone
// to 0 at a finite likelihood (one part of a combined error: a boundary estimate) carries no
// information, since ∂v_k/∂log σ ∝ σ² → 0. The others' covariance is then the one with that σ
// held at 0, which is the covariance of the fit with the simpler error model.
void Covariance(Problem* pb, const Objective::Evaluation& ev, const Eigen::VectorXd& phi, bool log_scale,
                FitSummary* summary) {
  const Objective& objective = pb->objective();
  const bool ml = objective.error_model().is_likelihood();
  const int n = pb->n(), nobs = objective.num_samples();
  std::vector<int> keep;
  std::vector<std::string> at_zero;
  for (int j = 0; j < n; ++j) {
    if (ml && SigmaAtZero(objective, summary->values, pb->free()[j])) {
      at_zero.push_back(objective.parameter_names()[pb->free()[j]]);
      for (ParameterEstimate& est : summary->estimates) est.at_bound = est.at_bound || est.name == at_zero.back();
    } else {
      keep.push_back(j);
    }
  }
  const int nk = static_cast<int>(keep.size());
  const Eigen::MatrixXd info = ev.information(keep, keep);
  Eigen::FullPivLU<Eigen::MatrixXd> lu;
  lu.setThreshold(1e-12);
  const bool finite = info.allFinite();
  if (finite) lu.compute(info);
  if (!finite) {
    summary->covariance_message = "the information matrix is not finite at the estimate";
    return;
  }
  if (nk == 0 || lu.rank() < nk) {
    std::vector<std::string> kept_names;
    Eigen::VectorXd ds_dphi(nk);
    for (int a = 0; a < nk; ++a) {
      kept_names.push_back(summary->estimated[keep[a]]);
      ds_dphi(a) = pb->transform(keep[a]).DsDphi(phi(keep[a]));
    }
    const std::string what = Unidentified(info, nk - static_cast<int>(lu.rank()), kept_names, ds_dphi, log_scale);
    summary->covariance_message = "the information matrix is singular: " +
                                  (what.empty() ? std::string("some parameters are not identifiable") : what);
    summary->identifiable = false;
    return;
  }
  Eigen::MatrixXd kept = lu.inverse();
  if (!ml) kept *= 2 * (0.5 * ev.residuals.head(nobs).squaredNorm()) / (nobs - n);
  const Eigen::VectorXd d = pb->Dtheta(phi);
  summary->covariance = Eigen::MatrixXd::Constant(n, n, NAN);
  summary->correlation = Eigen::MatrixXd::Constant(n, n, NAN);
  Eigen::VectorXd sd = Eigen::VectorXd::Constant(n, NAN);
  for (int a = 0; a < nk; ++a) {
    for (int b = 0; b < nk; ++b) summary->covariance(keep[a], keep[b]) = d(keep[a]) * kept(a, b) * d(keep[b]);
    sd(keep[a]) = std::sqrt(std::max(0.0, summary->covariance(keep[a], keep[a])));
  }
  for (int a : keep) {
    for (int b : keep) summary->correlation(a, b) = summary->covariance(a, b) / (sd(a) * sd(b));
  }
  int k = 0;
  for (ParameterEstimate& est : summary->estimates) {
    if (est.fixed) continue;
    est.se = sd(k++);
    est.rse_pct = 100 * est.se / std::fabs(est.estimate);
  }
  if (!at_zero.empty()) {
    summary->covariance_message = Join(at_zero, " and ") +
                                  " went to 0, the edge of its range: it has no SE, and the other SEs are those "
                                  "of a fit without it";
  }
}

// −2LL: exact for maximum likelihood; for least squares the Gaussian likelihood with the residual
// variance profiled out (weights known up to scale), which counts as one more parameter.
void InformationCriteria(const Objective& objective, const Objective::Evaluation& ev, double value, int n,
                         FitSummary* summary) {
  const int nobs = objective.num_samples();
  double m2ll = 0;
  int k = n;
  if (objective.error_model().is_likelihood()) {
    m2ll = 2 * value;
    // Censored samples enter by a probability (Beal's M3), without the Gaussian constant.
    summary->ofv = m2ll - (nobs - objective.num_censored()) * std::log(2 * M_PI);
  } else {
    const double rss = ev.residuals.head(nobs).squaredNorm();
    summary->rss = rss;
    double sum_log_w = 0;
    for (int j = 0; j < nobs; ++j) {
      if (objective.weights()(j) > 0) sum_log_w += std::log(objective.weights()(j));
    }
    m2ll = nobs * (std::log(2 * M_PI * rss / nobs) + 1) - sum_log_w;
    k = n + 1;
  }
  summary->minus2ll = m2ll;
  summary->aic = m2ll + 2 * k;
  summary->bic = m2ll + k * std::log(static_cast<double>(nobs));
}

}  // namespace

void CovarianceStep(Problem* pb, const Eigen::VectorXd& phi, bool log_scale, FitSummary* summary) {
  const Objective& objective = pb->objective();
  const Objective::Evaluation& ev = pb->Eval(phi, Need::kJacobian);
  // The standard errors need the Jacobian; say so when that route differs from the one the optimiser used.
  if (summary->gradient == "none") {
    summary->gradient = pb->route();
  } else if (pb->route() != summary->gradient) {
    summary->gradient += " (SE: " + pb->route() + ")";
  }
  if (!ev.ok) {
    summary->covariance_message = "the Jacobian could not be evaluated at the estimate: " + ev.message;
  } else if (!objective.error_model().is_likelihood() && objective.num_samples() <= pb->n()) {
    summary->covariance_message = "no degrees of freedom left for the residual variance";
  } else {
    Covariance(pb, ev, phi, log_scale, summary);
  }
  if (ev.ok) InformationCriteria(objective, ev, summary->objective, pb->n(), summary);
}

}  // namespace internal
}  // namespace pk
