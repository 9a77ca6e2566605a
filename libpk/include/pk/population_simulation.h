// libpk: simulation from a population model, as NONMEM's $SIMULATION: replicates of a dataset's
// design (its doses, sample times, covariates and outputs), each subject's random effects drawn
// anew and each sample's residual error added:
//
//   η_i ~ N(0, Ω)                        (η_i = L z, Ω = LLᵀ, z standard normal)
//   ŷ_ij = f_ij(θ, η_i)                   (IPRED; PRED is f_ij(θ, 0))
//   T(y_ij) = T(ŷ_ij) + √V_ij ε_ij,  ε_ij ~ N(0, 1),  V_ij = v(ŷ_ij, σ)
//
// with T and v the residual-error model's (pk/residual_error.h): y = ŷ + √V ε for the additive,
// proportional and combined errors (NONMEM's Y = F + F·EPS(1) + EPS(2) has the same distribution),
// log y = log ŷ + σ ε for the exponential. A simulated value is never censored (CENS is ignored),
// and an additive error can make it negative, as in NONMEM.
//
// The random numbers are reproducible: subject i of replicate r draws from streams of its own,
// derived from (seed, r, i), one for η and one for ε. So a replicate does not depend on the number
// of threads or of replicates, a subject's η not on its number of samples, and
// residual_error = false leaves every η as it was.
//
//   pk::PopulationSimulationOptions options;
//   options.seed = 20261127;
//   pk::SimulatePopulation(problem, fit.parameters, options, [](const pk::SimulatedReplicate& r) { ... });
#ifndef PK_POPULATION_SIMULATION_H_
#define PK_POPULATION_SIMULATION_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pk/population.h"
#include "pk/population_estimates.h"
#include "pk/residual_error.h"
#include "pk/simulate.h"

namespace pk {

struct PopulationSimulationOptions {
  int replicates = 1;
  std::uint64_t seed = 1;      ///< NONMEM's $SIMULATION (seed)
  bool residual_error = true;  ///< false: DV = IPRED
  int threads = 1;             ///< a replicate's subjects on this many threads; no effect on the values

  bool IsValid(std::string* error) const;
};

/// The samples a simulation reproduces: the problem's observation records, subject by subject.
struct SimulationDesign {
  struct Subject {
    double id = 0;
    int subject = -1;          ///< position in the dataset (Dataset::subjects)
    std::vector<double> time;  ///< per sample
    std::vector<int> dvid;     ///< per sample: the output it measures
    std::vector<int> censored; ///< per sample: the data's CENS (0 a value)
    Eigen::VectorXd dv;        ///< per sample: the data's DV (natural scale)
    Eigen::VectorXd pred;      ///< per sample: f(θ, η = 0) (NaN where it cannot be evaluated)
    /// Per sample: the value of the column the design was stratified by, at the sample's record
    /// (empty: not stratified).
    std::vector<double> stratum;
  };
  std::string stratify;  ///< that column (upper case), or empty
  std::vector<Subject> subjects;
};

/// One subject of one replicate.
struct SimulatedSubject {
  bool ok = true;
  std::string message;     ///< why the subject could not be simulated (its predictions at the drawn η)
  Eigen::VectorXd eta;     ///< the drawn η (Ω's order)
  Eigen::VectorXd ipred;   ///< f(θ, η) per sample
  Eigen::VectorXd dv;      ///< the simulated observations
};

struct SimulatedReplicate {
  int replicate = 0;  ///< 0-based
  std::vector<SimulatedSubject> subjects;  ///< in SimulationDesign::subjects order
  int failed = 0;     ///< subjects that could not be simulated
};

/// The design of `problem` at `parameters` (PRED included; NaN for a subject whose PRED cannot be
/// evaluated). Throws pk::InputError when the parameters do not fit the problem (sizes, a σ that
/// is negative or not finite).
/// With `stratify`, a data column (not a PREDPP one) whose value at each sample's record is kept.
SimulationDesign MakeSimulationDesign(const PopulationProblem& problem, const PopulationParameters& parameters,
                                      const std::string& stratify = "");

/// Simulates options.replicates replicates of the problem's design at `parameters`, handing each to
/// `consume` in order as it is done (memory holds one replicate). A subject whose predictions cannot
/// be evaluated at its η is reported in its SimulatedSubject, and the others go on. Throws
/// pk::InputError for invalid options, an Ω that is not positive semi-definite, or parameters that
/// do not fit the problem.
void SimulatePopulation(const PopulationProblem& problem, const PopulationParameters& parameters,
                        const PopulationSimulationOptions& options,
                        const std::function<void(const SimulatedReplicate&)>& consume);

/// Replicate `replicate` (0-based) alone, its subjects on options.threads threads: what
/// SimulatePopulation hands over for it. Throws as SimulatePopulation.
SimulatedReplicate SimulateReplicate(const PopulationProblem& problem, const PopulationParameters& parameters,
                                     const PopulationSimulationOptions& options, int replicate);

// ---- New designs: a dataset or regimen simulated with a population's variability (pksim --population).

/// Each subject of a dataset (or N copies of a one-subject regimen) simulated with its own η drawn
/// from a population's Ω, on the same streams as SimulatePopulation (so the fitted data's design
/// gives pkpop --simulate's η), and each output at every row given a residual error.
struct VariabilityOptions {
  int replicates = 1;
  std::uint64_t seed = 1;
  bool residual_error = true;
  /// 0: the dataset's subjects. N > 0: the dataset is one subject (a regimen), simulated as N
  /// subjects with IDs 1…N, each its own η.
  int subjects = 0;
  /// Parameter uncertainty (pk/uncertainty.h): when not empty, replicate r takes its θ, Ω and σ from
  /// parameter_sets[r mod size] in place of the population's (each set over the population's η and
  /// σ, as DrawFromCovariance and ReadParameterSets make them); the η and ε streams are unchanged.
  std::vector<PopulationEstimates> parameter_sets;

  bool IsValid(std::string* error) const;
};

/// The residual-error model of a population's σ: the model file's $ERROR when it declares one, else
/// the catalogue's whose σ the population names (SIGMA_ADD: additive, SIGMA_PROP: proportional,
/// both: combined, SIGMA_LOG: exponential) when the file's $ERROR has other σ (a run with pkpop
/// --error). Throws pk::InputError when none has those σ.
std::shared_ptr<const ResidualErrorModel> PopulationErrorModel(const Model& model, const PopulationEstimates& population);

/// Simulates every subject of every replicate, handing each to `sink` in order (replicate by
/// replicate), with SubjectSimulation::replicate, ::eta and ::observations set. Subject i's
/// parameters are `overrides`, else the population's θ, with each η applied: φ = θ·exp(η) for a
/// log-normal η, the η parameter itself for a model file's. Data columns named like a parameter
/// still override it record by record, as in any simulation. Throws pk::InputError for invalid
/// options, an Ω that is not positive semi-definite, residual error without σ, or a regimen of more
/// than one subject to copy.
void SimulateEachWithVariability(const Model& model, const Dataset& data, const PopulationEstimates& population,
                                 const ParameterValues& overrides, const SimulationOptions& options,
                                 const VariabilityOptions& variability, const SimulationSink& sink);

}  // namespace pk

#endif  // PK_POPULATION_SIMULATION_H_
