// Subjects simulated on worker threads and handed to a sink in order (not installed; simulate.cc).
#ifndef PK_SRC_SIMULATION_STREAM_H_
#define PK_SRC_SIMULATION_STREAM_H_

#include <functional>

#include "pk/simulate.h"

namespace pk {
namespace internal {

/// Hands simulate(i) for i = 0..n-1 to `sink` in order, rendered on the workers (options.jobs of
/// them); memory holds a few subjects a worker.
void StreamSimulations(int n, const SimulationOptions& options, const std::function<SubjectSimulation(int)>& simulate,
                       const SimulationSink& sink);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_SIMULATION_STREAM_H_
