// The population parameters as one vector (not installed): the unconstrained vector x the outer
// optimiser moves, and the natural-scale values (θ, Ω's elements, σ) the tables and the
// covariance step use.
//
//   x = [ for each estimated θ: log θ_k (θ_k > 0) or θ_k (a signed parameter); within a model
//         file's bounds (lo, hi), log((θ − lo)/(hi − θ)), or log(θ − lo) or log(hi − θ) with one
//         bound (NONMEM's $THETA (low, init, up): the search never leaves them);
//         for each estimated Ω block, its Cholesky factor L (Ω = LLᵀ) by rows:
//         log L_kk on the diagonal, L_kl below it (a SAME block has none: its L is its source's);
//         log σ_j, for each estimated σ ]
//
// so that every x gives a positive definite Ω and positive θ and σ.
#ifndef PK_SRC_POPULATION_PACKING_H_
#define PK_SRC_POPULATION_PACKING_H_

#include <cmath>
#include <string>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Core>

#include "pk/population.h"

namespace pk {
namespace internal {

class Packing {
 public:
  /// Throws pk::InputError for a structure that does not fit the problem or `initial` outside
  /// the domain (θ or σ not positive, an Ω block not positive definite, Ω not block diagonal).
  Packing(const PopulationProblem& problem, const PopulationStructure& structure, const PopulationParameters& initial);

  int size() const { return size_; }
  /// The initial parameters with each SAME block set to its source's values (the start of a fit).
  const PopulationParameters& initial() const { return initial_; }
  Eigen::VectorXd Pack(const PopulationParameters& p) const;
  /// The parameters at x; the fixed parts are the initial values.
  PopulationParameters Unpack(const Eigen::VectorXd& x) const;

  /// Natural-scale names (CL, OMEGA(CL), OMEGA(V,CL), SIGMA_ADD), values and fixed flags, over
  /// θ, the lower triangle of each Ω block, and σ.
  const std::vector<std::string>& natural_names() const { return names_; }
  const std::vector<bool>& natural_fixed() const { return fixed_; }
  /// Whether each natural parameter belongs to a SAME block (also flagged fixed there: it is not a
  /// parameter of its own, its value is its source block's).
  const std::vector<bool>& natural_same() const { return same_; }
  /// The natural parameter a SAME block's element k repeats (k itself for any other).
  int NaturalSource(size_t k) const;
  Eigen::VectorXd Natural(const PopulationParameters& p) const;
  PopulationParameters FromNatural(const Eigen::VectorXd& z) const;
  /// Whether θ_k lies within 1e-3 of the width of its bounds (or, with one bound, 1e-3 of the
  /// largest of |θ_k|, |bound|, |initial θ_k| and 1e-8) of a model file's bound: NONMEM's
  /// "estimate near its boundary".
  bool NearThetaBound(size_t k, double theta) const;
  /// Positions (in natural order) of the variances ω_kk, for boundary checks.
  std::vector<int> variance_positions() const;

  /// Unpack on another scalar type (the exact gradient's HyperDual): θ, σ and the lower Cholesky
  /// factor L of Ω (q×q, block diagonal, Ω = LLᵀ) as functions of x; `constant` makes a T from a
  /// double (the fixed parts and the zeros).
  template <typename T, typename Constant>
  void UnpackAs(const std::vector<T>& x, const Constant& constant, std::vector<T>* theta, std::vector<T>* sigma,
                std::vector<std::vector<T>>* l) const {
    using std::exp;  // pk::exp(Dual) would hide it for T = double
    size_t at = 0;
    theta->clear();
    for (size_t k = 0; k < theta_fixed_.size(); ++k) {
      const double v = initial_.theta(static_cast<Eigen::Index>(k));
      theta->push_back(theta_fixed_[k] ? constant(v) : ThetaOf(k, x[at++], constant));
    }
    const auto q = static_cast<size_t>(initial_.omega.rows());
    l->assign(q, std::vector<T>(q, constant(0.0)));
    for (const Block& b : blocks_) {
      const Eigen::MatrixXd fixed = initial_.omega.block(b.first, b.first, b.size, b.size).llt().matrixL();
      const int source = b.same < 0 ? -1 : blocks_[static_cast<size_t>(b.same)].first;
      for (int r = 0; r < b.size; ++r) {
        for (int c = 0; c <= r; ++c) {
          T& e = (*l)[static_cast<size_t>(b.first + r)][static_cast<size_t>(b.first + c)];
          if (source >= 0) {  // SAME: the source block's factor, unpacked before this block
            e = (*l)[static_cast<size_t>(source + r)][static_cast<size_t>(source + c)];
          } else {
            e = b.fixed ? constant(fixed(r, c)) : r == c ? exp(x[at++]) : x[at++];
          }
        }
      }
    }
    sigma->clear();
    for (size_t j = 0; j < sigma_fixed_.size(); ++j) {
      sigma->push_back(sigma_fixed_[j] ? constant(initial_.sigma(static_cast<Eigen::Index>(j))) : exp(x[at++]));
    }
  }

 private:
  // θ_k from its x (the transform above), on any scalar type.
  template <typename T, typename Constant>
  T ThetaOf(size_t k, const T& x, const Constant& constant) const {
    using std::exp;  // pk::exp(Dual) would hide it for T = double
    const double lo = theta_lower_[k], hi = theta_upper_[k];
    if (std::isfinite(lo) && std::isfinite(hi)) {
      return constant(lo) + (constant(1.0) / (constant(1.0) + exp(-x))) * (hi - lo);
    }
    if (std::isfinite(lo)) return constant(lo) + exp(x);
    if (std::isfinite(hi)) return constant(hi) - exp(x);
    return theta_log_[k] ? exp(x) : x;
  }
  double XOf(size_t k, double theta) const;
  struct Block;
  void SameAsBefore(const PopulationProblem& problem, const std::vector<int>& sizes, Block* block);

  struct Block {
    int first = 0, size = 1;
    bool fixed = false;
    int same = -1;     // SAME: the index of the block whose values it repeats (never itself a SAME), or -1
    int natural = 0;   // the position of its first entry among the natural parameters
  };
  PopulationParameters initial_;
  std::vector<bool> theta_fixed_, sigma_fixed_, theta_log_;
  std::vector<double> theta_lower_, theta_upper_;  // a model file's declared bounds (±∞: none)
  std::vector<Block> blocks_;
  std::vector<std::string> names_;
  std::vector<bool> fixed_, same_;
  int size_ = 0;
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_POPULATION_PACKING_H_
