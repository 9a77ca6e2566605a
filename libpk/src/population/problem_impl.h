// What a PopulationProblem holds (not installed).
#ifndef PK_SRC_POPULATION_PROBLEM_IMPL_H_
#define PK_SRC_POPULATION_PROBLEM_IMPL_H_

#include <memory>
#include <string>
#include <vector>

#include "population/conditional.h"
#include "pk/population.h"

namespace pk {

struct PopulationProblem::Impl {
  std::shared_ptr<const Model> model;
  std::shared_ptr<const Dataset> data;
  ObjectiveOptions options;  ///< as given (the error model); the subjects run least squares
  std::vector<std::string> theta_names, eta_names, sigma_names;
  std::vector<int> theta_model_index;  ///< model parameter index of each θ
  /// Per η: log-normal on a θ (CL_i = CL·exp(η)), else a model file's η parameter.
  std::vector<bool> eta_log_normal;
  std::vector<internal::SubjectModel> subjects;
  int num_observations = 0;
  int num_censored = 0;  ///< samples with CENS ≠ 0 (Beal's M3; Laplace only)
};

namespace internal {
/// Throws pk::InputError when the parameters' sizes do not match the problem.
void CheckSizes(const PopulationProblem& problem, const PopulationParameters& p);
}  // namespace internal

}  // namespace pk

#endif  // PK_SRC_POPULATION_PROBLEM_IMPL_H_
