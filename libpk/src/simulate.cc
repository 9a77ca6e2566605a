#include "pk/simulate.h"

#include <algorithm>
#include <thread>
#include <unordered_map>

#include "events.h"
#include "exact/exact_propagator.h"
#include "pk/error.h"
#include "pk/linear_model.h"
#include "pk/regimen.h"
#include "pk/residual_error.h"
#include "ode/ode_propagator.h"
#include "ordered_parallel.h"
#include "output_times.h"
#include "simulation/stream.h"

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
        linear_(dynamic_cast<const LinearModel*>(&sys.model())),
        prop_(*prop),
        out_(out),
        dvid_(s.data->ExtraColumn("DVID")) {
    if (!s.records().empty()) prop_.set_time(s.records()[0].time);
    for (const Eigen::VectorXd& set : s.sets) theta_.push_back(set.head(sys.num_theta()));
    const auto rows = std::count_if(s.records().begin(), s.records().end(), [](const Record& r) {
      return r.evid == Evid::kObservation || r.evid == Evid::kOther;
    });
    out->rows.reserve(static_cast<size_t>(rows));
    out->amounts.resize(sys.n(), rows);
    out->outputs.resize(sys.model().num_outputs(), rows);
    named_.resize(sys.model().num_outputs());
  }

  void Advance(double h, const Eigen::VectorXd& u, int set) { prop_.Advance(h, u, set); }
  void Bolus(int cmt, double amount, int set) { prop_.Bolus(cmt, amount, set); }
  void Reset() { prop_.Reset(); }
  void SteadyState(const internal::SteadyStateCycle<double>& c, int set, bool add) { prop_.SteadyState(c, set, add); }
  void SteadyInfusion(const Eigen::VectorXd& u, int set, bool add) { prop_.SteadyInfusion(u, set, add); }
  void DoseEntered(double time, int set) {
    out_->doses.push_back({time, Output(sys_.central_key(), Amounts(), set, &central_), prop_.auc()});
  }

  void RecordDone(int r, int set) {
    const Record& rec = s_.records()[r];
    prop_.set_time(rec.time);
    if (rec.evid != Evid::kObservation && rec.evid != Evid::kOther) return;
    const Eigen::Index i = static_cast<Eigen::Index>(out_->rows.size());
    out_->amounts.col(i) = Amounts();
    SimulatedRecord row;
    row.record = r;
    row.time = rec.time;
    row.evid = rec.evid;
    row.cp = Output(sys_.central_key(), out_->amounts.col(i), set, &central_);
    row.pred = Output(Key(r), out_->amounts.col(i), set, &record_);
    row.auc = prop_.auc();
    if (ode_) {
      x_ = out_->amounts.col(i);  // OutputValue takes a vector
      for (int k = 0; k < ode_->num_outputs(); ++k) out_->outputs(k, i) = ode_->OutputValue(k + 1, x_, Theta(set));
    } else if (out_->outputs.rows() > 0) {  // a linear model's named outputs, rows n + 1, n + 2, …
      out_->outputs(0, i) = row.cp;  // output 1's row is the central compartment's (file_model.cc)
      for (Eigen::Index k = 1; k < out_->outputs.rows(); ++k) {
        out_->outputs(k, i) = Output(sys_.n() + static_cast<int>(k) + 1, out_->amounts.col(i), set, &named_[k]);
      }
    }
    out_->rows.push_back(row);
  }

 private:
  // A linear model's output row c(θ) and offset d(θ) for the last (key, set) asked: y = c·x + d
  // costs n multiplications when neither changed since the row before, as along a grid of output times.
  struct CachedRow {
    int key = -1, set = -1;
    Eigen::RowVectorXd c;
    double d = 0;
  };

  double Output(int key, const Eigen::Ref<const Eigen::VectorXd>& x, int set, CachedRow* cache) {
    if (!linear_) {
      x_ = x;
      return sys_.Observe(key, x_, Theta(set));
    }
    if (cache->key != key || cache->set != set) {
      cache->c = linear_->OutputRow<double>(key, Theta(set));
      cache->d = linear_->OutputOffset<double>(key, Theta(set));
      cache->key = key;
      cache->set = set;
    }
    return cache->c.dot(x) + cache->d;
  }

  // The exact propagator's state carries the AUC after the amounts.
  auto Amounts() const { return prop_.state().head(sys_.n()); }
  const Eigen::VectorXd& Theta(int set) const { return theta_[static_cast<size_t>(set)]; }
  // Nonlinear models: the DVID's output; linear models: the record's compartment, or its DVID's
  // named output (PreparedSubject::cmt).
  int Key(int r) const {
    if (!ode_) return s_.cmt[r] + 1;
    return internal::OutputOfRecord(*ode_, *s_.data, s_.records()[r], dvid_);
  }

  const internal::OdeSystem& sys_;
  const internal::PreparedSubject& s_;
  const OdeModel* ode_;
  const LinearModel* linear_;
  Propagator& prop_;
  SubjectSimulation* out_;
  int dvid_ = -1;
  std::vector<Eigen::VectorXd> theta_;  // the model's θ of each parameter set
  CachedRow central_, record_;
  std::vector<CachedRow> named_;  // a linear model's named outputs
  Eigen::VectorXd x_;  // amounts for a nonlinear model's outputs, which take a vector
};

// The non-PREDPP columns a simulation reads: parameters and dose modifiers by name, and DVID.
std::vector<std::string> ColumnsRead(const ParameterLayout& layout) {
  std::vector<std::string> names{"DVID"};
  for (int i = 0; i < layout.size(); ++i) names.push_back(layout.name(i));
  return names;
}

template <typename Propagator>
void Run(const internal::OdeSystem& sys, const ParameterLayout& layout, const internal::PreparedSubject& s,
         Propagator* prop, SubjectSimulation* out) {
  Recorder<Propagator> recorder(sys, s, prop, out);
  internal::EventEngine<double, Recorder<Propagator>> engine(s, layout, s.sets, &recorder);
  engine.Run();
  const auto rows = static_cast<Eigen::Index>(out->rows.size());
  if (out->amounts.cols() != rows) {  // every output record gives a row; this keeps the shapes whatever
    out->amounts.conservativeResize(Eigen::NoChange, rows);
    out->outputs.conservativeResize(Eigen::NoChange, rows);
  }
}

}  // namespace

bool SimulationOptions::IsValid(std::string* error) const {
  if (jobs < 0) {
    *error = "jobs must be 0 (all cores) or positive";
    return false;
  }
  return ode.IsValid(error);
}

namespace {

// The options, once they are valid: checked before anything else is made of them, as SimulateSubject did.
const SimulationOptions& Valid(const SimulationOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw InputError(why);
  return options;
}

}  // namespace

internal::SubjectSimulator::SubjectSimulator(const Model& model, const SimulationOptions& options)
    : model_(model),
      options_(Valid(options)),
      propagator_(ResolvePropagator(model, options.propagator)),
      layout_(model),
      columns_read_(ColumnsRead(layout_)) {}

SubjectSimulation internal::SubjectSimulator::Simulate(const Dataset& data, int subject,
                                                       const Eigen::VectorXd& resolved) const {
  SubjectSimulation out;
  out.id = data.subjects[subject].id;
  // With an output grid: this subject alone, with the grid's records added, in storage this thread
  // keeps from one subject to the next.
  thread_local internal::OutputTimesWorkspace with_times;
  const Dataset* source = &data;
  if (!options_.output_times.empty()) {
    internal::SubjectWithOutputTimes(data, subject, options_.output_times, columns_read_, &with_times);
    source = &with_times.one;
    subject = 0;
  }
  internal::PreparedSubject s;
  try {
    s = internal::PrepareSubject(model_, layout_, *source, subject, resolved, true, options_.check_values);
  } catch (const internal::ParameterValueError& e) {
    out.ok = false;
    out.message = e.what();
    return out;
  }
  try {
    const internal::OdeSystem sys(model_);
    if (propagator_ == Propagator::kExact) {
      internal::ExactPropagator prop(dynamic_cast<const LinearModel&>(model_), s.sets, options_.track_auc);
      Run(sys, layout_, s, &prop, &out);
    } else {
      internal::OdePropagator<double> prop(sys, s.sets, 0, options_.ode, false, false, options_.track_auc, nullptr,
                                           propagator_);
      Run(sys, layout_, s, &prop, &out);
    }
  } catch (const internal::NumericalFailure& e) {
    out.ok = false;
    out.message = e.what();
    out.rows.clear();
    out.amounts.resize(0, 0);
    out.outputs.resize(0, 0);
    out.doses.clear();
  }
  return out;
}

SubjectSimulation SimulateSubject(const Model& model, const Dataset& data, int subject,
                                  const ParameterValues& values, const SimulationOptions& options) {
  return internal::SubjectSimulator(model, options)(data, subject, values);
}

namespace {

int Jobs(const SimulationOptions& options, int subjects) {
  const int cores = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  return std::max(1, std::min(options.jobs > 0 ? options.jobs : cores, subjects));
}

}  // namespace

// Subjects go to the workers in chunks: one subject of a hundred rows takes tens of microseconds,
// about what handing it between threads costs.
void internal::StreamSimulations(int n, const SimulationOptions& options,
                                 const std::function<SubjectSimulation(int)>& simulate, const SimulationSink& sink) {
  using Done = std::vector<std::pair<SubjectSimulation, std::string>>;
  const int jobs = Jobs(options, n);
  const int chunk = jobs == 1 ? 1 : std::max(1, std::min(32, n / (16 * jobs)));
  const int chunks = (n + chunk - 1) / chunk;
  internal::OrderedParallel<Done>(
      chunks, jobs, 4 * jobs,
      [&](int c) {
        Done done;
        for (int i = c * chunk; i < std::min(n, (c + 1) * chunk); ++i) {
          done.emplace_back(simulate(i), std::string());
          if (sink.render) done.back().second = sink.render(done.back().first);
        }
        return done;
      },
      [&](int, Done&& done) {
        for (auto& d : done) sink.consume(std::move(d.first), std::move(d.second));
      });
}

namespace {

// The estimates of a subject, without the residual-error σ, under `overrides`.
ParameterValues Merged(const ParameterValues& estimates, const ParameterValues& overrides) {
  ParameterValues merged;
  for (const auto& kv : estimates) {
    if (!IsResidualErrorName(kv.first)) merged[kv.first] = kv.second;  // names as the model spells them
  }
  for (const auto& kv : overrides) merged[kv.first] = kv.second;
  return merged;
}

}  // namespace

void SimulateEach(const Model& model, const Dataset& data, const ParameterValues& values,
                  const SimulationOptions& options, const SimulationSink& sink) {
  internal::CheckColumns(model, data, false);
  const internal::SubjectSimulator simulator(model, options);
  const Eigen::VectorXd resolved = simulator.layout().Resolve(values);
  internal::StreamSimulations(static_cast<int>(data.subjects.size()), options,
         [&](int i) { return simulator.Simulate(data, i, resolved); }, sink);
}

std::vector<SubjectSimulation> Simulate(const Model& model, const Dataset& data, const ParameterValues& values,
                                        const SimulationOptions& options) {
  std::vector<SubjectSimulation> out;
  SimulationSink sink;
  sink.consume = [&](SubjectSimulation&& s, std::string&&) { out.push_back(std::move(s)); };
  SimulateEach(model, data, values, options, sink);
  return out;
}

void SimulateEachWithEstimates(const Model& model, const Dataset& data, const std::vector<SubjectEstimates>& estimates,
                               const ParameterValues& overrides, EstimatesMatch match,
                               const SimulationOptions& options, const std::string& source,
                               const SimulationSink& sink) {
  internal::CheckColumns(model, data, false);
  if (match == EstimatesMatch::kEveryId && data.subjects.size() != 1) {
    throw InputError(data.source + ": a regimen to repeat has one subject, not " +
                     std::to_string(data.subjects.size()));
  }
  const internal::SubjectSimulator simulate(model, options);
  if (match == EstimatesMatch::kEveryId) {
    internal::StreamSimulations(static_cast<int>(estimates.size()), options, [&](int k) {
      SubjectSimulation sim = simulate(data, 0, Merged(estimates[k].second, overrides));
      sim.id = estimates[k].first;
      return sim;
    }, sink);
    return;
  }
  std::unordered_map<double, int> by_id;
  for (int k = 0; k < static_cast<int>(estimates.size()); ++k) by_id.emplace(estimates[k].first, k);
  internal::StreamSimulations(static_cast<int>(data.subjects.size()), options, [&](int i) {
    const auto it = by_id.find(data.subjects[i].id);
    if (it != by_id.end()) {
      return simulate(data, i, Merged(estimates[it->second].second, overrides));
    }
    SubjectSimulation missing;
    missing.id = data.subjects[i].id;
    missing.ok = false;
    missing.message = "no estimates for this ID in " + source;
    return missing;
  }, sink);
}

}  // namespace pk
