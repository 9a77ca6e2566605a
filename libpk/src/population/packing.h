// The population parameters as one vector (not installed): the unconstrained vector x the outer
// optimiser moves, and the natural-scale values (θ, Ω's elements, σ) the tables and the
// covariance step use.
//
//   x = [ log θ_k (θ_k > 0) or θ_k (a signed parameter), for each estimated θ;
//         for each estimated Ω block, its Cholesky factor L (Ω = LLᵀ) by rows:
//         log L_kk on the diagonal, L_kl below it;
//         log σ_j, for each estimated σ ]
//
// so that every x gives a positive definite Ω and positive θ and σ.
#ifndef PK_SRC_POPULATION_PACKING_H_
#define PK_SRC_POPULATION_PACKING_H_

#include <string>
#include <vector>

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
  Eigen::VectorXd Pack(const PopulationParameters& p) const;
  /// The parameters at x; the fixed parts are the initial values.
  PopulationParameters Unpack(const Eigen::VectorXd& x) const;

  /// Natural-scale names (CL, OMEGA(CL), OMEGA(V,CL), SIGMA_ADD), values and fixed flags, over
  /// θ, the lower triangle of each Ω block, and σ.
  const std::vector<std::string>& natural_names() const { return names_; }
  const std::vector<bool>& natural_fixed() const { return fixed_; }
  Eigen::VectorXd Natural(const PopulationParameters& p) const;
  PopulationParameters FromNatural(const Eigen::VectorXd& z) const;
  /// Positions (in natural order) of the variances ω_kk, for boundary checks.
  std::vector<int> variance_positions() const;

 private:
  struct Block {
    int first = 0, size = 1;
    bool fixed = false;
  };
  PopulationParameters initial_;
  std::vector<bool> theta_fixed_, sigma_fixed_, theta_log_;
  std::vector<Block> blocks_;
  std::vector<std::string> names_;
  std::vector<bool> fixed_;
  int size_ = 0;
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_POPULATION_PACKING_H_
