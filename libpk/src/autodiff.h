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
#include "pk/hyper_dual.h"

namespace pk {
namespace internal {

using Dual = pk::Dual;
using DualDerivatives = pk::DualDerivatives;
using DualVector = Eigen::Matrix<Dual, Eigen::Dynamic, 1>;

inline double Value(const Dual& x) { return x.value(); }
inline bool IsExactlyZero(const Dual& x) { return x.value() == 0.0 && x.derivatives().isZero(0.0); }
inline double Value(const HyperDual3& x) { return x.value(); }
inline bool IsExactlyZero(const HyperDual3& x) { return x.value() == 0.0 && x.constant(); }

/// The derivative vector of `x`, as a length-`p` vector (zero when x is a constant).
inline Eigen::VectorXd Derivatives(const Dual& x, int p) {
  if (x.derivatives().size() == 0) return Eigen::VectorXd::Zero(p);
  return x.derivatives();
}

/// count×P matrix of the derivatives of the first `count` entries of `v` (all of them by default).
inline Eigen::MatrixXd DerivativeMatrix(const DualVector& v, int p, Eigen::Index count = -1) {
  if (count < 0) count = v.size();
  Eigen::MatrixXd d(count, p);
  for (Eigen::Index i = 0; i < count; ++i) {
    const DualDerivatives& g = v(i).derivatives();  // no copy: the matrix row is written from it
    if (g.size() == 0) {
      d.row(i).setZero();
    } else {
      d.row(i) = g.transpose();
    }
  }
  return d;
}

inline bool HasDerivative(const Dual& x) { return !x.derivatives().isZero(0.0); }

// The same helpers for plain doubles (constants: no derivatives), so that code
// templated on the scalar type runs on either.
inline bool HasDerivative(double) { return false; }
inline Eigen::VectorXd Derivatives(double, int p) { return Eigen::VectorXd::Zero(p); }
inline Eigen::MatrixXd DerivativeMatrix(const Eigen::VectorXd& v, int p, Eigen::Index count = -1) {
  return Eigen::MatrixXd::Zero(count < 0 ? v.size() : count, p);
}
inline const Eigen::VectorXd& Values(const Eigen::VectorXd& v) { return v; }
inline Eigen::VectorXd Values(const Eigen::VectorXd& v, Eigen::Index count) { return v.head(count); }

/// The values of the first `count` entries of `v` (all of them by default).
inline Eigen::VectorXd Values(const DualVector& v, Eigen::Index count = -1) {
  if (count < 0) count = v.size();
  Eigen::VectorXd out(count);
  for (Eigen::Index i = 0; i < count; ++i) out(i) = v(i).value();
  return out;
}

}  // namespace internal
}  // namespace pk


#endif  // PK_SRC_AUTODIFF_H_
