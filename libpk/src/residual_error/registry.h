// The registered residual-error models (not installed): one factory per file of this folder.
#ifndef PK_SRC_RESIDUAL_ERROR_REGISTRY_H_
#define PK_SRC_RESIDUAL_ERROR_REGISTRY_H_

#include <memory>

#include <Eigen/Core>

#include "pk/residual_error.h"

namespace pk {
namespace internal {

std::shared_ptr<const ResidualErrorModel> MakeLeastSquares();
std::shared_ptr<const ResidualErrorModel> MakeAdditiveError();
std::shared_ptr<const ResidualErrorModel> MakeProportionalError();
std::shared_ptr<const ResidualErrorModel> MakeCombinedError();
std::shared_ptr<const ResidualErrorModel> MakeExponentialError();

/// A starting additive σ: a tenth of the mean |DV| of the samples (1 without samples, or when all are 0).
double AdditiveStart(const Eigen::VectorXd& dv);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_RESIDUAL_ERROR_REGISTRY_H_
