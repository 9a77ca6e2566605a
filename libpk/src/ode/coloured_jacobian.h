// Compressed sparse Jacobians of f for the one-step method's discrete adjoint (not installed).
//
// The adjoint needs wᵀ[f_x f_θ] at every stage X_i of every step (rk_solver.cc). A recording of f on
// the tape and a sweep of it cost about ten evaluations of f for a cheap right-hand side
// (docs/performance.md §9). When the Jacobian is sparse, forward mode is cheaper: columns that never
// share a row are given one lane of pk::FixedDual<W> (Curtis, Powell and Reid 1974), so one evaluation
// of f on W lanes holds every nonzero, J_ik = (f_i)'[colour(k)], and wᵀJ is a sum over the nonzeros.
// A chain of compartments, where f_i reads x_{i−1}, x_i and their transfer parameters, needs 6 lanes
// whatever its length. The pattern is found once per model by evaluating f on pk::SparsityScalar; a
// model whose f looks at a value (a branch could change the pattern) keeps the tape, as does one that
// needs more than 8 lanes.
#ifndef PK_SRC_ODE_COLOURED_JACOBIAN_H_
#define PK_SRC_ODE_COLOURED_JACOBIAN_H_

#include <algorithm>
#include <memory>
#include <vector>

#include <Eigen/Core>

#include "pk/fixed_dual.h"
#include "pk/ode_model.h"

namespace pk {
namespace internal {

/// The sparsity pattern of [f_x f_θ] (columns x_0…x_{n−1}, then θ_0…θ_{m−1}) and a colouring of its
/// columns in which no two columns of a colour share a row.
struct JacobianColouring {
  int n = 0, m = 0;
  int colours = 0;  ///< lanes needed
  int width = 0;    ///< lanes used (4, 6 or 8); 0: no compressed Jacobian for this model
  bool looks_at_values = false;  ///< f compared or read a value: the pattern may change with x, θ
  bool sets_every_row = false;   ///< f wrote each row without reading it first (no need to zero them)
  std::vector<int> colour;        ///< of each column
  std::vector<int> column_start;  ///< column k's rows are rows[column_start[k], column_start[k + 1])
  std::vector<int> rows;
  /// For each nonzero, where a row-major n × width array of a stage's lanes holds it: rows[p]·width +
  /// the colour of its column.
  std::vector<int> lane_offset;
  /// The lanes from which θ's products are summed, [theta_lanes_begin, width): the least colour of a θ
  /// column with a nonzero, rounded down to even (lanes go two at a time); width when θ has none. On a
  /// chain the x columns take colours 0 and 1, and the sweep skips them.
  int theta_lanes_begin = 0;
  /// Every x column with a nonzero has a colour below theta_lanes_begin: the sweep keeps the weighed
  /// lanes [theta_lanes_begin, width) only in the running sum.
  bool x_lanes_below_theta = false;
  /// The x columns' nonzeros as Sweep sums them: slot j of column k at x_gather[j·n + k] (the same
  /// offsets as lane_offset, in row order), a column with fewer than x_slots nonzeros padded with n·width,
  /// where the sweep keeps a 0. Adding +0 after a sum begun at +0 leaves its bits alone, so the padded
  /// sums are the unpadded ones, and a slot at a time is a loop without branches over the columns.
  int x_slots = 0;
  std::vector<int> x_gather;
};

/// Lanes of f kept at many stages, for an adjoint that keeps the forward pass's stages instead of
/// evaluating them again backward (ColouredJacobian::RecordSlot): slot k holds n numbers with their
/// lanes. Only the vector of the colouring's width is used.
struct StageSlots {
  std::vector<FixedDual<4>> lanes4;
  std::vector<FixedDual<6>> lanes6;
  std::vector<FixedDual<8>> lanes8;
  /// Numbers held (lanes included), for the adjoint's storage figures.
  size_t doubles() const { return 5 * lanes4.size() + 7 * lanes6.size() + 9 * lanes8.size(); }
};

/// wᵀf_x and wᵀf_θ at the stages of one step, as StageTape (ode_system.h) offers them, from a compressed
/// Jacobian at each stage: Record evaluates f once on FixedDual<W> and keeps the stage's lanes, Sweep
/// weighs them by w and sums each x column's nonzeros; the θ columns' sums wait for ThetaProduct.
class ColouredJacobian {
 public:
  /// The model's colouring, found at its first use on this thread (the last few models are kept).
  static std::shared_ptr<const JacobianColouring> ColouringOf(const OdeModel& model);
  /// Null when the model has no compressed Jacobian (JacobianColouring::width == 0).
  static std::unique_ptr<ColouredJacobian> For(const OdeModel& model, const Eigen::VectorXd& theta);

  void NewStep() { stages_ = 0; }
  /// Lanes an evaluation uses (4, 6 or 8).
  int width() const { return c_.width; }
  void Record(const Eigen::VectorXd& x, Eigen::VectorXd* f);
  void Record(const Eigen::VectorXd& x, double* f);  // n numbers at f
  void Sweep(int stage, const Eigen::VectorXd& w, Eigen::VectorXd* wfx);
  void Sweep(int stage, const Eigen::VectorXd& w, double* wfx);  // n numbers at wfx
  /// f at x on the lanes into slot `slot` < `limit` of *slots (which grows to hold it, to at most
  /// `limit` slots), its value into n numbers at f: a stage kept for SweepSlot. Does not touch the
  /// step's stages above.
  void RecordSlot(StageSlots* slots, size_t slot, size_t limit, const Eigen::VectorXd& x, double* f);
  /// Sweep's products at a kept slot.
  void SweepSlot(const StageSlots& slots, size_t slot, const Eigen::VectorXd& w, double* wfx);
  /// StateRowSumNorm at the point a kept slot was recorded at, from its lanes (no evaluation).
  double StateRowSumNormAt(const StageSlots& slots, size_t slot);
  /// Σ wᵀf_θ over every stage swept since construction or the last ResetProducts.
  Eigen::VectorXd ThetaProduct() const;
  void ResetProducts() { std::fill(weighted_sum_.begin(), weighted_sum_.end(), 0.0); }
  /// ‖f_x(x)‖∞ (the largest row sum of |f_x|) from one evaluation on the lanes; NaN or ∞ as f gives it.
  /// Does not touch the step's stages.
  double StateRowSumNorm(const Eigen::VectorXd& x);

 private:
  ColouredJacobian(const OdeModel& model, std::shared_ptr<const JacobianColouring> colouring,
                   const Eigen::VectorXd& theta);
  static bool EvaluatesOnLanes(const OdeModel& model, int width);
  template <int W>
  static bool EvaluatesOnLanes(const OdeModel& model);
  template <int W>
  struct Lanes {
    std::vector<FixedDual<W>> x, theta;
    std::vector<FixedDual<W>> f;        // f at each stage recorded this step, n a stage
    std::vector<FixedDual<W>> scratch;  // StateRowSumNorm's evaluation
  };
  template <int W>
  void Seed(const Eigen::VectorXd& theta, Lanes<W>* lanes);
  template <int W>
  void Evaluate(const Eigen::VectorXd& x, Lanes<W>* lanes, FixedDual<W>* out);
  template <int W>
  double RowSumNorm(const Eigen::VectorXd& x, Lanes<W>* lanes);
  template <int W>
  double RowSumNormOf(const FixedDual<W>* f);
  template <int W>
  void SweepLanes(const FixedDual<W>* lanes, const double* w, double* wfx);
  // f at x on the lanes into slot `slot` of *store (n lanes a slot; it grows to hold it, by doubling up
  // to `limit` slots), values into f.
  template <int W>
  void RecordInto(std::vector<FixedDual<W>>* store, size_t slot, size_t limit, const Eigen::VectorXd& x,
                  Lanes<W>* lanes, double* f);
  // Slot `slot` of a store of kept stages; throws std::logic_error when it was never recorded.
  template <int W>
  const FixedDual<W>* KeptSlot(const std::vector<FixedDual<W>>& store, size_t slot) const;

  const OdeModel& model_;
  std::shared_ptr<const JacobianColouring> colouring_;
  const JacobianColouring& c_;
  Lanes<4> lanes4_;
  Lanes<6> lanes6_;
  Lanes<8> lanes8_;
  int stages_ = 0;
  std::vector<double> weighted_sum_;  // n × width: w_i times lane l of f_i, summed over every stage swept
  // n × width + 1: the stage being swept's w_i times lane l of f_i, then a 0 that is never written
  // (JacobianColouring::x_gather's padding).
  std::vector<double> weighed_;
  std::vector<double> row_sums_;      // StateRowSumNorm's
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_ODE_COLOURED_JACOBIAN_H_
