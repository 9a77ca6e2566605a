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

#include <Eigen/Core>

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


/// A third-order hyper-dual number: a part for every subset S of three directions, Σ_S x_S ε^S
/// with ε₁² = ε₂² = ε₃² = 0 (Fike & Alonso's number one direction up). Evaluating f on
/// x + u ε₁ + v ε₂ + w ε₃ (and mixed parts) gives the value, three directional derivatives, the
/// three mixed second derivatives and the mixed third derivative f‴(x)[u, v, w], exactly.
/// The population's Laplace gradient needs ∂³ŷ (the log det of the exact ½∇²l moves with θ and
/// η), and takes it from this number as the second order takes ∂²ŷ from HyperDual. Part S is the
/// bit mask of its directions: 1 = ε₁, 2 = ε₂, 4 = ε₃, 7 = ε₁ε₂ε₃.
/// For one function of the scalar (i, j the directions of a pair):
///   f(x)_i = f′ x_i,   f(x)_ij = f′ x_ij + f″ x_i x_j,
///   f(x)_7 = f′ x_7 + f″ (x_1 x_6 + x_2 x_5 + x_4 x_3) + f‴ x_1 x_2 x_4   (parts by mask).
class HyperDual3 {
 public:
  HyperDual3() = default;
  HyperDual3(double a) { p_[0] = a; }  // NOLINT: constants convert implicitly, as for pk::Dual

  double value() const { return p_[0]; }
  /// The part of mask `s` (0 … 7).
  double part(int s) const { return p_[s]; }
  double& part(int s) { return p_[s]; }

  /// f(this) from f and its first three derivatives at the value. Zero parts stay zero where a
  /// derivative is infinite, as HyperDual::Apply keeps them.
  HyperDual3 Apply(double f, double d1, double d2, double d3) const {
    const auto times = [](double a, double b) { return b == 0 ? 0.0 : a * b; };
    const double* x = p_;
    HyperDual3 r(f);
    for (int s : {1, 2, 4}) r.p_[s] = times(d1, x[s]);
    for (int s : {3, 5, 6}) {
      const int i = s & -s, j = s - i;  // its two directions
      r.p_[s] = times(d1, x[s]) + times(times(d2, x[i]), x[j]);
    }
    r.p_[7] = times(d1, x[7]) + times(times(d2, x[1]), x[6]) + times(times(d2, x[2]), x[5]) +
              times(times(d2, x[4]), x[3]) + times(times(times(d3, x[1]), x[2]), x[4]);
    return r;
  }

  HyperDual3& operator+=(const HyperDual3& o) {
    for (int s = 0; s < 8; ++s) p_[s] += o.p_[s];
    return *this;
  }
  HyperDual3& operator-=(const HyperDual3& o) {
    for (int s = 0; s < 8; ++s) p_[s] -= o.p_[s];
    return *this;
  }
  HyperDual3& operator*=(const HyperDual3& o) {
    HyperDual3 r;  // (xy)_S = Σ over T ⊆ S of x_T y_{S∖T}
    for (int s = 0; s < 8; ++s) {
      for (int t = s;; t = (t - 1) & s) {
        r.p_[s] += p_[t] * o.p_[s & ~t];
        if (t == 0) break;
      }
    }
    return *this = r;
  }
  HyperDual3& operator/=(const HyperDual3& o) {
    const double inv = 1 / o.p_[0];
    return *this *= o.Apply(inv, -inv * inv, 2 * inv * inv * inv, -6 * inv * inv * inv * inv);
  }
  HyperDual3 operator-() const {
    HyperDual3 r;
    for (int s = 0; s < 8; ++s) r.p_[s] = -p_[s];
    return r;
  }
  HyperDual3 operator+() const { return *this; }

  friend HyperDual3 operator+(HyperDual3 x, const HyperDual3& y) { return x += y; }
  friend HyperDual3 operator-(HyperDual3 x, const HyperDual3& y) { return x -= y; }
  friend HyperDual3 operator*(HyperDual3 x, const HyperDual3& y) { return x *= y; }
  friend HyperDual3 operator/(HyperDual3 x, const HyperDual3& y) { return x /= y; }
  friend bool operator<(const HyperDual3& x, const HyperDual3& y) { return x.value() < y.value(); }
  friend bool operator>(const HyperDual3& x, const HyperDual3& y) { return x.value() > y.value(); }
  friend bool operator<=(const HyperDual3& x, const HyperDual3& y) { return x.value() <= y.value(); }
  friend bool operator>=(const HyperDual3& x, const HyperDual3& y) { return x.value() >= y.value(); }

  /// Whether every part but the value is zero (a constant).
  bool constant() const {
    for (int s = 1; s < 8; ++s) {
      if (p_[s] != 0) return false;
    }
    return true;
  }

 private:
  double p_[8] = {0, 0, 0, 0, 0, 0, 0, 0};
};

inline HyperDual3 exp(const HyperDual3& x) {
  const double e = std::exp(x.value());
  return x.Apply(e, e, e, e);
}
inline HyperDual3 log(const HyperDual3& x) {
  const double v = x.value();
  return x.Apply(std::log(v), 1 / v, -1 / (v * v), 2 / (v * v * v));
}
inline HyperDual3 sqrt(const HyperDual3& x) {
  const double v = x.value(), s = std::sqrt(v);
  return x.Apply(s, 0.5 / s, -0.25 / (s * v), 0.375 / (s * v * v));
}
inline HyperDual3 abs(const HyperDual3& x) { return x.value() < 0 ? -x : x; }
inline HyperDual3 fabs(const HyperDual3& x) { return abs(x); }
inline HyperDual3 pow(const HyperDual3& x, double p) {
  const double v = x.value();
  // v^p and its derivatives p v^(p−1), p(p−1) v^(p−2), p(p−1)(p−2) v^(p−3); a factor of 0 (an
  // integer p ≤ 2) gives 0 even at v = 0.
  const double d1 = p == 0 ? 0 : p * std::pow(v, p - 1);
  const double d2 = p == 0 || p == 1 ? 0 : p * (p - 1) * std::pow(v, p - 2);
  const double d3 = p == 0 || p == 1 || p == 2 ? 0 : p * (p - 1) * (p - 2) * std::pow(v, p - 3);
  return x.Apply(std::pow(v, p), d1, d2, d3);
}
inline HyperDual3 pow(const HyperDual3& x, const HyperDual3& y) {
  if (y.constant() || x.value() == 0) return pow(x, y.value());  // as pow(x, c), as HyperDual does
  return exp(y * log(x));
}
inline HyperDual3 pow(double x, const HyperDual3& y) { return pow(HyperDual3(x), y); }

}  // namespace pk

namespace Eigen {
/// HyperDual3 as a scalar of Eigen matrices (the event engine runs on it when doses move with θ).
template <>
struct NumTraits<pk::HyperDual3> : NumTraits<double> {
  typedef pk::HyperDual3 Real;
  typedef pk::HyperDual3 NonInteger;
  typedef pk::HyperDual3 Nested;
  typedef pk::HyperDual3 Literal;
  enum { IsComplex = 0, IsInteger = 0, IsSigned = 1, RequireInitialization = 1, ReadCost = 1, AddCost = 8, MulCost = 27 };
};
}  // namespace Eigen

#endif  // PK_HYPER_DUAL_H_
