#include "pk/simulate.h"

#include "events.h"
#include "exact/exact_propagator.h"
#include "pk/error.h"
#include "pk/linear_model.h"

namespace pk {
namespace {

// Forwards the engine's calls to the exact propagator and records the outputs.
class Recorder {
 public:
  Recorder(const LinearModel& model, const internal::PreparedSubject& s, bool track_auc, SubjectSimulation* out)
      : model_(model), s_(s), prop_(model, s.sets, track_auc), out_(out) {}

  void Advance(double h, const Eigen::VectorXd& u, int set) { prop_.Advance(h, u, set); }
  void Bolus(int cmt, double amount, int set) { prop_.Bolus(cmt, amount, set); }
  void Reset() { prop_.Reset(); }
  void SteadyState(const internal::SteadyStateCycle<double>& c, int set, bool add) { prop_.SteadyState(c, set, add); }
  void SteadyInfusion(const Eigen::VectorXd& u, int set, bool add) { prop_.SteadyInfusion(u, set, add); }

  void DoseEntered(double time, int set) {
    out_->doses.push_back({time, Concentration(model_.central_compartment(), set), prop_.auc()});
  }

  void RecordDone(int r, int set) {
    const Record& rec = s_.records()[r];
    if (rec.evid != Evid::kObservation && rec.evid != Evid::kOther) return;
    SimulatedRecord row;
    row.record = r;
    row.time = rec.time;
    row.evid = rec.evid;
    row.cp = Concentration(model_.central_compartment(), set);
    row.pred = Concentration(s_.cmt[r] + 1, set);
    row.auc = prop_.auc();
    row.amounts = prop_.state().head(model_.num_compartments());
    out_->rows.push_back(std::move(row));
  }

 private:
  double Concentration(int cmt, int set) const {
    return model_.Output(cmt, prop_.state().head(model_.num_compartments()),
                         s_.sets[set].head(model_.num_parameters()));
  }

  const LinearModel& model_;
  const internal::PreparedSubject& s_;
  internal::ExactPropagator prop_;
  SubjectSimulation* out_;
};

}  // namespace

bool SimulationOptions::IsValid(std::string* /*error*/) const { return true; }

SubjectSimulation SimulateSubject(const Model& model, const Dataset& data, int subject,
                                  const ParameterValues& values, const SimulationOptions& options) {
  const auto* linear = dynamic_cast<const LinearModel*>(&model);
  if (linear == nullptr) throw InputError("", 0, 0, "model " + model.name() + " has no propagator yet");
  const ParameterLayout layout(model);
  const internal::PreparedSubject s =
      internal::PrepareSubject(model, layout, data, subject, layout.Resolve(values));
  SubjectSimulation out;
  out.id = data.subjects[subject].id;
  try {
    Recorder recorder(*linear, s, options.track_auc, &out);
    internal::EventEngine<double, Recorder> engine(s, layout, s.sets, &recorder);
    engine.Run();
  } catch (const internal::NumericalFailure& e) {
    out.ok = false;
    out.message = e.what();
    out.rows.clear();
    out.doses.clear();
  }
  return out;
}

std::vector<SubjectSimulation> Simulate(const Model& model, const Dataset& data, const ParameterValues& values,
                                        const SimulationOptions& options) {
  std::vector<SubjectSimulation> out;
  for (int i = 0; i < static_cast<int>(data.subjects.size()); ++i) {
    out.push_back(SimulateSubject(model, data, i, values, options));
  }
  return out;
}

}  // namespace pk
