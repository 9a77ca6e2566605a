// Helpers around pk::Dual for the routes (not installed).
//
// The event engine runs on Dual so that event times, amounts and rates that
// depend on θ (ALAG, F, R, D) carry their derivatives, and the model's A(θ)
// and C(θ) templates give ∂A/∂θ and ∂C/∂θ.
#ifndef PK_SRC_AUTODIFF_H_
#define PK_SRC_AUTODIFF_H_

#include <utility>

#include <Eigen/Core>

#include "pk/dual.h"

namespace pk {
namespace internal {

using Dual = pk::Dual;
using DualDerivatives = pk::DualDerivatives;
using DualVector = Eigen::Matrix<Dual, Eigen::Dynamic, 1>;

inline double Value(const Dual& x) { return x.value(); }
inline bool IsExactlyZero(const Dual& x) { return x.value() == 0.0 && x.derivatives().isZero(0.0); }

/// The derivative vector of `x`, as a length-`p` vector (zero when x is a constant).
inline Eigen::VectorXd Derivatives(const Dual& x, int p) {
  if (x.derivatives().size() == 0) return Eigen::VectorXd::Zero(p);
  return x.derivatives();
}

/// n×P matrix of the derivatives of a vector of duals.
inline Eigen::MatrixXd DerivativeMatrix(const DualVector& v, int p) {
  Eigen::MatrixXd d(v.size(), p);
  for (int i = 0; i < v.size(); ++i) d.row(i) = Derivatives(v(i), p).transpose();
  return d;
}

inline bool HasDerivative(const Dual& x) { return !x.derivatives().isZero(0.0); }

// The same helpers for plain doubles (constants: no derivatives), so that code
// templated on the scalar type runs on either.
inline bool HasDerivative(double) { return false; }
inline Eigen::VectorXd Derivatives(double, int p) { return Eigen::VectorXd::Zero(p); }
inline Eigen::MatrixXd DerivativeMatrix(const Eigen::VectorXd& v, int p) { return Eigen::MatrixXd::Zero(v.size(), p); }
inline const Eigen::VectorXd& Values(const Eigen::VectorXd& v) { return v; }

inline Eigen::VectorXd Values(const DualVector& v) {
  Eigen::VectorXd out(v.size());
  for (int i = 0; i < v.size(); ++i) out(i) = v(i).value();
  return out;
}

}  // namespace internal
}  // namespace pk


#endif  // PK_SRC_AUTODIFF_H_
