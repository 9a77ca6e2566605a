// A second-order forward-mode scalar (not installed): a value with its gradient in d variables
// z and the rows of its Hessian that belong to the first q of them. The exact outer gradient
// (outer_gradient.cc) evaluates the conditional objective on it over z = (η, x) and needs ∇l, ∇L
// and only the η rows of ∇²l (∇²_ηη l and ∇²_ηx l): q × d second derivatives, not d × d.
//
// pk::Dual carries first derivatives only, and nesting it is not supported, so this small type
// carries the second-order terms explicitly (rows a < q, columns b < d):
//   (ab)_ab = a_ab b + a b_ab + a_a b_b + b_a a_b,   φ(a)_ab = φ'(a) a_ab + φ''(a) a_a a_b.
#ifndef PK_SRC_POPULATION_HYPER_DUAL_H_
#define PK_SRC_POPULATION_HYPER_DUAL_H_

#include <cmath>

#include <Eigen/Core>

namespace pk {
namespace internal {

/// The derivatives a HyperDual carries: first derivatives in d variables, second derivatives in
/// the first q of them (with every variable).
struct HyperDualShape {
  int q = 0;
  int d = 0;
};

/// MaxQ and MaxD bound q and d at compile time, which keeps the gradient and the Hessian's rows on
/// the stack (no allocation per operation); Eigen::Dynamic allows any number, on the heap.
template <int MaxQ, int MaxD>
class HyperDualT {
 public:
  using Vector = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, MaxD, 1>;
  using Matrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, MaxQ, MaxD>;
  using HyperDual = HyperDualT;

  HyperDualT() = default;
  /// A constant.
  HyperDualT(double v, HyperDualShape s) : v_(v), g_(Vector::Zero(s.d)), h_(Matrix::Zero(s.q, s.d)) {}
  /// Variable i.
  static HyperDual Variable(double v, HyperDualShape s, int i) {
    HyperDual x(v, s);
    x.g_(i) = 1;
    return x;
  }

  double value() const { return v_; }
  const Vector& gradient() const { return g_; }
  /// ∂²/∂z_a∂z_b for a < q (rows) and every b (columns).
  const Matrix& hessian() const { return h_; }
  HyperDualShape shape() const { return {static_cast<int>(h_.rows()), static_cast<int>(g_.size())}; }

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
    // Written out over raw storage: as an Eigen expression each outer product becomes a temporary
    // of the maximum size, and the dynamic-size loops cost several times the arithmetic.
    const Eigen::Index q = h_.rows(), d = h_.cols();
    double* h = h_.data();
    const double *oh = o.h_.data(), *g = g_.data(), *og = o.g_.data();
    const double v = v_, ov = o.v_;
    for (Eigen::Index b = 0; b < d; ++b) {
      for (Eigen::Index a = 0; a < q; ++a) {
        h[b * q + a] = h[b * q + a] * ov + oh[b * q + a] * v + g[a] * og[b] + og[a] * g[b];
      }
    }
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
    const Eigen::Index q = a.h_.rows(), d = a.h_.cols();
    r.h_.resize(q, d);
    double* h = r.h_.data();
    const double *ah = a.h_.data(), *g = a.g_.data();
    for (Eigen::Index b = 0; b < d; ++b) {
      for (Eigen::Index i = 0; i < q; ++i) h[b * q + i] = df * ah[b * q + i] + d2f * g[i] * g[b];
    }
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

template <int Q, int D> HyperDualT<Q, D> operator+(HyperDualT<Q, D> a, const HyperDualT<Q, D>& b) { return a += b; }
template <int Q, int D> HyperDualT<Q, D> operator-(HyperDualT<Q, D> a, const HyperDualT<Q, D>& b) { return a -= b; }
template <int Q, int D> HyperDualT<Q, D> operator*(HyperDualT<Q, D> a, const HyperDualT<Q, D>& b) { return a *= b; }
template <int Q, int D> HyperDualT<Q, D> operator/(HyperDualT<Q, D> a, const HyperDualT<Q, D>& b) { return a /= b; }
template <int Q, int D> HyperDualT<Q, D> operator*(HyperDualT<Q, D> a, double c) { return a *= c; }
template <int Q, int D> HyperDualT<Q, D> operator*(double c, HyperDualT<Q, D> a) { return a *= c; }
template <int Q, int D> HyperDualT<Q, D> operator+(HyperDualT<Q, D> a, double c) { return a += c; }
template <int Q, int D> HyperDualT<Q, D> operator-(HyperDualT<Q, D> a) { return a *= -1.0; }
template <int Q, int D> HyperDualT<Q, D> exp(const HyperDualT<Q, D>& a) {
  const double e = std::exp(a.value());
  return HyperDualT<Q, D>::Apply(a, e, e, e);
}
template <int Q, int D> HyperDualT<Q, D> log(const HyperDualT<Q, D>& a) {
  const double x = a.value();
  return HyperDualT<Q, D>::Apply(a, std::log(x), 1 / x, -1 / (x * x));
}
template <int Q, int D> HyperDualT<Q, D> sqrt(const HyperDualT<Q, D>& a) {
  const double s = std::sqrt(a.value());
  return HyperDualT<Q, D>::Apply(a, s, 0.5 / s, -0.25 / (s * a.value()));
}

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_POPULATION_HYPER_DUAL_H_
