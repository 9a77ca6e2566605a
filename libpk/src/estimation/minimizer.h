// The minimisers a fit can use (not installed), one per file of this folder, named in
// minimizers.cc: adding one is a file and a line there (docs/architecture.md).
#ifndef PK_SRC_ESTIMATION_MINIMIZER_H_
#define PK_SRC_ESTIMATION_MINIMIZER_H_

#include <memory>
#include <string>

#include <Eigen/Core>

#include "estimation/problem.h"
#include "pk/fit.h"

namespace pk {
namespace internal {

class Minimizer {
 public:
  virtual ~Minimizer() = default;
  /// Minimises from φ0 within options' limits and tolerances. Failure is reported, not thrown.
  virtual RunResult Minimize(Problem* problem, const Eigen::VectorXd& phi0, const FitOptions& options) const = 0;
  /// Works on the residual vector: least squares only, and needs at least as many residuals
  /// as parameters.
  virtual bool needs_residuals() const { return false; }
  /// Asks for the Jacobian or information matrix (not the adjoint route's gradient alone).
  virtual bool needs_jacobian() const { return false; }
};

/// The minimiser FitOptions::optimizer names ("lm", "bfgs", "newton", "nlopt:ALGORITHM"), or
/// null with `why`.
std::unique_ptr<Minimizer> MakeMinimizer(const std::string& name, std::string* why);

/// NLopt from φ0 with `algorithm` (nlopt_minimizer.cc; BFGS is LD_LBFGS).
RunResult RunNlopt(Problem* pb, const std::string& algorithm, const Eigen::VectorXd& phi0, const FitOptions& o);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_ESTIMATION_MINIMIZER_H_
