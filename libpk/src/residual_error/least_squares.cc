// Least squares: V = ½ Σ W_k (y_k − ŷ_k)², weights known (uniform, 1/DV², 1/DV or a data
// column); no σ, and the residual variance is profiled out for standard errors and −2LL.
#include "pk/residual_error.h"
#include "residual_error/registry.h"

namespace pk {
namespace internal {
namespace {

class LeastSquaresError final : public ResidualErrorModel {
 public:
  const char* name() const override { return "least-squares"; }
  bool is_likelihood() const override { return false; }
};

}  // namespace

std::shared_ptr<const ResidualErrorModel> MakeLeastSquares() { return std::make_shared<LeastSquaresError>(); }

}  // namespace internal
}  // namespace pk
