// One subject of one replicate of a population simulation (pk/population_simulation.h), for the
// routes that need a subject's simulations together (NPDE) rather than whole replicates (VPC).
#ifndef PK_POPULATION_SIMULATOR_H_
#define PK_POPULATION_SIMULATOR_H_

#include <vector>

#include <Eigen/Core>

#include "pk/population_simulation.h"
#include "population/conditional.h"
#include "population/problem_impl.h"

namespace pk {
namespace internal {

/// A simulation of `problem` at `parameters`, checked once. Subject i of replicate r draws from
/// the streams of (options.seed, r, i), whichever route asks for it.
class PopulationSimulator {
 public:
  /// Throws pk::InputError for invalid options, an Ω that is not positive semi-definite, or
  /// parameters that do not fit the problem. Keeps references to its arguments.
  PopulationSimulator(const PopulationProblem& problem, const PopulationParameters& parameters,
                      const PopulationSimulationOptions& options);
  int num_subjects() const { return static_cast<int>(subjects_.size()); }
  /// Subject `subject` (its position in the problem) of replicate `replicate` (0-based).
  SimulatedSubject Subject(int replicate, int subject) const;
  /// Replicate r, its subjects on `threads` threads.
  SimulatedReplicate Replicate(int replicate, int threads) const;

 private:
  const std::vector<SubjectModel>& subjects_;
  const PopulationPoint point_;
  const Eigen::MatrixXd factor_;
  const PopulationSimulationOptions& options_;
};

}  // namespace internal
}  // namespace pk

#endif  // PK_POPULATION_SIMULATOR_H_
