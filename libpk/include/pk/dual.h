// libpk: the forward-mode automatic-differentiation scalar.
//
// A Dual carries a value and its derivatives with respect to a set of
// directions (parameters, or seed directions of a Jacobian). Model functors
// (pk/ode_model.h) are templates on their scalar type, and libpk evaluates
// them on Dual to obtain g_x and g_θ (and on pk::TapeScalar for f_x and f_θ):
// nobody writes a model's derivatives by hand. The event engine and the linear
// models' A(θ) and C(θ) run on Dual too. In a model, write ordinary arithmetic and call the
// elementary functions unqualified after `using std::exp;` etc., so that
// argument-dependent lookup finds the Dual overloads below:
//
//   template <typename T>
//   void Rhs(const T* x, const T* theta, T* dxdt) const {
//     using std::pow;
//     dxdt[0] = -theta[0] * pow(x[0], theta[1]);
//   }
//
// Why not Eigen's AutoDiffScalar: it reconciles a constant (empty derivative
// vector) with a variable only for plain vectors, not for the expression
// templates that arise in sums like `t + k * ii`, where it silently mixes
// sizes. Here an empty derivative vector always means zero, in every operation.
#ifndef PK_DUAL_H_
#define PK_DUAL_H_

#include <cmath>

#include <Eigen/Core>

namespace pk {

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
  Dual operator+() const { return *this; }

  friend Dual operator+(Dual a, const Dual& b) { return a += b; }
  friend Dual operator-(Dual a, const Dual& b) { return a -= b; }
  friend Dual operator*(Dual a, const Dual& b) { return a *= b; }
  friend Dual operator/(Dual a, const Dual& b) { return a /= b; }

  // Comparisons look at the values only (a model may branch on them).
  friend bool operator<(const Dual& a, const Dual& b) { return a.v_ < b.v_; }
  friend bool operator>(const Dual& a, const Dual& b) { return a.v_ > b.v_; }
  friend bool operator<=(const Dual& a, const Dual& b) { return a.v_ <= b.v_; }
  friend bool operator>=(const Dual& a, const Dual& b) { return a.v_ >= b.v_; }

  /// f(v) with derivative f'(v)·d: the chain rule for the functions below.
  Dual Chain(double f, double df) const {
    return Dual(f, d_.size() ? DualDerivatives(df * d_) : DualDerivatives());
  }

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

inline Dual exp(const Dual& x) {
  const double e = std::exp(x.value());
  return x.Chain(e, e);
}
inline Dual log(const Dual& x) { return x.Chain(std::log(x.value()), 1 / x.value()); }
inline Dual sqrt(const Dual& x) {
  const double s = std::sqrt(x.value());
  return x.Chain(s, 0.5 / s);
}
inline Dual abs(const Dual& x) { return x.value() < 0 ? -x : x; }
inline Dual fabs(const Dual& x) { return abs(x); }
/// x^p for a constant p (x > 0, or x = 0 with p ≥ 1).
inline Dual pow(const Dual& x, double p) {
  const double v = std::pow(x.value(), p);
  return x.Chain(v, p == 0 ? 0.0 : p * std::pow(x.value(), p - 1));
}
/// x^p = exp(p log x) for x > 0; at x = 0 the value is 0 (p > 0) and the
/// derivative with respect to p is taken as 0.
inline Dual pow(const Dual& x, const Dual& p) {
  if (p.derivatives().size() == 0) return pow(x, p.value());
  if (x.value() == 0) return pow(x, p.value()) + Dual(0.0) * p;
  return exp(p * log(x));
}
inline Dual pow(double x, const Dual& p) { return pow(Dual(x), p); }

}  // namespace pk

namespace Eigen {
template <>
struct NumTraits<pk::Dual> : NumTraits<double> {
  typedef pk::Dual Real;
  typedef pk::Dual NonInteger;
  typedef pk::Dual Nested;
  typedef pk::Dual Literal;
  enum { IsComplex = 0, IsInteger = 0, IsSigned = 1, RequireInitialization = 1, ReadCost = 1, AddCost = 4, MulCost = 4 };
};
}  // namespace Eigen

#endif  // PK_DUAL_H_
