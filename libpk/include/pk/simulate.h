// libpk: simulation of a dataset or regimen.
//
// Events follow NONMEM's PREDPP semantics (docs/events.md): boluses are jumps
// of the state scaled by F<n>; infusions are piecewise-constant inputs; ADDL,
// II, ALAG<n>, SS=1/2 (bolus, infusion, infusion longer than II, constant
// infusion), EVID 2/3/4 and file order at equal times are honoured. A new
// subject starts from zero. Parameters come from `--param` style values, with
// data columns named like a parameter overriding them per record; the value on
// record i governs the interval that ends at record i.
//
// Linear models are propagated exactly by default, x ← Φ(h)x + Γ(h)u between
// event and output times, with Φ and Γ cached per distinct interval. Nonlinear
// models (and linear ones on request) are integrated by Dormand–Prince (rk, stiff
// stretches by CVODES) or by CVODES (ode), restarted at every discontinuity. Either way AUC is an extra integral state, not a
// trapezoid sum.
#ifndef PK_SIMULATE_H_
#define PK_SIMULATE_H_

#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pk/dataset.h"
#include "pk/estimates.h"
#include "pk/model.h"
#include "pk/ode_options.h"
#include "pk/parameters.h"
#include "pk/propagator.h"

namespace pk {

struct SimulationOptions {
  bool track_auc = true;  ///< carry the AUC of the central concentration
  Propagator propagator = Propagator::kAuto;
  OdeOptions ode;         ///< tolerances of the ODE propagator
  /// Refuse given values of zero or below for parameters the model requires positive
  /// (Model::must_be_positive). Data columns are always checked. Off for values a fit produced,
  /// which may sit at the edge of their range.
  bool check_values = true;
  /// Output records (EVID 2) added to every subject at these times, as AddOutputTimes adds them,
  /// one subject at a time: memory does not grow with subjects × times.
  std::vector<double> output_times;
  /// Worker threads for Simulate and SimulateEach (0: all cores). Results do not depend on it.
  int jobs = 1;

  bool IsValid(std::string* error) const;
};

/// The state after an output record (EVID 0 or 2) has been processed.
struct SimulatedRecord {
  int record = 0;     ///< index within the subject's records
  double time = 0;
  Evid evid = Evid::kObservation;
  double cp = 0;      ///< central concentration
  double pred = 0;    ///< prediction for the record's CMT (equal to cp for the default)
  double auc = 0;     ///< ∫ cp dt from the subject's first record
};

/// A dose entering the system, with the state just before it.
struct DoseEntry {
  double time = 0;
  double cp_before = 0;
  double auc_before = 0;
};

struct SubjectSimulation {
  double id = 0;
  bool ok = true;
  std::string message;  ///< why the simulation failed, when !ok
  std::vector<SimulatedRecord> rows;
  /// Column i: the compartments' amounts after rows[i] (n × rows.size()). One matrix a subject,
  /// not a vector a row: a simulation allocates per subject, not per row.
  Eigen::MatrixXd amounts;
  /// Column i: every named output of the model after rows[i] (Model::output_names; outputs(0, i) =
  /// rows[i].cp); 0 × rows.size() for a catalogue linear model, which names none.
  Eigen::MatrixXd outputs;
  std::vector<DoseEntry> doses;
  /// With variability (pk::SimulateEachWithVariability): the replicate (0-based), the subject's drawn
  /// η, and, with residual error, column i the simulated observation of each output after rows[i]
  /// (row 0 the central concentration's, as outputs; one row for a catalogue linear model).
  int replicate = 0;
  Eigen::VectorXd eta;
  Eigen::MatrixXd observations;
};

/// Simulates one subject. For a nonlinear model, `pred` is the output named by
/// the record's DVID column (default 1). Input errors (CMT out of range, a RATE=-1 dose with
/// no R<n>, ...) throw pk::InputError naming the file, line and column;
/// numerical failure (for example no steady state because nothing is
/// eliminated) is reported through `ok` and `message`.
SubjectSimulation SimulateSubject(const Model& model, const Dataset& data, int subject,
                                  const ParameterValues& values,
                                  const SimulationOptions& options = SimulationOptions());

/// What SimulateEach does with each subject's simulation, as it is done. Memory holds a few
/// subjects at a time (about four per thread), however many the dataset has.
struct SimulationSink {
  /// Optional. Runs on a worker thread right after the subject is simulated: work that may run in
  /// parallel, such as formatting the subject's rows as text. Its result reaches `consume`.
  std::function<std::string(const SubjectSimulation&)> render;
  /// Runs on the calling thread once per subject, in the dataset's order.
  std::function<void(SubjectSimulation&&, std::string&& rendered)> consume;
};

/// Simulates every subject of `data` at `values`, handing each to `sink` in order.
/// An input error (pk::InputError) of a subject is thrown after every earlier subject was handed over.
void SimulateEach(const Model& model, const Dataset& data, const ParameterValues& values,
                  const SimulationOptions& options, const SimulationSink& sink);

/// Simulates every subject, kept in memory (SimulateEach for datasets of any size).
std::vector<SubjectSimulation> Simulate(const Model& model, const Dataset& data,
                                        const ParameterValues& values,
                                        const SimulationOptions& options = SimulationOptions());

/// How SimulateEachWithEstimates pairs subjects with the rows of an estimates table.
enum class EstimatesMatch {
  kById,     ///< each subject of the dataset takes the estimates of its ID
  kEveryId,  ///< the dataset is one regimen, simulated once under each ID of the table, in its order
};

/// Simulates with per-subject parameters from `estimates` (per-subject tables such as pkfit's
/// estimates.csv; residual-error σ are left out), `overrides` taking precedence, handing each
/// subject to `sink` in order. With kById, a subject without an entry is a failed simulation whose
/// message names `source`. With kEveryId the regimen's records are shared, not copied per ID.
void SimulateEachWithEstimates(const Model& model, const Dataset& data, const std::vector<SubjectEstimates>& estimates,
                               const ParameterValues& overrides, EstimatesMatch match,
                               const SimulationOptions& options, const std::string& source,
                               const SimulationSink& sink);

}  // namespace pk

#endif  // PK_SIMULATE_H_
