// Exact discretisation of dx/dt = A x + B u for one parameter set (not installed).
//
// For each step length h it gives Φ(h) = e^{Ah} and Γ(h) = ∫₀ʰ e^{As} ds B
// (B = [I; 0]: inputs enter the first n_in states), their derivatives with
// respect to the parameters (given as ∂A/∂θ_j), and the discrete adjoint's
// parameter gradient.
//
// Values always come from the Padé exponential (Eigen's MatrixFunctions):
// exp(Ah) alone for a step without input, Van Loan's exp([[A, B],[0, 0]]h) =
// [[Φ, Γ],[0, I]] for a step with one. Scaling and squaring keeps the
// structure of A (a depot that only empties stays exactly e^{−KA h}), so small
// amounts keep their relative accuracy; an eigendecomposition would give only
// normwise accuracy there.
//
// Derivatives take one of two exact paths, chosen per parameter set and step:
//
//  * Eigendecomposition (fast): when A = V Λ V⁻¹ with real eigenvalues and a
//    well-conditioned V (κ₁(V) ≤ 1e3; the derivatives carry errors of about κ²ε). Reversible exchange between volumes
//    makes T⁻¹AT symmetric for a diagonal T (found from the graph), and then
//    the symmetric eigensolver gives V = TQ with Q orthogonal; otherwise (a
//    one-way depot) the general real eigensolver is used.
//      ∂Φ/∂θ_j = V (F ∘ (V⁻¹ A_j V)) V⁻¹          (Daleckii–Krein)
//    with F_ik the divided difference of e^{λh}, computed stably as
//      h e^{(λ_i+λ_k)h/2} sinh(δ)/δ,  δ = (λ_i − λ_k)h/2,
//    which is also right for coincident eigenvalues. For the adjoint,
//      Σ λ'ᵀ ∂Φ/∂θ_j x = ⟨V⁻ᵀ Z Vᵀ, A_j⟩,   Z = Σ F ∘ ((Vᵀλ')(V⁻¹x)ᵀ),
//    so each step costs O(n²) and each set O(n³), whatever the number of θ_j.
//  * Block exponentials (general): the seed's 5.4/5.7 block-triangular
//    exp([[M, 0],[M_j, M]]h), M = [[A, B],[0, 0]], for the sensitivities, and
//    one Fréchet derivative per distinct h for the adjoint.
//    Used when the eigendecomposition is complex or ill-conditioned (nearly
//    coincident eigenvalues of a non-normal A, as in flip-flop KA ≈ CL/V), and
//    for steps with an input, whose ∂Γ this class takes from the block form.
#ifndef PK_SRC_EXACT_DISCRETIZATION_H_
#define PK_SRC_EXACT_DISCRETIZATION_H_

#include <cmath>
#include <map>
#include <memory>
#include <vector>

#include <Eigen/Core>
#include <Eigen/LU>

#include "jet_exponential.h"

namespace pk {
namespace internal {

/// sinh(d)/d, accurate near 0.
double Sinhc(double d);

/// A diagonal T with T⁻¹AT symmetric, when one exists: reversible exchange
/// (clearance flows between compartments with volumes) gives A_ij t_j/t_i =
/// A_ji t_i/t_j, so t_j = t_i sqrt(A_ji/A_ij) along every edge of the graph.
/// False for one-way flow (a depot), an inconsistent cycle, or a ratio of
/// rates beyond double range (a t_j that would underflow or overflow).
template <typename Mat, typename Vec>
bool SymmetrizingDiagonal(const Mat& a, Vec* t) {
  const int n = static_cast<int>(a.rows());
  *t = Vec::Zero(n);
  for (int root = 0; root < n; ++root) {
    if ((*t)(root) != 0) continue;
    (*t)(root) = 1;
    // Graph search without a heap: the visited set grows until no edge adds to it.
    for (bool grew = true; grew;) {
      grew = false;
      for (int i = 0; i < n; ++i) {
        if ((*t)(i) == 0) continue;
        for (int j = 0; j < n; ++j) {
          if (j == i || (a(i, j) == 0 && a(j, i) == 0)) continue;
          if (!(a(i, j) * a(j, i) > 0)) return false;
          const double tj = (*t)(i) * std::sqrt(a(j, i) / a(i, j));
          // t_j = 0 would be "unvisited" again on the next pass: the search would never end.
          if (!(tj > 0) || !std::isfinite(tj)) return false;
          if ((*t)(j) == 0) {
            (*t)(j) = tj;
            grew = true;
          } else if (std::fabs((*t)(j) - tj) > 1e-12 * tj) {
            return false;
          }
        }
      }
    }
  }
  return true;
}

class Discretization {
 public:
  struct Step {
    Eigen::MatrixXd phi;    // N×N
    Eigen::MatrixXd gamma;  // N×n_in; empty until a step with input asks for it
  };
  struct Sensitivity {
    std::vector<Eigen::MatrixXd> dphi;    // one per dA entry
    std::vector<Eigen::MatrixXd> dgamma;  // empty unless requested
  };

  /// `allow_eigen` = false forces the block-exponential path (for tests). With `jet`, `a` is a
  /// stacked jet matrix (jet_exponential.h: the block A_a at (t, b) for each of the algebra's
  /// entries, parts of n_in states, inputs into part 0), and Φ and Γ come from the jet's exponential,
  /// not the dense one.
  Discretization(Eigen::MatrixXd a, int n_in, bool allow_eigen = true,
                 std::shared_ptr<const JetProducts> jet = nullptr);

  /// Whether derivatives use the eigendecomposition (computed on first use).
  bool eigen_path();
  const Eigen::MatrixXd& A() const { return a_; }

  /// Φ(h), and Γ(h) too when `with_gamma`.
  const Step& Get(double h, bool with_gamma = true);
  /// The step of a cached length *at with ‖A‖₁·|h − *at| ≤ 2⁻³⁰ (h itself when none is): grids of
  /// output times computed as k·Δ give step lengths a few ulps apart. Then
  ///   Φ(h) = Φ(at)(I + Aδ) + O((‖A‖δ)²),   Γ(h) = Γ(at) + Φ(at)δB + O(δ²‖A‖),   δ = h − at,
  /// and the neglected terms are below 1e-18 of the step's size: the caller applies the correction
  /// (ExactPropagator::Advance) at the cost of one product with A instead of one exponential.
  const Step& GetNearby(double h, bool with_gamma, double* at);
  /// ∂Φ (and ∂Γ when `with_gamma`) for each of `da` (∂A/∂θ_j, the same list on every call).
  const Sensitivity& GetSensitivity(double h, bool with_gamma, const std::vector<Eigen::MatrixXd>& da);

  /// Records one step x⁺ = Φx + Γu with adjoint λ' of x⁺, for the θ gradient
  /// (an empty `u` means no input).
  void AccumulateAdjoint(double h, const Eigen::VectorXd& lambda_after, const Eigen::VectorXd& x_before,
                         const Eigen::VectorXd& u);
  /// The n×n matrix G with ⟨G, ∂A/∂θ_j⟩ = Σ over recorded steps of
  /// λ'ᵀ(∂Φ/∂θ_j x + ∂Γ/∂θ_j u), for every θ_j at once; clears the record.
  Eigen::MatrixXd FinishAdjoint();

  long exponentials() const { return exponentials_; }

 private:
  const Eigen::MatrixXd& DividedDifferences(double h);
  void JetStep(double h, bool with_gamma, Step* step);
  void Decompose();
  Sensitivity BlockSensitivity(double h, const std::vector<Eigen::MatrixXd>& da);

  Eigen::MatrixXd a_;
  double a_norm_ = -1;  // ‖A‖₁, computed on GetNearby's first call
  int n_;
  int n_in_;
  bool allow_eigen_;
  std::shared_ptr<const JetProducts> jet_;
  bool decomposed_ = false;
  bool eigen_ = false;
  Eigen::VectorXd lambda_;
  Eigen::MatrixXd v_, w_;  // V and V⁻¹
  std::vector<std::pair<double, Step>> steps_;
  std::vector<std::pair<double, Sensitivity>> sens_;
  std::vector<std::pair<double, Sensitivity>> sens_gamma_;
  std::vector<std::pair<double, Eigen::MatrixXd>> divided_;
  Eigen::MatrixXd z_;                                 // eigen-path adjoint accumulator
  std::vector<std::pair<double, Eigen::MatrixXd>> frechet_;  // block-path accumulators
  long exponentials_ = 0;
};

/// The steady state before a dose of a periodic dosing cycle: one period adds
/// `bolus` and then runs through `segments` (step length, input rates), an
/// affine map P(x) = M (x + b) + w. The fixed point solves (I − M) x* = M b + w.
/// Only the first `n` states take part (the simulator's AUC row does not).
struct PeriodicSteadyState {
  Eigen::VectorXd x_star;
  Eigen::MatrixXd m;
  Eigen::PartialPivLU<Eigen::MatrixXd> lu;  ///< of I − M, for implicit derivatives
};
/// Throws NumericalFailure when I − M is singular (no elimination).
PeriodicSteadyState SolvePeriodicSteadyState(Discretization* d, int n, const Eigen::VectorXd& bolus,
                                             const std::vector<std::pair<double, Eigen::VectorXd>>& segments);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_EXACT_DISCRETIZATION_H_
