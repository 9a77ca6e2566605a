// libpk: a simulation as CSV rows, as pksim writes them.
//
//   ID,TIME,EVID,CP[,further outputs of a nonlinear model, e.g. EFFECT],A1,...,An
//
// one row per output record (EVID 0 or 2), numbers in FormatNumber's shortest form that reads back.
// With SimulateEach, the rows of a subject are formatted on its worker thread (SimulationSink::render)
// and written in order by the caller.
#ifndef PK_SIMULATION_CSV_H_
#define PK_SIMULATION_CSV_H_

#include <string>
#include <vector>

#include "pk/model.h"
#include "pk/simulate.h"

namespace pk {

/// The header line, with its '\n'.
std::string SimulationCsvHeader(const Model& model);

/// Appends the rows of `simulation` (none for a failed one) to `out`.
void AppendSimulationCsv(const SubjectSimulation& simulation, std::string* out);

/// Some of those columns, in a chosen order, as NONMEM's $TABLE lists them (pksim --columns).
class SimulationColumns {
 public:
  /// The columns `list` names, comma-separated and case-insensitive: ID, TIME, EVID, CP, a
  /// nonlinear model's further outputs by name, A1..An. Throws pk::InputError for an unknown or
  /// repeated name, listing the columns `model` has.
  SimulationColumns(const Model& model, const std::string& list);
  /// The same for a simulation with variability (pk::SimulateEachWithVariability), which also has
  /// REP (the replicate, from 1), the η (named `etas`: ETA_CL, …) and, with `observations`, each
  /// output's simulated observation: DV for the first (CP), DV_<NAME> for the others.
  SimulationColumns(const Model& model, const std::string& list, const std::vector<std::string>& etas,
                    bool observations);
  /// Every column of such a simulation: ID,TIME,EVID,CP, the outputs, DV and DV_<NAME> (with
  /// observations), A1..An, the η; REP first when `replicates`.
  static std::string DefaultList(const Model& model, const std::vector<std::string>& etas, bool observations,
                                 bool replicates);

  /// The header line, with its '\n'.
  std::string Header() const;
  /// Appends the rows of `simulation` (none for a failed one), these columns only.
  void Append(const SubjectSimulation& simulation, std::string* out) const;

 private:
  enum class Kind { kId, kTime, kEvid, kCp, kOutput, kAmount, kReplicate, kEta, kObservation };
  struct Column {
    Kind kind;
    int index;  // output k (0-based, 1.. for the further outputs), compartment c or η k (0-based)
    std::string name;
  };
  std::vector<Column> columns_;
};

}  // namespace pk

#endif  // PK_SIMULATION_CSV_H_
