// libpk: a forward-mode scalar with a fixed number of derivative lanes.
//
// pk::Dual carries as many derivatives as it is given, in a heap vector. FixedDual<W> carries exactly
// W of them in place, so an evaluation allocates nothing and each operation is a short loop the
// compiler vectorises. libpk evaluates a model's right-hand side on it for a compressed Jacobian:
// columns of [f_x f_θ] that never meet in a row share a lane (Curtis, Powell and Reid's column
// colouring), so W lanes give every nonzero of a sparse Jacobian at once. The one-step method's
// discrete adjoint takes its vector–Jacobian products from there (src/ode/coloured_jacobian.h). A model
// never uses this type directly; its Rhs only has to be a template on the scalar type.
//
// Values are computed with the same double operations as the model on double, so f is the same bits.
#ifndef PK_FIXED_DUAL_H_
#define PK_FIXED_DUAL_H_

#include <cmath>
#include <cstring>

namespace pk {

template <int W>
class FixedDual {
 public:
  static_assert(W > 0, "FixedDual needs at least one lane");
  FixedDual() : FixedDual(0.0) {}
  FixedDual(double value) : v_(value) {  // NOLINT: constants convert implicitly
    for (int j = 0; j < W; ++j) d_[j] = 0;
  }
  // Copied in the groups the operators store the lanes in (Lanewise). GCC copies a struct in 16-byte
  // pieces, and a copy of a result the operators had just stored 32 bytes at a time (or the value and
  // the first lane, stored apart) then waits for stores it cannot forward from: a model's temporaries
  // (a chain's inflow = out) made f on 8 lanes five times as slow as on 6, and on 6 lanes twice as slow
  // in a model with a loop-invariant branch (`if (leaky) dxdt[i] -= …`) compiled at -O3. Copied by
  // groups, each load matches a store.
  FixedDual(const FixedDual& o) noexcept : v_(o.v_) { CopyLanes(o); }
  FixedDual& operator=(const FixedDual& o) noexcept {
    v_ = o.v_;
    CopyLanes(o);
    return *this;
  }

  double value() const { return v_; }
  /// The derivative in lane j (0 ≤ j < W).
  double derivative(int j) const { return d_[j]; }
  double& derivative(int j) { return d_[j]; }
  /// Moves the value, keeping the lanes (an input seeded once, evaluated at many points).
  void set_value(double value) { v_ = value; }
  /// The W lanes, contiguous.
  const double* derivatives() const { return d_; }

  friend FixedDual operator+(const FixedDual& a, const FixedDual& b) {
    FixedDual r(Uninitialised{}, a.v_ + b.v_);
    Lanewise(&r, a, b, [](auto& z, const auto& x, const auto& y) { z = x + y; });
    return r;
  }
  friend FixedDual operator-(const FixedDual& a, const FixedDual& b) {
    FixedDual r(Uninitialised{}, a.v_ - b.v_);
    Lanewise(&r, a, b, [](auto& z, const auto& x, const auto& y) { z = x - y; });
    return r;
  }
  friend FixedDual operator*(const FixedDual& a, const FixedDual& b) {
    FixedDual r(Uninitialised{}, a.v_ * b.v_);
    const double av = a.v_, bv = b.v_;
    Lanewise(&r, a, b, [av, bv](auto& z, const auto& x, const auto& y) { z = x * bv + av * y; });
    return r;
  }
  friend FixedDual operator/(const FixedDual& a, const FixedDual& b) {
    // (a/b)' = (a' − (a/b) b') / b; the quotient exactly as in double.
    const double q = a.v_ / b.v_, inv = 1 / b.v_;
    FixedDual r(Uninitialised{}, q);
    Lanewise(&r, a, b, [q, inv](auto& z, const auto& x, const auto& y) { z = (x - q * y) * inv; });
    return r;
  }
  FixedDual operator-() const {
    FixedDual r(Uninitialised{}, -v_);
    Lanewise(&r, *this, *this, [](auto& z, const auto& x, const auto&) { z = -x; });
    return r;
  }
  FixedDual operator+() const { return *this; }
  FixedDual& operator+=(const FixedDual& o) { return *this = *this + o; }
  FixedDual& operator-=(const FixedDual& o) { return *this = *this - o; }
  FixedDual& operator*=(const FixedDual& o) { return *this = *this * o; }
  FixedDual& operator/=(const FixedDual& o) { return *this = *this / o; }

  // Comparisons look at the values only (a model may branch on them).
  friend bool operator<(const FixedDual& a, const FixedDual& b) { return a.v_ < b.v_; }
  friend bool operator>(const FixedDual& a, const FixedDual& b) { return a.v_ > b.v_; }
  friend bool operator<=(const FixedDual& a, const FixedDual& b) { return a.v_ <= b.v_; }
  friend bool operator>=(const FixedDual& a, const FixedDual& b) { return a.v_ >= b.v_; }

  /// f(v) with derivative f'(v)·d: the chain rule for the functions below. Where f'(v) is infinite
  /// (sqrt, log, pow at 0) a lane whose tangent is 0 stays 0, not 0·∞ = NaN: a lane holds several
  /// columns of a compressed Jacobian, and those that do not pass through v must keep their finite
  /// derivatives, as a reverse sweep gives them.
  FixedDual Chain(double f, double df) const {
    FixedDual r(Uninitialised{}, f);
    if (std::isfinite(df)) {
      Lanewise(&r, *this, *this, [df](auto& z, const auto& x, const auto&) { z = df * x; });
    } else {
      for (int j = 0; j < W; ++j) r.d_[j] = Times(df, d_[j]);
    }
    return r;
  }
  /// f(v, w) with partials: the chain rule for two arguments (infinite partials as in Chain).
  static FixedDual Chain2(double f, const FixedDual& x, double dx, const FixedDual& y, double dy) {
    FixedDual r(Uninitialised{}, f);
    if (std::isfinite(dx) && std::isfinite(dy)) {
      Lanewise(&r, x, y, [dx, dy](auto& z, const auto& a, const auto& b) { z = dx * a + dy * b; });
    } else {
      for (int j = 0; j < W; ++j) r.d_[j] = Times(dx, x.d_[j]) + Times(dy, y.d_[j]);
    }
    return r;
  }

 private:
  void CopyLanes(const FixedDual& o) {
    Lanewise(this, o, o, [](auto& z, const auto& x, const auto&) { z = x; });
  }
  static double Times(double partial, double tangent) { return tangent == 0 ? 0.0 : partial * tangent; }
  // r's lanes f(a_j, b_j), f generic in its arguments' type: two lanes at once where the compiler has
  // vector types (GCC and clang; SSE2 on every x86-64), each the same IEEE operations as on double, so
  // an operation is about W/2 instructions, where GCC left the plain loops scalar (a saturable chain's
  // f on 6 lanes: 3.9 ns a compartment against 5.4).
  template <typename F>
  static void Lanewise(FixedDual* r, const FixedDual& a, const FixedDual& b, F f) {
    int j = 0;
#if defined(__GNUC__)
    typedef double Four __attribute__((vector_size(32)));
    typedef double Two __attribute__((vector_size(16)));
    for (; j + 4 <= W; j += 4) Group<Four>(r->d_ + j, a.d_ + j, b.d_ + j, f);
    for (; j + 2 <= W; j += 2) Group<Two>(r->d_ + j, a.d_ + j, b.d_ + j, f);
#endif
    for (; j < W; ++j) f(r->d_[j], a.d_[j], b.d_[j]);
  }
  template <typename V, typename F>
  static void Group(double* r, const double* a, const double* b, F f) {
    V x, y, z;
    std::memcpy(&x, a, sizeof x);
    std::memcpy(&y, b, sizeof y);
    f(z, x, y);
    std::memcpy(r, &z, sizeof z);
  }
  struct Uninitialised {};
  FixedDual(Uninitialised, double value) : v_(value) {}  // every lane written by the caller
  double v_;
  double d_[W];
};

template <int W>
FixedDual<W> exp(const FixedDual<W>& x) {
  const double e = std::exp(x.value());
  return x.Chain(e, e);
}
template <int W>
FixedDual<W> log(const FixedDual<W>& x) {
  return x.Chain(std::log(x.value()), 1 / x.value());
}
template <int W>
FixedDual<W> sqrt(const FixedDual<W>& x) {
  const double s = std::sqrt(x.value());
  return x.Chain(s, 0.5 / s);
}
template <int W>
FixedDual<W> abs(const FixedDual<W>& x) {
  return x.value() < 0 ? -x : x;
}
template <int W>
FixedDual<W> fabs(const FixedDual<W>& x) {
  return abs(x);
}
/// x^p for a constant p, as pk::Dual and pk::TapeScalar take it.
template <int W>
FixedDual<W> pow(const FixedDual<W>& x, double p) {
  return x.Chain(std::pow(x.value(), p), p == 0 ? 0.0 : p * std::pow(x.value(), p - 1));
}
/// x^p; at x ≤ 0 the derivative with respect to p is taken as 0 (as for pk::TapeScalar).
template <int W>
FixedDual<W> pow(const FixedDual<W>& x, const FixedDual<W>& p) {
  const double v = std::pow(x.value(), p.value());
  const double dx = p.value() == 0 ? 0.0 : p.value() * std::pow(x.value(), p.value() - 1);
  const double dp = x.value() > 0 ? v * std::log(x.value()) : 0.0;
  return FixedDual<W>::Chain2(v, x, dx, p, dp);
}
template <int W>
FixedDual<W> pow(double x, const FixedDual<W>& p) {
  return pow(FixedDual<W>(x), p);
}

namespace internal {

// A model's f on lanes, compiled a second time for AVX2 (x86-64 CPUs since 2013). Debian builds for the
// x86-64 baseline (SSE2, two lanes an instruction); where the CPU has AVX2 the clone takes four. The
// clone inlines everything f calls (flatten), so the model's own template code, FixedDual's operators
// included, is compiled for AVX2 too. AVX2 brings no FMA (that is a separate flag), so the clone does
// the same IEEE operations in the same order as the baseline: the same bits (tests/test_coloured_jacobian.cc).
// The inlining is GCC's (flatten inlines recursively there, at -O1 and above); clang 14's flatten inlines
// only the calls written in CallOnAvx2, so under clang the model's code stays the baseline's, called from
// the clone: the same results, without the speed.
#if defined(__GNUC__) && defined(__x86_64__) && !defined(__AVX2__) && !defined(PK_NO_AVX2_LANES)
#define PK_AVX2_LANES 1
template <typename F>
__attribute__((target("avx2"), flatten)) void CallOnAvx2(const F& f) {
  f();
}
#endif

/// Whether this build has the AVX2 clone and this CPU can run it.
inline bool CpuRunsAvx2Clone() {
#ifdef PK_AVX2_LANES
  static const bool yes = __builtin_cpu_supports("avx2");
  return yes;
#else
  return false;
#endif
}

/// Whether CallOnLanes takes the AVX2 clone: CpuRunsAvx2Clone() at first. Tests and pkbench set it to
/// false to compare the two, only while no thread evaluates a model; setting it to true where
/// CpuRunsAvx2Clone() is false would run AVX2 instructions on a CPU without them.
inline bool& LanesOnAvx2() {
  static bool on = CpuRunsAvx2Clone();
  return on;
}

/// f() (an evaluation of a model on FixedDual lanes), through the AVX2 clone where LanesOnAvx2().
template <typename F>
void CallOnLanes(const F& f) {
#ifdef PK_AVX2_LANES
  if (LanesOnAvx2()) return CallOnAvx2(f);
#endif
  f();
}

}  // namespace internal
}  // namespace pk

#endif  // PK_FIXED_DUAL_H_
