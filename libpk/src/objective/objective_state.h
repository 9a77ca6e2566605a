// What an Objective holds (not installed): the subject bound to the model, its samples, the
// residual-error model and its σ positions, and the storage kept between evaluations.
#ifndef PK_SRC_OBJECTIVE_OBJECTIVE_STATE_H_
#define PK_SRC_OBJECTIVE_OBJECTIVE_STATE_H_

#include <atomic>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "events.h"
#include "exact/modal.h"
#include "ode/ode_routes.h"
#include "ode/ode_system.h"
#include "pk/linear_model.h"
#include "pk/objective.h"
#include "pk/parameters.h"
#include "pk/residual_error.h"

namespace pk {
namespace internal {

/// A modal evaluator with what it last replayed, kept between evaluations for its storage.
struct ModalWork {
  std::unique_ptr<ModalEvaluator> evaluator;
  std::shared_ptr<const EventSchedule> schedule;  // the schedule it replays
  Eigen::VectorXd dl_dy;                          // Evaluate's ∂ℓ/∂ŷ, kept for its storage
};

struct ObjectiveState;

/// Hands a ModalWork back to its objective when the evaluation ends.
struct ModalLease {
  const ObjectiveState* owner = nullptr;
  std::unique_ptr<ModalWork> work;
  ModalLease() = default;
  ModalLease(const ModalLease&) = delete;
  ModalLease& operator=(const ModalLease&) = delete;
  ~ModalLease();
};

struct ObjectiveState {
  std::shared_ptr<const Model> model;
  const LinearModel* linear = nullptr;
  std::shared_ptr<const Dataset> data;
  int subject = 0;
  ObjectiveOptions options;
  ParameterLayout layout;
  PreparedSubject prepared;
  std::vector<std::string> names;  // the layout's, then the error model's σ
  const ResidualErrorModel* error = nullptr;  // options.error_model
  std::vector<int> sigma;          // the σ parameters' positions in `names`
  Eigen::VectorXd y, w;            // samples and least-squares weights
  Eigen::VectorXi cens;            // per sample: 0, or ±1 for a value beyond DV (CENS)
  Eigen::VectorXi outputs;         // per sample: the output it measures (DVID of a nonlinear model, else 1)
  std::vector<double> times;
  Propagator propagator = Propagator::kExact;
  std::unique_ptr<OdeSystem> ode_system;
  OdeSubject ode;
  struct Prior {
    int index;
    double log_median, sd;
  };
  std::vector<Prior> priors;

  // The event schedule for the modal path, recorded for the dose-modifier values it was last asked for.
  mutable std::mutex schedule_mutex;
  mutable std::shared_ptr<const EventSchedule> schedule;
  // Modal evaluators, one per concurrent evaluation. The last one handed back waits in
  // `modal_spare`, which a sequential caller (an optimiser) takes and returns without a lock;
  // concurrent callers use the pool behind the mutex.
  mutable std::atomic<ModalWork*> modal_spare{nullptr};
  mutable std::mutex modal_mutex;
  mutable std::vector<std::unique_ptr<ModalWork>> modal_pool;

  ObjectiveState(std::shared_ptr<const Model> m, std::shared_ptr<const Dataset> d, int subj,
                 const ObjectiveOptions& o);
  ~ObjectiveState();

  int L() const { return layout.size(); }
  bool likelihood() const { return error->is_likelihood(); }
  /// σ values at `values` (one per error-model σ), in `out`.
  void Sigmas(const Eigen::VectorXd& values, double* out) const;
  std::shared_ptr<const EventSchedule> Schedule(const Eigen::VectorXd& values) const;
  /// What a schedule depends on: the modifiers, then the parameters a computed modifier reads.
  Eigen::VectorXd ScheduleKey(const Eigen::VectorXd& values) const;
  /// Whether `schedule` was recorded at values with the same key (NaN matches NaN).
  bool ScheduleFits(const EventSchedule& schedule, const Eigen::VectorXd& values) const;
  /// The modal evaluator at `values`, leased into `lease` (null when some set's A is unsuitable;
  /// see exact/modal.h). Its schedule is re-recorded only when the dose modifiers' values changed.
  ModalEvaluator* Modal(const Eigen::VectorXd& values, const std::vector<int>& model_free, ModalLease* lease) const;
  /// The central-difference step relative to |θ|.
  double FdStep() const;
};

/// Reads the subject's samples, weights, censoring and continuous records into `s`, and binds
/// the priors. Throws pk::InputError for data the options cannot take.
void BindSamples(ObjectiveState* s, const std::vector<LogNormalPrior>& priors);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_OBJECTIVE_OBJECTIVE_STATE_H_
