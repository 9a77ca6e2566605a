// libpk: from transfer-function coefficients to exponents, half-lives and
// compartmental parameters, with standard errors by the delta method.
//
// A tf<n> model y = B(s)/A(s)·u (per unit dose) has poles −λ_i, the roots of
// A(s), and an impulse response Σ a_i e^{−λ_i t} with residues
// a_i = B(−λ_i)/A'(−λ_i). Read as an IV bolus input, the exponentials give a
// mammillary model of n compartments (ExponentialsToMammillary). Read as an
// oral input, the fastest rate is taken as KA (the usual, non-flip-flop
// labelling, which the data alone cannot decide), the disposition amplitudes
// become a_i (KA − λ_i)/KA, and n − 1 compartments follow.
//
// Standard errors: Cov(g) = J Cov(θ) Jᵀ, with J = ∂g/∂θ by central differences
// of the conversion (it involves polynomial roots, which are smooth where the
// conversion is feasible).
#ifndef PK_CONVERSION_H_
#define PK_CONVERSION_H_

#include <limits>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pk/model.h"

namespace pk {

/// The unit-dose IV response of a mammillary disposition: Σ_i a_i e^{−λ_i t}.
struct Exponentials {
  std::vector<double> amplitude;  ///< a_i (concentration per unit dose)
  std::vector<double> rate;       ///< λ_i > 0
};

/// Mammillary micro-constants, then clearances and volumes, from a unit-dose
/// sum of 1, 2 or 3 exponentials: {CL, V} / {CL, V1, Q, V2} / {CL, V1, Q2, V2,
/// Q3, V3} in catalogue order. For three exponentials the peripheral rates
/// k21 ≥ k31 are the roots of s² − (b₁/b₀)s + b₂/b₀ from the transfer
/// function's numerator, so the faster-equilibrating peripheral is labelled 2.
/// Returns false with `why` for infeasible values (negative or complex rates).
bool ExponentialsToMammillary(const Exponentials& e, std::vector<double>* parameters, std::string* why);

/// The transfer function of a unit-dose sum of exponentials:
/// A(s) = Π(s + λ_i) = sⁿ + a₁sⁿ⁻¹ + … + aₙ and B(s) = Σ a_i Π_{j≠i}(s + λ_j) =
/// b₁sⁿ⁻¹ + … + bₙ; `coefficients` = {a₁..aₙ, b₁..bₙ}, the tf<n> parameter order.
void ExponentialsToTransferFunction(const Exponentials& e, std::vector<double>* coefficients);

struct DerivedParameter {
  std::string name;  ///< e.g. LAMBDA1, THALF1, AMP1, CL, V1, Q, V2, KA
  double value = 0;
  double se = std::numeric_limits<double>::quiet_NaN();
  double rse_pct = std::numeric_limits<double>::quiet_NaN();
};

struct TransferFunctionReading {
  std::string reading;  ///< "exponents", "iv" or "oral"
  bool ok = false;
  /// Why the coefficients do not convert, when !ok; when ok, a caveat or empty
  /// (exponents: two rates that nearly coincide, whose amplitudes cancel).
  std::string message;
  std::vector<DerivedParameter> parameters;
};

/// The other direction: the unit-dose response of a linear model (central
/// concentration after a unit dose into the default dose compartment) as a sum
/// of exponentials, from the eigendecomposition of A(θ). `theta` holds the
/// model parameters. ExponentialsToTransferFunction then gives its tf coefficients.
/// Returns false with `why` for a complex or defective spectrum.
bool ModelToExponentials(const Model& model, const Eigen::VectorXd& theta, Exponentials* e, std::string* why);

/// The "exponents" reading of a linear compartment model: λ_i (fastest first),
/// t½_i = ln2/λ_i and the amplitudes a_i of its unit-dose response (see
/// ModelToExponentials), with standard errors by the delta method from the
/// covariance of `theta` (the model parameters, model.num_parameters() of them;
/// pass an empty matrix for no standard errors).
TransferFunctionReading ModelExponents(const Model& model, const Eigen::VectorXd& theta,
                                       const Eigen::MatrixXd& covariance);

/// Converts tf<n> coefficients {a₁..aₙ, b₁..bₙ} (per unit dose) with their
/// covariance (2n×2n; pass an empty matrix for no standard errors) into three
/// readings: the exponents (λ_i fastest first, t½_i = ln2/λ_i, amplitudes a_i),
/// the IV mammillary parameters and their micro-constants (CL, V1, …, K10, K12,
/// K21, …), and the oral ones (KA, then the same for the disposition).
std::vector<TransferFunctionReading> ConvertTransferFunction(const Eigen::VectorXd& coefficients,
                                                             const Eigen::MatrixXd& covariance);

}  // namespace pk

#endif  // PK_CONVERSION_H_
