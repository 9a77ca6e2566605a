// libpk: a hyper-dual number, a + b ε₁ + c ε₂ + d ε₁ε₂ with ε₁² = ε₂² = 0 (Fike & Alonso,
// AIAA 2011-886).
//
// Evaluating f on x + u ε₁ + v ε₂ + w ε₁ε₂ gives, exactly and in one pass,
//   f(x) + f'(x)u ε₁ + f'(x)v ε₂ + (f'(x)w + f''(x)[u, v]) ε₁ε₂:
// the value, two directional derivatives and the mixed second derivative, with no step and no
// cancellation. libpk takes the second-order sensitivities of the population's outer gradient
// from it: a linear model's A(θ) and C(θ), and a nonlinear model's right-hand side and outputs
// (pk/ode_model.h), are evaluated on it. A model never uses it directly; it only has to be a
// template on its scalar type and call exp, log, sqrt, pow and abs unqualified.
// For one function of the scalar:
//   f(a + bε₁ + cε₂ + dε₁ε₂) = f(a) + f'(a)b ε₁ + f'(a)c ε₂ + (f'(a)d + f''(a)bc) ε₁ε₂.
#ifndef PK_HYPER_DUAL_H_
#define PK_HYPER_DUAL_H_

#include <cmath>

namespace pk {

class HyperDual {
 public:
  HyperDual() = default;
  HyperDual(double a) : a_(a) {}  // NOLINT: constants convert implicitly, as for pk::Dual
  HyperDual(double a, double b, double c, double d) : a_(a), b_(b), c_(c), d_(d) {}

  double value() const { return a_; }
  double e1() const { return b_; }   ///< the ε₁ part: the derivative along the first direction
  double e2() const { return c_; }   ///< the ε₂ part: along the second
  double e12() const { return d_; }  ///< the ε₁ε₂ part: the mixed second derivative

  /// f(this) from f, f' and f'' at the value. A part that is zero stays zero even where f' or
  /// f'' is infinite (√x or x^1.5 at x = 0 along a direction that does not move x), as a
  /// derivative of a constant should, instead of becoming 0·∞ = NaN.
  HyperDual Apply(double f, double df, double d2f) const {
    const auto times = [](double a, double b) { return b == 0 ? 0.0 : a * b; };
    return HyperDual(f, times(df, b_), times(df, c_), times(df, d_) + times(times(d2f, b_), c_));
  }

  HyperDual& operator+=(const HyperDual& o) {
    a_ += o.a_, b_ += o.b_, c_ += o.c_, d_ += o.d_;
    return *this;
  }
  HyperDual& operator-=(const HyperDual& o) {
    a_ -= o.a_, b_ -= o.b_, c_ -= o.c_, d_ -= o.d_;
    return *this;
  }
  HyperDual& operator*=(const HyperDual& o) {
    // (a + bε₁ + cε₂ + dε₁ε₂)(a' + b'ε₁ + c'ε₂ + d'ε₁ε₂): the ε₁ε₂ part is ad' + da' + bc' + cb'.
    const HyperDual r(a_ * o.a_, a_ * o.b_ + b_ * o.a_, a_ * o.c_ + c_ * o.a_,
                            a_ * o.d_ + d_ * o.a_ + b_ * o.c_ + c_ * o.b_);
    return *this = r;
  }
  HyperDual& operator/=(const HyperDual& o) {
    const double inv = 1 / o.a_;
    return *this *= o.Apply(inv, -inv * inv, 2 * inv * inv * inv);
  }
  HyperDual operator-() const { return HyperDual(-a_, -b_, -c_, -d_); }
  HyperDual operator+() const { return *this; }

  friend HyperDual operator+(HyperDual x, const HyperDual& y) { return x += y; }
  friend HyperDual operator-(HyperDual x, const HyperDual& y) { return x -= y; }
  friend HyperDual operator*(HyperDual x, const HyperDual& y) { return x *= y; }
  friend HyperDual operator/(HyperDual x, const HyperDual& y) { return x /= y; }
  // Comparisons look at the values (a model may branch on them).
  friend bool operator<(const HyperDual& x, const HyperDual& y) { return x.a_ < y.a_; }
  friend bool operator>(const HyperDual& x, const HyperDual& y) { return x.a_ > y.a_; }
  friend bool operator<=(const HyperDual& x, const HyperDual& y) { return x.a_ <= y.a_; }
  friend bool operator>=(const HyperDual& x, const HyperDual& y) { return x.a_ >= y.a_; }

 private:
  double a_ = 0, b_ = 0, c_ = 0, d_ = 0;
};

inline HyperDual exp(const HyperDual& x) {
  const double e = std::exp(x.value());
  return x.Apply(e, e, e);
}
inline HyperDual log(const HyperDual& x) {
  const double v = x.value();
  return x.Apply(std::log(v), 1 / v, -1 / (v * v));
}
inline HyperDual sqrt(const HyperDual& x) {
  const double s = std::sqrt(x.value());
  return x.Apply(s, 0.5 / s, -0.25 / (s * x.value()));
}
inline HyperDual abs(const HyperDual& x) { return x.value() < 0 ? -x : x; }
inline HyperDual pow(const HyperDual& x, double p) {
  const double v = x.value();
  // v^p, p v^(p−1), p(p−1) v^(p−2), written so that v = 0 with p = 1 or 2 stays finite.
  const double f = std::pow(v, p);
  const double df = p == 0 ? 0 : p * std::pow(v, p - 1);
  const double d2f = p == 0 || p == 1 ? 0 : p * (p - 1) * std::pow(v, p - 2);
  return x.Apply(f, df, d2f);
}
inline HyperDual pow(const HyperDual& x, const HyperDual& y) {
  // A constant exponent, or a base of 0 (where log x is −∞): as pow(x, c), as pk::Dual does.
  if ((y.e1() == 0 && y.e2() == 0 && y.e12() == 0) || x.value() == 0) return pow(x, y.value());
  return exp(y * log(x));
}

inline HyperDual pow(double x, const HyperDual& y) { return pow(HyperDual(x), y); }
inline HyperDual fabs(const HyperDual& x) { return abs(x); }

}  // namespace pk

#endif  // PK_HYPER_DUAL_H_
