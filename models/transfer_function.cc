// tf1..tf4: y = B(s)/A(s)·u with A(s) = sⁿ + a₁sⁿ⁻¹ + … + aₙ and
// B(s) = b₁sⁿ⁻¹ + … + bₙ, in the companion realisation of the seed's 6.1–6.2,
// with the states ordered so that the input enters X1 (CMT 1, as in datasets):
//   x₁' = −a₁x₁ − a₂x₂ − … − aₙxₙ + u,   x_k' = x_{k−1} (k ≥ 2),
//   y = b₁x₁ + … + bₙxₙ,
// i.e. x_k = s^{n−k}/A(s)·u. Every observation is y.
#include "catalogue_models.h"
#include <cmath>

#include "pk/conversion.h"

namespace pk {
namespace models {

std::shared_ptr<const LinearModel> TransferFunction(int n) {
  std::vector<std::string> params, states;
  for (int i = 1; i <= n; ++i) params.push_back("A" + std::to_string(i));
  for (int i = 1; i <= n; ++i) params.push_back("B" + std::to_string(i));
  for (int i = 1; i <= n; ++i) states.push_back("X" + std::to_string(i));
  std::vector<LinearTerm> a_terms;
  for (int i = 0; i < n; ++i) a_terms.push_back({0, i, -1.0, i, -1});  // −a_{i+1} x_{i+1}
  for (int k = 1; k < n; ++k) a_terms.push_back({k, k - 1, 1.0, -1, -1});
  std::vector<LinearTerm> output;
  for (int i = 0; i < n; ++i) output.push_back({0, i, 1.0, n + i, -1});  // b_{i+1} x_{i+1}
  // Defaults: rates 0.6, 0.15, … per hour, each phase 0.04 concentration per unit dose.
  Exponentials e;
  for (int k = 0; k < n; ++k) {
    e.rate.push_back(0.6 * std::pow(0.25, k));
    e.amplitude.push_back(0.04);
  }
  std::vector<double> coeffs;
  ExponentialsToTransferFunction(e, &coeffs);
  Eigen::VectorXd defaults = Eigen::Map<Eigen::VectorXd>(coeffs.data(), 2 * n);
  return LinearModel::FromTerms("tf" + std::to_string(n),
                                "transfer function of order " + std::to_string(n) + " (companion form)", states,
                                params, defaults, 1, 1, a_terms, std::vector<std::vector<LinearTerm>>(n, output), n,
                                {InitialStructure::Kind::kTransferFunction, n, false, params, "", ""});
}

}  // namespace models
}  // namespace pk
