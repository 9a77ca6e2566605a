// PopulationSummary's reports: NONMEM-like tables of θ, Ω and σ with SE and RSE%, shrinkage
// and the objective.
#include <algorithm>
#include <cmath>
#include <sstream>

#include "internal_text.h"
#include "pk/output.h"
#include "pk/population.h"

namespace pk {
namespace {

std::string MethodName(PopulationMethod m) {
  switch (m) {
    case PopulationMethod::kFo: return "FO";
    case PopulationMethod::kFoce: return "FOCE";
    case PopulationMethod::kFocei: return "FOCEI";
    case PopulationMethod::kLaplace: return "Laplace";
  }
  return "?";
}

// The shrinkages of η (each) and ε, SD form and variance form.
std::string ShrinkageTable(const PopulationSummary& s) {
  std::ostringstream out;
  out << "  shrinkage (SD form; variance form in parentheses)\n";
  for (Eigen::Index k = 0; k < s.eta_shrinkage_sd.size(); ++k) {
    const auto at = static_cast<size_t>(k);
    std::string name = at < s.eta_names.size() ? "η(" + s.eta_names[at] + ")" : "η" + std::to_string(k + 1);
    // Padded to 12 bytes with at least one space after it (η takes two bytes).
    name.resize(std::max<size_t>(name.size() + 1, 12), ' ');
    out << "    " << name << internal::Num(100 * s.eta_shrinkage_sd(k), "%.1f") << "%  ("
        << internal::Num(100 * s.eta_shrinkage_variance(k), "%.1f") << "%)\n";
  }
  out << "    ε         " << internal::Num(100 * s.epsilon_shrinkage_sd, "%.1f") << "%  ("
      << internal::Num(100 * s.epsilon_shrinkage_variance, "%.1f") << "%)"
      << (s.epsilon_shrinkage_sd_by_output.empty() ? "" : "  (every output)") << "\n";
  for (size_t k = 0; k < s.epsilon_shrinkage_sd_by_output.size(); ++k) {
    std::string name = "ε(DVID " + std::to_string(k + 1) + ")";  // ε takes two bytes, η too
    name.resize(std::max<size_t>(name.size() + 2, 12), ' ');
    out << "    " << name << internal::Num(100 * s.epsilon_shrinkage_sd_by_output[k], "%.1f") << "%  ("
        << internal::Num(100 * s.epsilon_shrinkage_variance_by_output[k], "%.1f") << "%)\n";
  }
  return out.str();
}

}  // namespace

std::vector<std::string> PopulationSummary::CovarianceWarnings() const {
  constexpr double kHighCorrelation = 0.95, kHighCondition = 1000;
  std::vector<std::string> out;
  if (correlation.size() == 0) return out;
  std::vector<std::string> names;  // the estimated ones, the correlation matrix's order
  for (const PopulationEstimate& e : estimates) {
    if (!e.fixed) names.push_back(e.name);
  }
  if (static_cast<Eigen::Index>(names.size()) != correlation.rows()) return out;
  for (Eigen::Index a = 0; a < correlation.rows(); ++a) {
    for (Eigen::Index b = 0; b < a; ++b) {
      const double r = correlation(a, b);
      if (!(std::abs(r) > kHighCorrelation)) continue;
      out.push_back(names[static_cast<size_t>(b)] + " and " + names[static_cast<size_t>(a)] + " are correlated " +
                    internal::Num(r, "%.3f") + " (|r| > 0.95): the data hardly separate them");
    }
  }
  if (std::isinf(condition_number)) {
    out.push_back("the correlation matrix is singular (condition number ∞): some combination of the estimates is "
                  "not determined, as when there are no more subjects than estimated parameters");
  } else if (condition_number > kHighCondition) {
    out.push_back("the condition number " + internal::Num(condition_number, "%.4g") +
                  " exceeds 1000: the estimates are ill-determined in some direction");
  }
  return out;
}

std::string PopulationSummary::BriefReport() const {
  std::ostringstream out;
  out << MethodName(method) << ": OFV " << internal::Num(ofv, "%.6f") << " (initial "
      << internal::Num(initial_ofv, "%.6f") << "), " << evaluations << " evaluations, "
      << internal::Num(seconds, "%.3g") << " s, " << (converged ? "converged" : "not converged") << " ("
      << message << ")";
  if (failed_subjects > 0) out << "; " << failed_subjects << " subject(s) left out";
  return out.str();
}

std::string PopulationSummary::FullReport() const {
  using internal::Cell;
  std::ostringstream out;
  out << BriefReport() << "\n\n";
  out << "  parameter            estimate          SE      RSE%\n";
  for (const PopulationEstimate& e : estimates) {
    std::string name = e.name;
    name.resize(std::max<size_t>(name.size(), 18), ' ');
    out << "  " << name << Cell(e.estimate, "%.6g", 12) << Cell(e.se, "%.4g", 12) << Cell(e.rse_pct, "%.1f", 10);
    if (e.same) {
      out << "  SAME";
    } else if (e.fixed) {
      out << "  FIX";
    }
    if (e.at_boundary) out << "  (near a boundary)";
    out << "\n";
  }
  // NONMEM's $SIGMA holds variances: σ² with SE(σ²) = 2σ·SE(σ) (the sandwich transforms exactly by
  // the Jacobian at the optimum), RSE doubled.
  for (const PopulationEstimate& e : estimates) {
    if (e.name.rfind("SIGMA_", 0) != 0) continue;
    std::string name = e.name + "²";
    name.resize(std::max<size_t>(name.size(), 19), ' ');
    out << "  " << name << Cell(e.estimate * e.estimate, "%.6g", 12) << Cell(2 * e.estimate * e.se, "%.4g", 12)
        << Cell(2 * e.rse_pct, "%.1f", 10) << "  (as NONMEM's $SIGMA, a variance)\n";
  }
  if (!covariance_message.empty()) out << "  no standard errors: " << covariance_message << "\n";
  if (covariance.size()) {
    out << "  covariance: " << Describe(covariance_matrix) << "; condition number "
        << internal::Num(condition_number, "%.4g") << "\n";
    if (!covariance_derivatives.empty()) out << "  (" << covariance_derivatives << ")\n";
    for (const std::string& w : CovarianceWarnings()) out << "  warning: " << w << "\n";
  }
  if (eta_shrinkage_sd.size() > 0) {
    out << "\n" << ShrinkageTable(*this);
  } else {
    out << "\n  no tables: η̂, residuals and shrinkage not formed (PopulationOptions::tables false, or no OFV at "
           "the estimate)\n";
  }
  for (const PopulationSubject& s : subjects) {
    if (!s.ok) out << "  subject " << FormatNumber(s.id) << ": " << s.message << "\n";
  }
  out << "  outer gradient: " << gradient << "\n";
  if (!conditional_hessian.empty()) out << "  Laplace's H: " << conditional_hessian << "\n";
  if (!eta_estimates.empty()) out << "  η̂: " << eta_estimates << "\n";
  if (processes > 1) out << "  subjects split across " << processes << " processes\n";
  return out.str();
}

}  // namespace pk
