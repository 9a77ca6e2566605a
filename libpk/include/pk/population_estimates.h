// libpk: a population model's estimates as pkpop writes them (population_estimates.csv), read back
// to simulate new designs with between-subject and residual variability (pksim --population).
//
//   PARAMETER,ESTIMATE,...
//   CL,0.0047          a typical value θ (any model parameter)
//   OMEGA(CL),0.029    ω² of an η: on a parameter NAME, log-normal (CL_i = CL·exp(η)); on a model
//   "OMEGA(V,CL)",0.01    file's η parameter (ETA_CL), that parameter; a covariance within a block
//   SIGMA_PROP,0.115   a residual-error σ (a standard deviation)
//   OFV,586.28         (ignored, as are SE and the other columns)
//
// The η are those with a variance, in the table's order. Names are case-insensitive.
#ifndef PK_POPULATION_ESTIMATES_H_
#define PK_POPULATION_ESTIMATES_H_

#include <string>
#include <vector>

#include <Eigen/Core>

#include "pk/model.h"
#include "pk/parameters.h"

namespace pk {

struct PopulationEstimates {
  std::string source;
  ParameterValues theta;  ///< the typical values, under the model's names
  /// The η in Ω's order: a model parameter with a log-normal η, or a model file's η parameter.
  std::vector<std::string> etas;
  std::vector<bool> eta_log_normal;  ///< per η: φ = θ·exp(η) (true), or the η parameter itself
  Eigen::MatrixXd omega;
  std::vector<std::string> sigma_names;  ///< SIGMA_ADD, SIGMA_PROP_CP, ...
  Eigen::VectorXd sigma;
};

/// The estimates in the table at `path`, bound to `model` (a model file made with
/// RandomEffects::kParameters, so that its η are parameters). Throws pk::InputError naming the
/// file, line and column of the first problem: an unknown parameter, an η on a covariate, a
/// covariance of η without variances, a name given twice, a σ or variance that is negative.
PopulationEstimates ReadPopulationEstimates(const std::string& path, const Model& model);

/// The same from text in memory; `source` names it in errors.
PopulationEstimates ParsePopulationEstimates(const std::string& text, const std::string& source, const Model& model);

}  // namespace pk

#endif  // PK_POPULATION_ESTIMATES_H_
