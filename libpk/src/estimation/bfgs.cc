// BFGS: NLopt's limited-memory BFGS (LD_LBFGS), in the moving box of nlopt_minimizer.cc.
#include "estimation/minimizer.h"

namespace pk {
namespace internal {
namespace {

class Bfgs final : public Minimizer {
 public:
  RunResult Minimize(Problem* problem, const Eigen::VectorXd& phi0, const FitOptions& options) const override {
    return RunNlopt(problem, "LD_LBFGS", phi0, options);
  }
};

}  // namespace

std::unique_ptr<Minimizer> MakeBfgs(const std::string&, std::string*) { return std::make_unique<Bfgs>(); }

}  // namespace internal
}  // namespace pk
