// Helpers for the residual-error models of this folder (not installed). Each file defines one
// model and its factory; registry.cc names them.
#ifndef PK_SRC_RESIDUAL_ERROR_REGISTRY_H_
#define PK_SRC_RESIDUAL_ERROR_REGISTRY_H_

#include <memory>

#include <Eigen/Core>

#include "pk/residual_error.h"

namespace pk {
namespace internal {

/// A starting additive σ: a tenth of the mean |DV| of the samples (1 without samples, or when all are 0).
double AdditiveStart(const Eigen::VectorXd& dv);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_RESIDUAL_ERROR_REGISTRY_H_
