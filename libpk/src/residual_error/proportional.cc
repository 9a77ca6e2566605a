// The proportional error: y = ŷ(1 + ε), ε ~ N(0, SIGMA_PROP²) (NONMEM's Y = F + F·EPS(1)).
#include "pk/residual_error.h"
#include "residual_error/registry.h"

namespace pk {
namespace internal {
namespace {

class Proportional final : public ResidualErrorModel {
 public:
  const char* name() const override { return "proportional"; }
  std::vector<std::string> sigma_names() const override { return {kSigmaProp}; }
  int num_sigma() const override { return 1; }
  double DefaultSigma(int, const Eigen::VectorXd&) const override { return 0.1; }
  void Variance(double yhat, const double* sigma, double* v, double* dv_dyhat, double* dv_dsigma) const override {
    const double b = sigma[0];
    *v = b * b * yhat * yhat;
    *dv_dyhat = 2 * b * b * yhat;
    dv_dsigma[0] = 2 * b * yhat * yhat;
  }
};

}  // namespace

std::shared_ptr<const ResidualErrorModel> MakeProportionalError() { return std::make_shared<Proportional>(); }

}  // namespace internal
}  // namespace pk
