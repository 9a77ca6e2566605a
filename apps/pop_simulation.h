// pkpop's simulations at the estimates (parsing and I/O only): --simulate's simtab.csv, the visual
// predictive check's vpc.csv and plots, and the NPDE's npde.csv and plots (the numbers come from
// pk/population_simulation.h, pk/vpc.h and pk/npde.h).
#ifndef PK_APPS_POP_SIMULATION_H_
#define PK_APPS_POP_SIMULATION_H_

#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <boost/program_options.hpp>

#include "pk/npde.h"
#include "pk/population.h"
#include "pk/vpc.h"

namespace pk {
namespace cli {

/// What pkpop simulates after the fit.
struct PopulationSimulationRequest {
  int simulate = 0;  ///< replicates for simtab.csv (0: none)
  std::uint64_t seed = 1;
  int threads = 1;
  std::optional<VpcOptions> vpc;  ///< none without --vpc
  std::optional<NpdeOptions> npde;  ///< none without --npde
  int bootstrap = 0;  ///< --bootstrap's replicates (0: none)
  std::string bootstrap_stratify;  ///< --bootstrap-stratify's column, or empty
};

void AddPopulationSimulationOptions(boost::program_options::options_description* desc);
/// From the parsed options, checked before any fitting (pk::InputError, exit 2).
PopulationSimulationRequest ParsePopulationSimulation(const boost::program_options::variables_map& vm, int threads);

/// simtab.csv, written as replicates are simulated (memory holds one): REP,ID,TIME,DVID,DV,IPRED,PRED
/// and the drawn η. Subjects that could not be simulated are left out; returns how many.
int WriteSimtab(const std::string& path, const PopulationProblem& problem, const PopulationParameters& parameters,
                const PopulationSimulationRequest& request);

/// The NPDE's plots: NPDE against time and against EPRED, and their quantiles against N(0, 1)'s.
std::string NpdeSvg(const NpdeSummary& npde);

/// The VPC's plot: a panel per DVID (the output's name in its title when the model has several).
std::string VpcSvg(const VpcSummary& vpc, const Model& model);

}  // namespace cli
}  // namespace pk

#endif  // PK_APPS_POP_SIMULATION_H_
