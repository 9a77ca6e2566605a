// What a fit reports at its estimate (not installed): whether the likelihood collapsed, the
// covariance of the estimates with SEs and correlations, and −2LL, AIC and BIC.
#ifndef PK_SRC_ESTIMATION_COVARIANCE_H_
#define PK_SRC_ESTIMATION_COVARIANCE_H_

#include <string>

#include <Eigen/Core>

#include "estimation/problem.h"
#include "pk/fit.h"

namespace pk {
namespace internal {

/// Maximum likelihood has no maximum when a sample's variance can shrink to 0 together with
/// its residual: −½ log v_k → +∞ (see covariance.cc). Returns true with `why` when a σ has
/// collapsed so. `yhat` are the predictions at `values`; `structural` counts the estimated
/// model parameters.
bool CollapsedSigma(const Objective& objective, const Eigen::VectorXd& values, const Eigen::VectorXd& yhat,
                    int structural, std::string* why);

/// The covariance step at φ (the best run's end): the covariance, correlations, SEs and RSE%,
/// the reason when there are none, and −2LL, AIC and BIC, into `summary`.
void CovarianceStep(Problem* pb, const Eigen::VectorXd& phi, bool log_scale, FitSummary* summary);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_ESTIMATION_COVARIANCE_H_
