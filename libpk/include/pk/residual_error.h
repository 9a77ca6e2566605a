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
  /// sigma_names().size(), without building the names (per-sample code asks for it).
  virtual int num_sigma() const { return static_cast<int>(sigma_names().size()); }
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

  /// The model that output `output` (1-based, a sample's DVID) follows, and where its σ start in
  /// sigma_names(). A single model serves every output, its σ from 0; MakePerOutputError's
  /// serves each output from its own. Callers pass `sigma + *first_sigma` to the component.
  virtual const ResidualErrorModel& ForOutput(int output, int* first_sigma) const;
  /// The number of outputs with a model of their own (0: one model for every output).
  virtual int num_outputs() const { return 0; }
};

/// Each output its own error model and σ, as NONMEM's $ERROR with an EPS per DVID: output k
/// (1-based) follows models[k-1], whose σ are named after the output (SIGMA_PROP_CP,
/// SIGMA_ADD_E for outputs CP and E). Every model must be a likelihood (not least squares).
/// Throws pk::InputError otherwise, or when the names and models differ in number.
std::shared_ptr<const ResidualErrorModel> MakePerOutputError(
    std::vector<std::shared_ptr<const ResidualErrorModel>> models, std::vector<std::string> output_names);

/// The variance of output `output`'s compared quantity, with ∂v/∂ŷ and ∂v/∂σ over every σ of
/// `error` (zero for the σ of other outputs): ResidualErrorModel::ForOutput applied.
void OutputVariance(const ResidualErrorModel& error, int output, double yhat, const double* sigma, double* v,
                    double* dv_dyhat, double* dv_dsigma);
/// The standard deviation of output `output`'s compared quantity (IWRES's scale).
double OutputStandardDeviation(const ResidualErrorModel& error, int output, double yhat, const double* sigma);
/// The model's name for reports: "proportional", or per output "proportional (SIGMA_PROP_CP);
/// additive (SIGMA_ADD_E)".
std::string DescribeErrorModel(const ResidualErrorModel& error);

/// Starting values of every σ of `error`: each output's from that output's observations
/// (`outputs` gives the output of each observation; empty: all output 1).
std::vector<double> DefaultSigmas(const ResidualErrorModel& error, const Eigen::VectorXd& observations,
                                  const Eigen::VectorXi& outputs);
/// Whether output `output` compares log y (its model's log_transformed()).
inline bool OutputLogTransformed(const ResidualErrorModel& error, int output) {
  int first = 0;
  return error.ForOutput(output, &first).log_transformed();
}

/// The error model of this name (case-insensitive): "least-squares" (also "ls", "none"),
/// "additive", "proportional", "combined", "exponential". Throws pk::InputError listing the
/// names for any other.
std::shared_ptr<const ResidualErrorModel> MakeResidualError(const std::string& name);
/// The names MakeResidualError takes, least squares first.
std::vector<std::string> ResidualErrorNames();
/// Least squares, the default of ObjectiveOptions.
std::shared_ptr<const ResidualErrorModel> LeastSquares();

/// Whether `name` (canonical upper case) names a σ parameter of some registered error model, or
/// (SIGMA_…_OUTPUT) of a per-output one.
bool IsResidualErrorName(const std::string& name);

}  // namespace pk

#endif  // PK_RESIDUAL_ERROR_H_
