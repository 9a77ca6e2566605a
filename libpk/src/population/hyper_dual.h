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

/// MaxD bounds the number of variables at compile time, which keeps the gradient and Hessian on
/// the stack (no allocation per operation); Eigen::Dynamic allows any number, on the heap.
template <int MaxD>
class HyperDualT {
 public:
  using Vector = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, MaxD, 1>;
  using Matrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, MaxD, MaxD>;
  using HyperDual = HyperDualT;

  HyperDualT() = default;
  /// A constant in d variables.
  HyperDualT(double v, int d) : v_(v), g_(Vector::Zero(d)), h_(Matrix::Zero(d, d)) {}
  /// Variable i of d.
  static HyperDual Variable(double v, int d, int i) {
    HyperDual x(v, d);
    x.g_(i) = 1;
    return x;
  }

  double value() const { return v_; }
  const Vector& gradient() const { return g_; }
  const Matrix& hessian() const { return h_; }

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
  Vector g_;
  Matrix h_;
};

template <int D> HyperDualT<D> operator+(HyperDualT<D> a, const HyperDualT<D>& b) { return a += b; }
template <int D> HyperDualT<D> operator-(HyperDualT<D> a, const HyperDualT<D>& b) { return a -= b; }
template <int D> HyperDualT<D> operator*(HyperDualT<D> a, const HyperDualT<D>& b) { return a *= b; }
template <int D> HyperDualT<D> operator/(HyperDualT<D> a, const HyperDualT<D>& b) { return a /= b; }
template <int D> HyperDualT<D> operator*(HyperDualT<D> a, double c) { return a *= c; }
template <int D> HyperDualT<D> operator*(double c, HyperDualT<D> a) { return a *= c; }
template <int D> HyperDualT<D> operator+(HyperDualT<D> a, double c) { return a += c; }
template <int D> HyperDualT<D> operator-(HyperDualT<D> a) { return a *= -1.0; }
template <int D> HyperDualT<D> exp(const HyperDualT<D>& a) {
  const double e = std::exp(a.value());
  return HyperDualT<D>::Apply(a, e, e, e);
}
template <int D> HyperDualT<D> log(const HyperDualT<D>& a) {
  const double x = a.value();
  return HyperDualT<D>::Apply(a, std::log(x), 1 / x, -1 / (x * x));
}
template <int D> HyperDualT<D> sqrt(const HyperDualT<D>& a) {
  const double s = std::sqrt(a.value());
  return HyperDualT<D>::Apply(a, s, 0.5 / s, -0.25 / (s * a.value()));
}

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_POPULATION_HYPER_DUAL_H_
