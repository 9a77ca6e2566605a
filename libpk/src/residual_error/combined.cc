// The combined error: v = SIGMA_ADD² + (SIGMA_PROP·ŷ)² (NONMEM's Y = F + F·EPS(1) + EPS(2)).
#include "pk/residual_error.h"
#include "residual_error/registry.h"

namespace pk {
namespace internal {
namespace {

class Combined final : public ResidualErrorModel {
 public:
  const char* name() const override { return "combined"; }
  std::vector<std::string> sigma_names() const override { return {kSigmaAdd, kSigmaProp}; }
  int num_sigma() const override { return 2; }
  double DefaultSigma(int j, const Eigen::VectorXd& dv) const override { return j == 0 ? AdditiveStart(dv) : 0.1; }
  bool sigma_in_dv_units(int j) const override { return j == 0; }
  void Variance(double yhat, const double* sigma, double* v, double* dv_dyhat, double* dv_dsigma) const override {
    const double a = sigma[0], b = sigma[1];
    *v = a * a + b * b * yhat * yhat;
    *dv_dyhat = 2 * b * b * yhat;
    dv_dsigma[0] = 2 * a;
    dv_dsigma[1] = 2 * b * yhat * yhat;
  }
};

}  // namespace

std::shared_ptr<const ResidualErrorModel> MakeCombinedError() { return std::make_shared<Combined>(); }

}  // namespace internal
}  // namespace pk
