// The exponential of a matrix over R[ε₁, …, ε_d]/(ε₁², …, ε_d²) (not installed): a "jet" X = Σ_S X_S ε^S,
// one w×w part per subset S of the d directions (bit masks, 2^d parts). Products of jets convolve
// over subsets, (XY)_S = Σ_{T ⊆ S} X_T Y_{S∖T}, 3^d part products in all.
//
// The higher-order sensitivities of exact/third_order.h step a stacked system whose matrix M has
// the block A_{S∖T} at (S, T): M is the jet A(ε) written out as a (2^d w)-square matrix, and e^{Mh}
// is the jet exp(hA(ε)) written out the same way. Exponentiating the jet costs 3^d products of w×w
// matrices per product, against (2^d w)³/w³ = 8^d for the dense matrix: 27 against 512 for d = 3.
//
// Scaling and squaring with a truncated Taylor series: X/2^s with Σ_S ‖X_S‖₁ ≤ 1/16 (that sum
// bounds the jet's own norm), the series to degree 10 (remainder below (1/16)^11/11! ≈ 1e-21 of
// the leading term), then s squarings, as Higham's scaling and squaring does for one matrix.
#ifndef PK_SRC_EXACT_JET_EXPONENTIAL_H_
#define PK_SRC_EXACT_JET_EXPONENTIAL_H_

#include <vector>

#include <Eigen/Core>

namespace pk {
namespace internal {

/// A matrix over the algebra of d nilpotent directions: parts[S] for every bit mask S < 2^d.
using Jet = std::vector<Eigen::MatrixXd>;

/// exp(X), part by part. Every part must be square and of one size; parts.size() a power of 2.
Jet JetExponential(Jet x);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_EXACT_JET_EXPONENTIAL_H_
