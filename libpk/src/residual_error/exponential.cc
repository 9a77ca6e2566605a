// The exponential error: y = ŷ·e^ε, ε ~ N(0, SIGMA_LOG²), fitted as log y against log ŷ
// (NONMEM's log-transform-both-sides). DV must be positive, and so must the predictions
// at samples.
#include <cmath>

#include "pk/residual_error.h"
#include "residual_error/registry.h"

namespace pk {
namespace internal {
namespace {

class Exponential final : public ResidualErrorModel {
 public:
  const char* name() const override { return "exponential"; }
  bool log_transformed() const override { return true; }
  std::vector<std::string> sigma_names() const override { return {kSigmaLog}; }
  int num_sigma() const override { return 1; }
  double DefaultSigma(int, const Eigen::VectorXd&) const override { return 0.2; }
  void Variance(double, const double* sigma, double* v, double* dv_dyhat, double* dv_dsigma) const override {
    *v = sigma[0] * sigma[0];
    *dv_dyhat = 0;
    dv_dsigma[0] = 2 * sigma[0];
  }
  double StandardDeviation(double, const double* sigma) const override { return std::fabs(sigma[0]); }
};

}  // namespace

std::shared_ptr<const ResidualErrorModel> MakeExponentialError() { return std::make_shared<Exponential>(); }

}  // namespace internal
}  // namespace pk
