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

  /// f(v) with derivative f'(v)·d: the chain rule for the functions below. Where f'(v) is infinite
  /// (sqrt, log, pow at 0) a derivative that is 0 stays 0, not 0·∞ = NaN, as on pk::FixedDual's lanes
  /// and pk::Tape's tangents: a direction that does not pass through v keeps its finite derivative.
  Dual Chain(double f, double df) const {
    if (d_.size() == 0) return Dual(f);
    if (std::isfinite(df)) return Dual(f, DualDerivatives(df * d_));
    return Dual(f, DualDerivatives(d_.unaryExpr([df](double t) { return t == 0 ? 0.0 : df * t; })));
  }
  /// f(x, y) with partials ∂f/∂x and ∂f/∂y: the chain rule for two arguments.
  static Dual Chain2(double f, const Dual& x, double dx, const Dual& y, double dy) {
    Dual r = x.Chain(f, dx);
    r.Axpy(1.0, y.Chain(0.0, dy).d_);
    return r;
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
/// x^p; at x ≤ 0 the derivative with respect to p is taken as 0. The value is std::pow's and the
/// partials are those of pk::TapeScalar and pk::FixedDual, so the routes agree where 0^p is met.
inline Dual pow(const Dual& x, const Dual& p) {
  if (p.derivatives().size() == 0) return pow(x, p.value());
  const double v = std::pow(x.value(), p.value());
  const double dx = p.value() == 0 ? 0.0 : p.value() * std::pow(x.value(), p.value() - 1);
  const double dp = x.value() > 0 ? v * std::log(x.value()) : 0.0;
  return Dual::Chain2(v, x, dx, p, dp);
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
