// A second-order forward-mode scalar (not installed): a value with its gradient and Hessian in
// d variables. The exact outer gradient (outer_gradient.cc) evaluates the conditional objective
// on it to get ∇l, ∇²l and ∇L in one pass over a subject's samples.
//
// pk::Dual carries first derivatives only, and nesting it is not supported, so this small type
// carries the second-order terms explicitly:
//   (ab)'' = a''b + ab'' + a'b'ᵀ + b'a'ᵀ,   φ(a)'' = φ'(a) a'' + φ''(a) a'a'ᵀ.
#ifndef PK_SRC_POPULATION_HYPER_DUAL_H_
#define PK_SRC_POPULATION_HYPER_DUAL_H_

#include <cmath>

#include <Eigen/Core>

namespace pk {
namespace internal {

class HyperDual {
 public:
  HyperDual() = default;
  /// A constant in d variables.
  HyperDual(double v, int d) : v_(v), g_(Eigen::VectorXd::Zero(d)), h_(Eigen::MatrixXd::Zero(d, d)) {}
  /// Variable i of d.
  static HyperDual Variable(double v, int d, int i) {
    HyperDual x(v, d);
    x.g_(i) = 1;
    return x;
  }

  double value() const { return v_; }
  const Eigen::VectorXd& gradient() const { return g_; }
  const Eigen::MatrixXd& hessian() const { return h_; }

  HyperDual& operator+=(const HyperDual& o) {
    v_ += o.v_;
    g_ += o.g_;
    h_ += o.h_;
    return *this;
  }
  HyperDual& operator-=(const HyperDual& o) {
    v_ -= o.v_;
    g_ -= o.g_;
    h_ -= o.h_;
    return *this;
  }
  HyperDual& operator*=(const HyperDual& o) {
    h_ = h_ * o.v_ + o.h_ * v_ + g_ * o.g_.transpose() + o.g_ * g_.transpose();
    g_ = g_ * o.v_ + o.g_ * v_;
    v_ *= o.v_;
    return *this;
  }
  HyperDual& operator*=(double c) {
    v_ *= c;
    g_ *= c;
    h_ *= c;
    return *this;
  }
  HyperDual& operator+=(double c) {
    v_ += c;
    return *this;
  }
  HyperDual& operator/=(const HyperDual& o) { return *this *= Reciprocal(o); }

  /// φ(a) from φ(a.v), φ'(a.v), φ''(a.v).
  static HyperDual Apply(const HyperDual& a, double f, double df, double d2f) {
    HyperDual r;
    r.v_ = f;
    r.g_ = df * a.g_;
    r.h_ = df * a.h_ + d2f * a.g_ * a.g_.transpose();
    return r;
  }
  static HyperDual Reciprocal(const HyperDual& a) {
    const double inv = 1 / a.v_;
    return Apply(a, inv, -inv * inv, 2 * inv * inv * inv);
  }

 private:
  double v_ = 0;
  Eigen::VectorXd g_;
  Eigen::MatrixXd h_;
};

inline HyperDual operator+(HyperDual a, const HyperDual& b) { return a += b; }
inline HyperDual operator-(HyperDual a, const HyperDual& b) { return a -= b; }
inline HyperDual operator*(HyperDual a, const HyperDual& b) { return a *= b; }
inline HyperDual operator/(HyperDual a, const HyperDual& b) { return a /= b; }
inline HyperDual operator*(HyperDual a, double c) { return a *= c; }
inline HyperDual operator*(double c, HyperDual a) { return a *= c; }
inline HyperDual operator+(HyperDual a, double c) { return a += c; }
inline HyperDual operator-(HyperDual a) { return a *= -1.0; }
inline HyperDual exp(const HyperDual& a) {
  const double e = std::exp(a.value());
  return HyperDual::Apply(a, e, e, e);
}
inline HyperDual log(const HyperDual& a) {
  const double x = a.value();
  return HyperDual::Apply(a, std::log(x), 1 / x, -1 / (x * x));
}
inline HyperDual sqrt(const HyperDual& a) {
  const double s = std::sqrt(a.value());
  return HyperDual::Apply(a, s, 0.5 / s, -0.25 / (s * a.value()));
}

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_POPULATION_HYPER_DUAL_H_
