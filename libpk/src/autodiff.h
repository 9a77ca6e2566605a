// Forward-mode automatic differentiation scalars (not installed).
//
// Dual carries a value and its derivatives with respect to the P estimated
// parameters. The event engine runs on Dual so that event times, amounts and
// rates that depend on θ (ALAG, F, R, D) carry their derivatives, and the
// model's A(θ) and C(θ) templates give ∂A/∂θ and ∂C/∂θ.
//
// Why not Eigen's AutoDiffScalar: it reconciles a constant (empty derivative
// vector) with a variable only for plain vectors, not for the expression
// templates that arise in sums like `t + k * ii`, where it silently mixes
// sizes. Here an empty derivative vector always means zero, in every operation.
#ifndef PK_SRC_AUTODIFF_H_
#define PK_SRC_AUTODIFF_H_

#include <utility>

#include <Eigen/Core>

namespace pk {
namespace internal {

using DualDerivatives = Eigen::VectorXd;

class Dual {
 public:
  Dual() = default;
  Dual(double value) : v_(value) {}  // NOLINT: constants convert implicitly
  /// The independent variable number `i` of `n`.
  Dual(double value, int n, int i) : v_(value), d_(DualDerivatives::Unit(n, i)) {}
  Dual(double value, const DualDerivatives& d) : v_(value), d_(d) {}

  double value() const { return v_; }
  /// Empty when the value is a constant.
  const DualDerivatives& derivatives() const { return d_; }

  Dual& operator+=(const Dual& o) {
    Axpy(1.0, o.d_);
    v_ += o.v_;
    return *this;
  }
  Dual& operator-=(const Dual& o) {
    Axpy(-1.0, o.d_);
    v_ -= o.v_;
    return *this;
  }
  Dual& operator*=(const Dual& o) {
    // (uv)' = u'v + uv'
    if (d_.size()) d_ *= o.v_;
    Axpy(v_, o.d_);
    v_ *= o.v_;
    return *this;
  }
  Dual& operator/=(const Dual& o) {
    // (u/v)' = (u' − (u/v) v') / v
    const double q = v_ / o.v_;
    Axpy(-q, o.d_);
    if (d_.size()) d_ /= o.v_;
    v_ = q;
    return *this;
  }
  Dual operator-() const { return Dual(-v_, d_.size() ? DualDerivatives(-d_) : DualDerivatives()); }

  friend Dual operator+(Dual a, const Dual& b) { return a += b; }
  friend Dual operator-(Dual a, const Dual& b) { return a -= b; }
  friend Dual operator*(Dual a, const Dual& b) { return a *= b; }
  friend Dual operator/(Dual a, const Dual& b) { return a /= b; }

 private:
  void Axpy(double a, const DualDerivatives& x) {
    if (x.size() == 0 || a == 0) return;
    if (d_.size() == 0) {
      d_ = a * x;
    } else {
      d_ += a * x;
    }
  }

  double v_ = 0;
  DualDerivatives d_;
};

}  // namespace internal
}  // namespace pk

namespace Eigen {
template <>
struct NumTraits<pk::internal::Dual> : NumTraits<double> {
  typedef pk::internal::Dual Real;
  typedef pk::internal::Dual NonInteger;
  typedef pk::internal::Dual Nested;
  typedef pk::internal::Dual Literal;
  enum { IsComplex = 0, IsInteger = 0, IsSigned = 1, RequireInitialization = 1, ReadCost = 1, AddCost = 4, MulCost = 4 };
};
}  // namespace Eigen

namespace pk {
namespace internal {

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
