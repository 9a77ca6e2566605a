// One sample's term of ½∇²_ηη l, element (a, b), written once for any scalar (not installed): doubles
// for Laplace's H at the mode (conditional.cc), population/hyper_dual.h's scalar for the gradient
// of log det H (outer_gradient.cc).
//
// From the sample's derivatives in η: g = ∂f/∂η and ∂²f (ff) of the compared f = T(ŷ), v = ∂V/∂η
// and ∂²V (vv) of its variance; r = y − f and w = 1/V. For a value, ½∂²[r²/V + log V] with ∂r = −g:
//   w g_a g_b − r w ff + r w² (g_a v_b + v_a g_b) + (r² w³ − ½ w²) v_a v_b + ½ (w − r² w²) vv.
// For a censored sample (M3, sign = CENS ≠ 0), ½∂²[−2 log Φ(z)] = m(z + m) ∂z_a ∂z_b − m ∂²z with
// z = sign·r·√w, m = φ(z)/Φ(z), ∂z = −sign·g √w − ½ z w v and
// ∂²z = −sign·ff √w + ½ sign (g_a v_b + v_a g_b) w^{3/2} + ¾ z w² v_a v_b − ½ z w vv.
#ifndef PK_SRC_POPULATION_HALF_HESSIAN_TERM_H_
#define PK_SRC_POPULATION_HALF_HESSIAN_TERM_H_

namespace pk {
namespace internal {

/// What HalfHessianTerm needs of a sample beyond its derivatives.
template <class S>
struct SampleScale {
  S r, w, root_w;  ///< residual, 1/V and √(1/V)
  double sign;     ///< CENS: 0 for a value
  S z, m;          ///< M3's z and inverse Mills ratio (sign ≠ 0)
};

template <class S>
S HalfHessianTerm(const SampleScale<S>& k, const S& ga, const S& gb, const S& va, const S& vb, const S& ff,
                  const S& vv) {
  const S gv = ga * vb + va * gb;
  if (k.sign == 0) {
    return k.w * ga * gb - k.r * k.w * ff + k.r * k.w * k.w * gv +
           (k.r * k.r * k.w * k.w * k.w - 0.5 * k.w * k.w) * va * vb + 0.5 * (k.w - k.r * k.r * k.w * k.w) * vv;
  }
  const double s = k.sign;
  const S dza = -s * k.root_w * ga - 0.5 * k.z * k.w * va, dzb = -s * k.root_w * gb - 0.5 * k.z * k.w * vb;
  const S d2z = -s * k.root_w * ff + 0.5 * s * k.w * k.root_w * gv + 0.75 * k.z * k.w * k.w * va * vb -
                0.5 * k.z * k.w * vv;
  return k.m * (k.z + k.m) * dza * dzb - k.m * d2z;
}

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_POPULATION_HALF_HESSIAN_TERM_H_
