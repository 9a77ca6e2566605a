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

#include "pk/model.h"
#include "pk/simulate.h"

namespace pk {

/// The header line, with its '\n'.
std::string SimulationCsvHeader(const Model& model);

/// Appends the rows of `simulation` (none for a failed one) to `out`.
void AppendSimulationCsv(const SubjectSimulation& simulation, std::string* out);

}  // namespace pk

#endif  // PK_SIMULATION_CSV_H_
