// The additive error: y = ŷ + ε, ε ~ N(0, SIGMA_ADD²) (NONMEM's Y = F + EPS(1)).
#include <cmath>

#include "pk/residual_error.h"
#include "residual_error/registry.h"

namespace pk {
namespace internal {
namespace {

class Additive final : public ResidualErrorModel {
 public:
  const char* name() const override { return "additive"; }
  std::vector<std::string> sigma_names() const override { return {kSigmaAdd}; }
  int num_sigma() const override { return 1; }
  double DefaultSigma(int, const Eigen::VectorXd& dv) const override { return AdditiveStart(dv); }
  bool sigma_in_dv_units(int) const override { return true; }
  void Variance(double, const double* sigma, double* v, double* dv_dyhat, double* dv_dsigma) const override {
    *v = sigma[0] * sigma[0];
    *dv_dyhat = 0;
    dv_dsigma[0] = 2 * sigma[0];
  }
  double StandardDeviation(double, const double* sigma) const override { return std::fabs(sigma[0]); }
};

}  // namespace

std::shared_ptr<const ResidualErrorModel> MakeAdditiveError() { return std::make_shared<Additive>(); }

}  // namespace internal
}  // namespace pk
