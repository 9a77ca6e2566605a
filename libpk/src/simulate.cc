#include "pk/simulate.h"

#include <algorithm>

#include "events.h"
#include "exact/exact_propagator.h"
#include "pk/error.h"
#include "pk/linear_model.h"
#include "pk/residual_error.h"
#include "ode/ode_propagator.h"

namespace pk {
namespace {

// Forwards the engine's calls to a propagator (exact or ODE) and records the
// outputs. Observations go through OdeSystem, which reads a linear model's
// output by compartment and a nonlinear model's by DVID.
template <typename Propagator>
class Recorder {
 public:
  Recorder(const internal::OdeSystem& sys, const internal::PreparedSubject& s, Propagator* prop,
           SubjectSimulation* out)
      : sys_(sys),
        s_(s),
        ode_(dynamic_cast<const OdeModel*>(&sys.model())),
        prop_(*prop),
        out_(out),
        dvid_(s.data->ExtraColumn("DVID")) {
    if (!s.records().empty()) prop_.set_time(s.records()[0].time);
  }

  void Advance(double h, const Eigen::VectorXd& u, int set) { prop_.Advance(h, u, set); }
  void Bolus(int cmt, double amount, int set) { prop_.Bolus(cmt, amount, set); }
  void Reset() { prop_.Reset(); }
  void SteadyState(const internal::SteadyStateCycle<double>& c, int set, bool add) { prop_.SteadyState(c, set, add); }
  void SteadyInfusion(const Eigen::VectorXd& u, int set, bool add) { prop_.SteadyInfusion(u, set, add); }
  void DoseEntered(double time, int set) {
    out_->doses.push_back({time, sys_.Observe(sys_.central_key(), Amounts(), Theta(set)), prop_.auc()});
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
    row.amounts = Amounts();
    row.cp = sys_.Observe(sys_.central_key(), row.amounts, theta);
    row.pred = sys_.Observe(Key(r), row.amounts, theta);
    row.auc = prop_.auc();
    if (ode_) {
      row.outputs.resize(ode_->num_outputs());
      for (int k = 0; k < ode_->num_outputs(); ++k) row.outputs(k) = ode_->OutputValue(k + 1, row.amounts, theta);
    }
    out_->rows.push_back(std::move(row));
  }

 private:
  // The exact propagator's state carries the AUC after the amounts.
  Eigen::VectorXd Amounts() const { return prop_.state().head(sys_.n()); }
  Eigen::VectorXd Theta(int set) const { return s_.sets[set].head(sys_.num_theta()); }
  // Nonlinear models: the DVID's output; linear models: the record's compartment.
  int Key(int r) const {
    if (!ode_) return s_.cmt[r] + 1;
    return internal::OutputOfRecord(*ode_, *s_.data, s_.records()[r], dvid_);
  }

  const internal::OdeSystem& sys_;
  const internal::PreparedSubject& s_;
  const OdeModel* ode_;
  Propagator& prop_;
  SubjectSimulation* out_;
  int dvid_ = -1;
};

template <typename Propagator>
void Run(const internal::OdeSystem& sys, const ParameterLayout& layout, const internal::PreparedSubject& s,
         Propagator* prop, SubjectSimulation* out) {
  Recorder<Propagator> recorder(sys, s, prop, out);
  internal::EventEngine<double, Recorder<Propagator>> engine(s, layout, s.sets, &recorder);
  engine.Run();
}

}  // namespace

bool SimulationOptions::IsValid(std::string* error) const { return ode.IsValid(error); }

SubjectSimulation SimulateSubject(const Model& model, const Dataset& data, int subject,
                                  const ParameterValues& values, const SimulationOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw InputError(why);
  const auto* linear = dynamic_cast<const LinearModel*>(&model);
  const Propagator propagator = ResolvePropagator(model, options.propagator);
  const ParameterLayout layout(model);
  SubjectSimulation out;
  out.id = data.subjects[subject].id;
  internal::PreparedSubject s;
  try {
    s = internal::PrepareSubject(model, layout, data, subject, layout.Resolve(values), true, options.check_values);
  } catch (const internal::ParameterValueError& e) {
    out.ok = false;
    out.message = e.what();
    return out;
  }
  try {
    const internal::OdeSystem sys(model);
    if (propagator == Propagator::kExact) {
      internal::ExactPropagator prop(*linear, s.sets, options.track_auc);
      Run(sys, layout, s, &prop, &out);
    } else {
      internal::OdePropagator<double> prop(sys, s.sets, 0, options.ode, false, false, options.track_auc);
      Run(sys, layout, s, &prop, &out);
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

std::vector<SubjectSimulation> SimulateWithEstimates(const Model& model, const Dataset& data,
                                                     const std::vector<SubjectEstimates>& estimates,
                                                     const ParameterValues& overrides,
                                                     const SimulationOptions& options, const std::string& source) {
  std::vector<SubjectSimulation> sims;
  for (int i = 0; i < static_cast<int>(data.subjects.size()); ++i) {
    const double id = data.subjects[i].id;
    const auto it = std::find_if(estimates.begin(), estimates.end(), [&](const auto& e) { return e.first == id; });
    if (it == estimates.end()) {
      SubjectSimulation missing;
      missing.id = id;
      missing.ok = false;
      missing.message = "no estimates for this ID in " + source;
      sims.push_back(std::move(missing));
      continue;
    }
    ParameterValues merged;
    for (const auto& kv : it->second) {
      if (!IsResidualErrorName(kv.first)) merged[kv.first] = kv.second;  // names as the model spells them
    }
    for (const auto& kv : overrides) merged[kv.first] = kv.second;
    sims.push_back(SimulateSubject(model, data, i, merged, options));
  }
  return sims;
}

Dataset RepeatForEach(const Dataset& one, const std::vector<SubjectEstimates>& estimates) {
  if (one.subjects.size() != 1) {
    throw InputError(one.source + ": a regimen to repeat has one subject, not " + std::to_string(one.subjects.size()));
  }
  Dataset out = one;
  out.subjects.clear();
  for (const auto& e : estimates) {
    out.subjects.push_back(one.subjects.front());
    out.subjects.back().id = e.first;
  }
  return out;
}

}  // namespace pk
