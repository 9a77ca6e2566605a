// libpk: the uncertainty of a population's estimates, for simulations that carry it ("simulation with
// parameter uncertainty": a trial simulation whose replicates differ in θ, Ω and σ as the estimates
// could, beside each subject's η and ε). It comes as parameter sets, one per replicate, from either
//
//   - the covariance step: draws of N(estimates, covariance) over the estimated natural parameters
//     (θ, Ω's variances and covariances, σ; what pkpop's covariance.csv holds), the fixed ones held.
//     A draw with a θ that must be positive and is not, an Ω that is not positive definite or a σ
//     that is not positive is drawn again (up to 1000 times): the normal truncated to the parameter
//     space, as PsN's sse and SIR proposals truncate theirs. The normal approximation is the
//     covariance step's own; a skewed variance is better served by
//   - a bootstrap (pkpop's bootstrap.csv, its rows marked USED; PsN's vpc -rawres_input): each row a
//     set, replicate r taking row r mod (the number of rows), in the file's order.
//
//   const pk::PopulationEstimates est = pk::ReadPopulationEstimates("run/population_estimates.csv", model);
//   const auto sets = pk::DrawFromCovariance(est, pk::ReadEstimatesCovariance("run/covariance.csv"), model,
//                                            200, seed);
//   variability.parameter_sets = sets;  // pk::SimulateEachWithVariability, pk/population_simulation.h
//
// Names are population_estimates.csv's: a θ by its parameter's name, OMEGA(A) and OMEGA(A,B) for Ω
// (A, B the η: a parameter with a log-normal η, or a model file's η parameter), SIGMA_… for σ.
#ifndef PK_UNCERTAINTY_H_
#define PK_UNCERTAINTY_H_

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pk/model.h"
#include "pk/population_estimates.h"

namespace pk {

/// The covariance of the estimated natural parameters (pkpop's covariance.csv).
struct EstimatesCovariance {
  std::vector<std::string> names;
  Eigen::MatrixXd covariance;
};

/// covariance.csv as pkpop writes it: a header PARAMETER,NAME…, then a row per name in the same
/// order. Throws pk::InputError naming the file, line and column of a missing or unreadable value,
/// a row out of order, or a matrix that is not symmetric.
EstimatesCovariance ReadEstimatesCovariance(const std::string& path);

/// `base` with the named values replaced (a covariance sets both of Ω's symmetric entries). Throws
/// pk::InputError for a name `base` does not hold: a θ it has no typical value for, an η it has no
/// variance for, a σ of another error model.
PopulationEstimates WithNaturalValues(const PopulationEstimates& base, const std::vector<std::string>& names,
                                      const Eigen::VectorXd& values, const Model& model);

/// Whether `set` lies in the parameter space: every θ that `model` requires positive is (its signed
/// parameters aside) and within a model file's bounds, Ω is positive definite, every σ positive;
/// else false with `why`.
bool InParameterSpace(const PopulationEstimates& set, const Model& model, std::string* why);

/// `count` sets drawn from N(estimates, covariance) as above, set r from a stream of its own (seed, r),
/// so a set does not depend on how many are drawn. *redrawn (when non-null) counts the draws rejected.
/// Throws pk::InputError when the covariance is not positive semi-definite or names a value the
/// estimates do not hold, or when a set cannot be drawn inside the parameter space in 1000 tries.
std::vector<PopulationEstimates> DrawFromCovariance(const PopulationEstimates& estimates,
                                                    const EstimatesCovariance& covariance, const Model& model,
                                                    int count, std::uint64_t seed, int* redrawn = nullptr);

/// The sets of a bootstrap: bootstrap.csv's rows (those with USED 1 when it has the column), each
/// over `estimates`, the columns REPLICATE, CONVERGED, BOUNDARY, USED and OFV aside. The columns
/// must be the estimates' own parameters, every θ, Ω variance and σ of them and no covariance
/// they do not have (a bootstrap of another run is refused). Throws pk::InputError naming the
/// file, line and column of an unknown or missing name, an unreadable value, a row outside the
/// parameter space, or when no row is left.
std::vector<PopulationEstimates> ReadParameterSets(const std::string& path, const PopulationEstimates& estimates,
                                                   const Model& model);

}  // namespace pk

#endif  // PK_UNCERTAINTY_H_
