#include "objective/objective_state.h"

#include <cmath>
#include <utility>

#include "pk/ode_model.h"

namespace pk {
namespace internal {

ModalLease::~ModalLease() {
  if (owner == nullptr || !work) return;
  ModalWork* empty = nullptr;
  if (owner->modal_spare.compare_exchange_strong(empty, work.get())) {
    work.release();
    return;
  }
  std::lock_guard<std::mutex> lock(owner->modal_mutex);
  owner->modal_pool.push_back(std::move(work));
}

ObjectiveState::ObjectiveState(std::shared_ptr<const Model> m, std::shared_ptr<const Dataset> d, int subj,
                               const ObjectiveOptions& o)
    : model(std::move(m)), data(std::move(d)), subject(subj), options(o), layout(*model) {
  error = options.error_model.get();
  linear = dynamic_cast<const LinearModel*>(model.get());
  propagator = ResolvePropagator(*model, options.propagator);
  // Dose modifiers (R, D, ...) are checked when values are given (Objective::CheckValues).
  prepared = PrepareSubject(*model, layout, *data, subject, layout.Defaults(), false);
  // A continuous record (CONT=1) is an integral Φ/Γ does not take: `auto` integrates a linear
  // model's subject that has one, as it does a nonlinear model's.
  const int cont = data->ExtraColumn("CONT");
  if (options.propagator == Propagator::kAuto && !IntegratesOde(propagator) && cont >= 0) {
    for (const Record& r : prepared.records()) {
      if (r.IsSample() && r.extra[static_cast<size_t>(cont)] == 1) propagator = Propagator::kRungeKutta;
    }
  }
  if (IntegratesOde(propagator)) {
    ode_system.reset(new OdeSystem(*model));
    ode.system = ode_system.get();
    ode.layout = &layout;
    ode.options = options.ode;
    ode.integrator = propagator;
  }
  names = layout.names();
  for (const std::string& name : error->sigma_names()) {
    sigma.push_back(static_cast<int>(names.size()));
    names.push_back(name);
  }
}

ObjectiveState::~ObjectiveState() { delete modal_spare.load(); }

void ObjectiveState::Sigmas(const Eigen::VectorXd& values, double* out) const {
  for (size_t j = 0; j < sigma.size(); ++j) out[j] = values(sigma[j]);
}

Eigen::VectorXd ObjectiveState::ScheduleKey(const Eigen::VectorXd& values) const {
  // The schedule depends on the modifiers, and on the parameters a modifier computed in $PK reads.
  const int m = model->num_parameters();
  const std::vector<int>& reads = layout.computed_reads();
  Eigen::VectorXd key(L() - m + static_cast<Eigen::Index>(reads.size()));
  key.head(L() - m) = values.segment(m, L() - m);
  for (size_t k = 0; k < reads.size(); ++k) key(L() - m + static_cast<Eigen::Index>(k)) = values(reads[k]);
  return key;
}

bool ObjectiveState::ScheduleFits(const EventSchedule& schedule, const Eigen::VectorXd& values) const {
  const int m = model->num_parameters();
  const std::vector<int>& reads = layout.computed_reads();
  const Eigen::VectorXd& key = schedule.key;
  if (key.size() != L() - m + static_cast<Eigen::Index>(reads.size())) return false;
  if (!SameValues(key.head(L() - m), values.segment(m, L() - m))) return false;
  for (size_t k = 0; k < reads.size(); ++k) {
    const double a = key(L() - m + static_cast<Eigen::Index>(k)), b = values(reads[k]);
    if (!(a == b || (std::isnan(a) && std::isnan(b)))) return false;
  }
  return true;
}

std::shared_ptr<const EventSchedule> ObjectiveState::Schedule(const Eigen::VectorXd& values) const {
  {
    std::lock_guard<std::mutex> lock(schedule_mutex);
    // Unused modifiers are NaN: NaN matches NaN.
    if (schedule && ScheduleFits(*schedule, values)) return schedule;
  }
  PreparedSubject s = prepared;
  RebindParameters(layout, values.head(L()), &s);
  auto made = std::make_shared<EventSchedule>(RecordSchedule(layout, s));
  made->key = ScheduleKey(values);
  std::lock_guard<std::mutex> lock(schedule_mutex);
  schedule = made;
  return made;
}

ModalEvaluator* ObjectiveState::Modal(const Eigen::VectorXd& values, const std::vector<int>& model_free,
                                      ModalLease* lease) const {
  lease->work.reset(modal_spare.exchange(nullptr));
  if (!lease->work) {
    std::lock_guard<std::mutex> lock(modal_mutex);
    if (!modal_pool.empty()) {
      lease->work = std::move(modal_pool.back());
      modal_pool.pop_back();
    }
  }
  if (!lease->work) {
    lease->work.reset(new ModalWork);
    lease->work->evaluator = NewModalEvaluator(*linear);
  }
  lease->owner = this;
  ModalWork& w = *lease->work;
  if (!w.schedule || !ScheduleFits(*w.schedule, values)) w.schedule = Schedule(values);
  if (!w.evaluator->Reset(*w.schedule, values, prepared, model_free)) return nullptr;
  return w.evaluator.get();
}

double ObjectiveState::FdStep() const {
  if (options.fd_relative_step > 0) return options.fd_relative_step;
  return IntegratesOde(propagator) ? std::cbrt(options.ode.relative_tolerance) : 1e-5;
}

}  // namespace internal
}  // namespace pk
