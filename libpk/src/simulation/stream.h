// Subjects simulated on worker threads and handed to a sink in order (not installed; simulate.cc).
#ifndef PK_SRC_SIMULATION_STREAM_H_
#define PK_SRC_SIMULATION_STREAM_H_

#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pk/parameters.h"
#include "pk/propagator.h"
#include "pk/simulate.h"

namespace pk {
namespace internal {

/// SimulateSubject for many subjects of one model and options: what they share (the options' check,
/// the propagator's choice, the parameter layout and the columns a simulation reads) is built once,
/// not once a subject. Const and safe to call from several threads.
class SubjectSimulator {
 public:
  /// Throws InputError for invalid options.
  SubjectSimulator(const Model& model, const SimulationOptions& options);
  /// pk::SimulateSubject(model, data, subject, values, options).
  SubjectSimulation operator()(const Dataset& data, int subject, const ParameterValues& values) const {
    return Simulate(data, subject, layout_.Resolve(values));
  }
  /// The same with the values already resolved into the layout (ParameterLayout::Resolve).
  SubjectSimulation Simulate(const Dataset& data, int subject, const Eigen::VectorXd& resolved) const;
  const ParameterLayout& layout() const { return layout_; }

 private:
  const Model& model_;
  SimulationOptions options_;
  Propagator propagator_;
  ParameterLayout layout_;
  std::vector<std::string> columns_read_;
};

/// Hands simulate(i) for i = 0..n-1 to `sink` in order, rendered on the workers (options.jobs of
/// them); memory holds a few subjects a worker.
void StreamSimulations(int n, const SimulationOptions& options, const std::function<SubjectSimulation(int)>& simulate,
                       const SimulationSink& sink);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_SIMULATION_STREAM_H_
