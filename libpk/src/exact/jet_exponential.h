// The exponential of a matrix over a commutative algebra of "jets" (not installed): X = Σ_a X_a e_a,
// one w×w part per basis element e_a, multiplied by a product table, (XY)_t = Σ over the table's
// entries (t, a, b) of X_a Y_b. exact/third_order.cc takes it for truncated Taylor series in p
// variables to degree 3: a part per monomial, its coefficient ∂^α/α!, and (XY)_γ = Σ_{α+β=γ} X_α Y_β.
// (Dual numbers in d directions, a part per subset, are another such algebra; the tests use them.)
//
// A stacked linear system whose matrix has the block A_a at (t, b) for each entry (t, a, b) is the
// jet A written out as a square matrix, and e^{Mh} is the jet exp(hA) written out the same way.
// Exponentiating the jet costs one w×w product per table entry and product, against (parts·w)³/w³
// for the dense matrix: 84 against 8000 for the 20 monomials of degree ≤ 3 in three variables.
//
// Scaling and squaring with a truncated Taylor series: X/2^s with Σ_a ‖X_a‖₁ ≤ 1/16 (that sum
// bounds the jet's own norm), the series to degree 10 (remainder below (1/16)^11/11! ≈ 1e-21 of
// the leading term), then s squarings, as Higham's scaling and squaring does for one matrix.
#ifndef PK_SRC_EXACT_JET_EXPONENTIAL_H_
#define PK_SRC_EXACT_JET_EXPONENTIAL_H_

#include <array>
#include <vector>

#include <Eigen/Core>

namespace pk {
namespace internal {

/// A jet's parts, one per basis element.
using Jet = std::vector<Eigen::MatrixXd>;

/// The multiplication of an algebra of jets: `parts` basis elements, element 0 the unit, and the
/// entries (t, a, b): e_a e_b contributes to e_t.
struct JetProducts {
  int parts = 1;
  std::vector<std::array<int, 3>> entries;
};

/// *x = exp(*x) in the algebra, in place (its parts' storage is reused from call to call). Every
/// part square and of one size, x->size() == algebra.parts. Throws NumericalFailure when X is not
/// finite.
void JetExponential(const JetProducts& algebra, Jet* x);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_EXACT_JET_EXPONENTIAL_H_
