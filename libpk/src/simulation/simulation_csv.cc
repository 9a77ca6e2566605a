#include "pk/simulation_csv.h"

#include "pk/ode_model.h"
#include "pk/output.h"

namespace pk {

std::string SimulationCsvHeader(const Model& model) {
  const auto* ode_model = dynamic_cast<const OdeModel*>(&model);
  std::string csv = "ID,TIME,EVID,CP";
  for (int k = 1; ode_model && k < ode_model->num_outputs(); ++k) csv += "," + ode_model->output_names()[k];
  for (int c = 1; c <= model.num_compartments(); ++c) csv += ",A" + std::to_string(c);
  return csv + "\n";
}

void AppendSimulationCsv(const SubjectSimulation& s, std::string* out) {
  if (!s.ok || s.rows.empty()) return;
  std::string id;
  AppendNumber(&id, s.id);
  const auto& first = s.rows.front();
  // About 20 characters a number: one allocation for the subject's rows.
  out->reserve(out->size() + s.rows.size() * (id.size() + 24 * (3 + first.outputs.size() + first.amounts.size())));
  for (const SimulatedRecord& r : s.rows) {
    *out += id;
    *out += ',';
    AppendNumber(out, r.time);
    *out += r.evid == Evid::kObservation ? ",0," : ",2,";
    AppendNumber(out, r.cp);
    for (int k = 1; k < r.outputs.size(); ++k) {
      *out += ',';
      AppendNumber(out, r.outputs(k));
    }
    for (int c = 0; c < r.amounts.size(); ++c) {
      *out += ',';
      AppendNumber(out, r.amounts(c));
    }
    *out += '\n';
  }
}

}  // namespace pk
