#include "pk/simulate.h"

#include "events.h"
#include "exact/exact_propagator.h"
#include "pk/error.h"
#include "pk/linear_model.h"
#include "ode/ode_propagator.h"

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

// The same for the ODE propagator.
class OdeRecorder {
 public:
  OdeRecorder(const internal::OdeSystem& sys, const ParameterLayout& layout, const internal::PreparedSubject& s,
              const SimulationOptions& options, SubjectSimulation* out)
      : sys_(sys),
        s_(s),
        ode_(dynamic_cast<const OdeModel*>(&sys.model())),
        prop_(sys, layout, s.sets, 0, options.ode, false, false, options.track_auc),
        out_(out) {
    dvid_ = s.data->ExtraColumn("DVID");
    if (!s.records().empty()) prop_.set_time(s.records()[0].time);
  }

  void Advance(double h, const Eigen::VectorXd& u, int set) { prop_.Advance(h, u, set); }
  void Bolus(int cmt, double amount, int set) { prop_.Bolus(cmt, amount, set); }
  void Reset() { prop_.Reset(); }
  void SteadyState(const internal::SteadyStateCycle<double>& c, int set, bool add) { prop_.SteadyState(c, set, add); }
  void SteadyInfusion(const Eigen::VectorXd& u, int set, bool add) { prop_.SteadyInfusion(u, set, add); }
  void DoseEntered(double time, int set) {
    out_->doses.push_back({time, sys_.Observe(sys_.central_key(), prop_.state(), Theta(set)), prop_.auc()});
  }

  void RecordDone(int r, int set) {
    const Record& rec = s_.records()[r];
    prop_.set_time(rec.time);
    if (rec.evid != Evid::kObservation && rec.evid != Evid::kOther) return;
    const Eigen::VectorXd theta = Theta(set);
    SimulatedRecord row;
    row.record = r;
    row.time = rec.time;
    row.evid = rec.evid;
    row.cp = sys_.Observe(sys_.central_key(), prop_.state(), theta);
    row.pred = sys_.Observe(Key(r), prop_.state(), theta);
    row.auc = prop_.auc();
    row.amounts = prop_.state();
    if (ode_) {
      row.outputs.resize(ode_->num_outputs());
      for (int k = 0; k < ode_->num_outputs(); ++k) row.outputs(k) = ode_->OutputValue(k + 1, prop_.state(), theta);
    }
    out_->rows.push_back(std::move(row));
  }

 private:
  Eigen::VectorXd Theta(int set) const { return s_.sets[set].head(sys_.num_theta()); }
  // Nonlinear models: the DVID's output; linear models: the record's compartment.
  int Key(int r) const {
    if (!ode_) return s_.cmt[r] + 1;
    return internal::OutputOfRecord(*ode_, *s_.data, s_.records()[r], dvid_);
  }

  const internal::OdeSystem& sys_;
  const internal::PreparedSubject& s_;
  const OdeModel* ode_;
  internal::OdePropagator<double> prop_;
  SubjectSimulation* out_;
  int dvid_ = -1;
};

}  // namespace

bool SimulationOptions::IsValid(std::string* error) const { return ode.IsValid(error); }

SubjectSimulation SimulateSubject(const Model& model, const Dataset& data, int subject,
                                  const ParameterValues& values, const SimulationOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw InputError("", 0, 0, why);
  const auto* linear = dynamic_cast<const LinearModel*>(&model);
  const Propagator propagator = ResolvePropagator(model, options.propagator);
  const ParameterLayout layout(model);
  const internal::PreparedSubject s =
      internal::PrepareSubject(model, layout, data, subject, layout.Resolve(values));
  SubjectSimulation out;
  out.id = data.subjects[subject].id;
  try {
    if (propagator == Propagator::kExact) {
      Recorder recorder(*linear, s, options.track_auc, &out);
      internal::EventEngine<double, Recorder> engine(s, layout, s.sets, &recorder);
      engine.Run();
    } else {
      const internal::OdeSystem sys(model);
      OdeRecorder recorder(sys, layout, s, options, &out);
      internal::EventEngine<double, OdeRecorder> engine(s, layout, s.sets, &recorder);
      engine.Run();
    }
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
