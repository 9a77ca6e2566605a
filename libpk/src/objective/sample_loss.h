// The per-sample loss of one evaluation (not installed): ℓ_k(ŷ_k, σ) and its derivatives
// from the residual-error model (pk/residual_error.h), with Beal's M3 for censored samples.
//
//   least squares   ℓ_k = ½ W_k (y_k − ŷ_k)²
//   likelihood      ℓ_k = ½ [log(2π v_k) + (T(y_k) − T(ŷ_k))²/v_k] (+ log y_k when T = log)
//   censored (M3)   ℓ_k = −log Φ(z_k),  z_k = s_k (T(y_k) − T(ŷ_k))/√v_k,  s_k = CENS
//
// The gradient routes need only ∂ℓ/∂ŷ; σ's gradient needs ∂ℓ/∂v and ∂v/∂σ.
#ifndef PK_SRC_OBJECTIVE_SAMPLE_LOSS_H_
#define PK_SRC_OBJECTIVE_SAMPLE_LOSS_H_

#include <string>
#include <vector>

#include <Eigen/Core>

#include "pk/residual_error.h"

namespace pk {
namespace internal {

/// The samples as the loss sees them.
struct SampleSet {
  const Eigen::VectorXd* y = nullptr;     ///< observations (a censored sample's limit)
  const Eigen::VectorXd* w = nullptr;     ///< least-squares weights
  const Eigen::VectorXi* cens = nullptr;  ///< 0, or ±1 beyond DV
  const std::vector<double>* times = nullptr;  ///< for messages
  const Eigen::VectorXi* outputs = nullptr;    ///< the output each measures (its error model); null: all 1
};

struct SampleLoss {
  double value = 0;
  Eigen::VectorXd r;          ///< y − ŷ (T(y) − T(ŷ) on log scale); least squares: kept when asked
  // Likelihood only, per sample:
  Eigen::VectorXd v;          ///< variance of the compared quantity
  Eigen::VectorXd dv_dy;      ///< ∂v/∂ŷ
  Eigen::MatrixXd dv_dsigma;  ///< ∂v/∂σ_j (N × number of σ)
  Eigen::VectorXd dl_dv;      ///< ∂ℓ/∂v
  Eigen::VectorXd dmu_dy;     ///< ∂T(ŷ)/∂ŷ: 1, or 1/ŷ on log scale
  Eigen::VectorXd z;          ///< censored samples: where Φ(z) is their probability (else 0)
};

/// Computes the loss of every sample at predictions `yhat` into `out` and ∂ℓ/∂ŷ into `dl_dy`
/// (storage the caller may keep). `sigma` holds the error model's σ values. Least squares
/// keeps r only when `keep_residuals`. Returns false with `why` when the loss is undefined
/// (a zero variance, a censored sample of probability 0, a non-positive prediction on log scale).
bool ComputeSampleLoss(const ResidualErrorModel& error, const SampleSet& samples, const double* sigma,
                       const Eigen::VectorXd& yhat, bool keep_residuals, SampleLoss* out, Eigen::VectorXd* dl_dy,
                       std::string* why);

/// Expected Fisher information of the samples in the free parameters:
/// Σ_k ∇μ_k∇μ_kᵀ/v_k + ∇v_k∇v_kᵀ/(2v_k²), the Tobit model's for a censored sample.
/// `jy` holds ∇μ (N × P, zero in the σ columns); `sigma_of[j]` is the error-model σ that free
/// parameter j is, or -1.
Eigen::MatrixXd SampleInformation(const SampleLoss& loss, const Eigen::VectorXi& cens, const Eigen::MatrixXd& jy,
                                  const std::vector<int>& sigma_of);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_OBJECTIVE_SAMPLE_LOSS_H_
