// libpk: residual-error models, the distribution of an observation y about its prediction ŷ.
//
// Least squares (the default) is no distribution: V = ½ Σ_k W_k (y_k − ŷ_k)² with known weights.
// Every other model is a likelihood: a compared quantity T(y) (y itself, or log y for the
// exponential error) is normal about T(ŷ) with a variance v(ŷ, σ) that the model defines,
// and its σ parameters are appended to the model's parameters and estimated jointly:
//
//   additive       v = SIGMA_ADD²                         NONMEM's Y = F + EPS(1)
//   proportional   v = (SIGMA_PROP·ŷ)²                    Y = F·(1 + EPS(1))
//   combined       v = SIGMA_ADD² + (SIGMA_PROP·ŷ)²       Y = F·(1 + EPS(1)) + EPS(2)
//   exponential    log y ~ N(log ŷ, SIGMA_LOG²)           log-transform-both-sides
//
// The per-sample loss (ℓ_k = ½[log 2πv + (T(y) − T(ŷ))²/v], plus log y under the log
// transform, and Beal's M3 for censored samples) is written once, in the library, from
// what a model declares here. Adding an error model is one file that implements this
// interface, its factory's two lines in libpk/src/residual_error/registry.cc, and the file in
// libpk/CMakeLists.txt (docs/architecture.md).
#ifndef PK_RESIDUAL_ERROR_H_
#define PK_RESIDUAL_ERROR_H_

#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace pk {

/// The residual-error parameters of the catalogue's error models: SIGMA_ADD (additive and
/// combined), SIGMA_PROP (proportional and combined) and SIGMA_LOG (exponential, σ of log DV).
inline constexpr const char* kSigmaAdd = "SIGMA_ADD";
inline constexpr const char* kSigmaProp = "SIGMA_PROP";
inline constexpr const char* kSigmaLog = "SIGMA_LOG";

class ResidualErrorModel {
 public:
  virtual ~ResidualErrorModel() = default;

  /// The name pkfit's --error takes ("additive"), or "least-squares".
  virtual const char* name() const = 0;
  /// False for least squares (weights, no σ); true for a likelihood.
  virtual bool is_likelihood() const { return true; }
  /// Whether the compared quantity is log y (DV and predictions must then be positive).
  virtual bool log_transformed() const { return false; }

  /// The σ parameters appended to the model's, in order (upper case). None for least squares.
  virtual std::vector<std::string> sigma_names() const { return {}; }
  /// A starting value for σ_j from the subject's observations (0.1 unless overridden).
  virtual double DefaultSigma(int j, const Eigen::VectorXd& observations) const;
  /// Whether σ_j is in the units of DV (an additive σ) rather than relative (the default). A σ
  /// counts as 0 (collapsed, or at its bound) below 1e-6 of the largest |DV|, or below 1e-6.
  virtual bool sigma_in_dv_units(int j) const;

  /// The variance v of the compared quantity for prediction ŷ and σ (sigma_names() values),
  /// with ∂v/∂ŷ and ∂v/∂σ_j (dv_dsigma has sigma_names().size() entries).
  virtual void Variance(double yhat, const double* sigma, double* v, double* dv_dyhat, double* dv_dsigma) const;
  /// The standard deviation √v for scaled residuals (IWRES); a model with one σ returns |σ| so
  /// that a σ of 1e-160 still divides.
  virtual double StandardDeviation(double yhat, const double* sigma) const;
};

/// The error model of this name (case-insensitive): "least-squares" (also "ls", "none"),
/// "additive", "proportional", "combined", "exponential". Throws pk::InputError listing the
/// names for any other.
std::shared_ptr<const ResidualErrorModel> MakeResidualError(const std::string& name);
/// The names MakeResidualError takes, least squares first.
std::vector<std::string> ResidualErrorNames();
/// Least squares, the default of ObjectiveOptions.
std::shared_ptr<const ResidualErrorModel> LeastSquares();

/// Whether `name` (canonical upper case) names a σ parameter of some registered error model.
bool IsResidualErrorName(const std::string& name);

}  // namespace pk

#endif  // PK_RESIDUAL_ERROR_H_
