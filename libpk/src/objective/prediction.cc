#include "objective/prediction.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "autodiff.h"
#include "exact/companion_route.h"
#include "numerical_failure.h"
#include "objective/output_offsets.h"

namespace pk {
namespace internal {

FreeParameters::FreeParameters(const std::vector<int>& free, int layout_size) : free_(&free) {
  for (int i : free) all_model_ = all_model_ && i < layout_size;
  if (all_model_) return;
  for (size_t k = 0; k < free.size(); ++k) {
    if (free[k] < layout_size) {
      subset_.push_back(free[k]);
      position_.push_back(static_cast<int>(k));
    }
  }
}

Eigen::VectorXd* Prediction::LossGradientStorage(Eigen::VectorXd* fallback) {
  return modal_lease.work ? &modal_lease.work->dl_dy : fallback;
}

bool Prediction::ModelGradient(const Eigen::VectorXd& dl_dy, int num_model, Eigen::VectorXd* gradient,
                               Objective::Evaluation* ev) {
  if (adjoint) {
    *gradient = adjoint->Gradient(dl_dy);
  } else if (modal) {
    *gradient = modal->AdjointGradient(dl_dy);
  } else if (ode_adjoint) {
    try {
      *gradient = ode_adjoint->Gradient(dl_dy);  // includes the continuous records' term
      ev->ode_statistics = ode_adjoint->statistics();
    } catch (const NumericalFailure& e) {
      ev->ok = false;
      ev->message = e.what();
      return false;
    }
  } else if (num_model > 0) {
    *gradient = jacobian.transpose() * dl_dy;
    if (continuous_gradient.size()) *gradient += continuous_gradient.transpose();
  } else {
    gradient->setZero(num_model);
  }
  if (offset_jacobian.size() && (adjoint || modal)) *gradient += offset_jacobian.transpose() * dl_dy;
  return true;
}

namespace {

const std::vector<int> kNoParameters;  // a value alone: no parameter needs derivatives

bool ModalRoute(GradientRoute route) {
  return route == GradientRoute::kAuto || route == GradientRoute::kForward || route == GradientRoute::kAdjoint;
}

// Whether some free parameter moves a dose.
bool EventsDepend(const ObjectiveState& d, const FreeParameters& free) {
  bool depend = false;
  for (int i : free.model()) depend = depend || MovesDoses(d, i);
  return depend;
}

// The eigen-coordinate path for linear models (exact/modal.h). Returns true when it computed ŷ
// (and ∂ŷ/∂p or the adjoint's record); false when the model's A is unsuitable here. Throws
// NumericalFailure.
bool PredictModal(const ObjectiveState& d, const Eigen::VectorXd& values, const FreeParameters& free,
                  Objective::Need need, GradientRoute route, Prediction* out, Eigen::VectorXd* yhat) {
  const int pm = free.num_model();
  // A value alone needs no partials of A.
  ModalEvaluator* modal = d.Modal(values, need == Objective::Need::kValue ? kNoParameters : free.model(),
                                  &out->modal_lease);
  if (modal == nullptr) return false;
  if (route == GradientRoute::kForward && pm > 0) {
    modal->Jacobian(yhat, &out->jacobian);
  } else if (route == GradientRoute::kAdjoint && pm > 0) {
    modal->AdjointForward(yhat);
    out->modal = modal;
  } else {
    modal->Predict(yhat);
    out->jacobian = Eigen::MatrixXd::Zero(yhat->size(), pm);
  }
  return true;
}


// tf<n> models: the two companion filters give ∂ŷ/∂a_i and ∂ŷ/∂b_i (layout entries 0..2n−1).
void PredictCompanion(const ObjectiveState& d, const PreparedSubject& s, const FreeParameters& free,
                      Eigen::VectorXd* yhat, Eigen::MatrixXd* jacobian) {
  const bool ode = IntegratesOde(d.propagator);
  const int order = d.linear == nullptr || ode ? 0 : d.linear->transfer_function_order();
  if (order == 0) {
    throw NumericalFailure("the companion route applies to tf<n> models only (with the exact propagator)");
  }
  for (int i : free.model()) {
    if (i >= 2 * order) {
      throw NumericalFailure("the companion route differentiates a_i and b_i only, not " + d.layout.name(i));
    }
  }
  Eigen::MatrixXd j_all;
  CompanionJacobian(*d.linear, d.layout, s, yhat, &j_all);
  jacobian->resize(yhat->size(), free.num_model());
  for (int a = 0; a < free.num_model(); ++a) jacobian->col(a) = j_all.col(free.model()[a]);
}

// Predictions alone at other values (finite differences, and the routes without derivatives).
void PredictAt(const ObjectiveState& d, const Eigen::VectorXd& v, Eigen::VectorXd* y, double* continuous_loss,
               OdeStatistics* stats) {
  PreparedSubject sv = d.prepared;
  RebindParameters(d.layout, v.head(d.L()), &sv);
  *continuous_loss = 0;
  if (IntegratesOde(d.propagator)) {
    OdePredict(d.ode, sv, y, continuous_loss, stats);
  } else {
    internal::Predict(*d.linear, d.layout, sv, y);
  }
}

// Central differences of ŷ in each free model parameter.
void FdJacobian(const ObjectiveState& d, const Eigen::VectorXd& values, const FreeParameters& free,
                Eigen::MatrixXd* jacobian, OdeStatistics* stats) {
  for (int a = 0; a < free.num_model(); ++a) {
    const int i = free.model()[a];
    const double h = std::max(std::fabs(values(i)), 1e-8) * d.FdStep();
    Eigen::VectorXd vp = values, vm = values, yp, ym;
    vp(i) += h;
    vm(i) -= h;
    double cp, cm;
    PredictAt(d, vp, &yp, &cp, stats);
    PredictAt(d, vm, &ym, &cm, stats);
    jacobian->col(a) = (yp - ym) / (2 * h);
  }
}

// The other paths: the Padé propagator's routes, the ODE routes and the companion filters.
void PredictRoute(const ObjectiveState& d, const Eigen::VectorXd& values, const FreeParameters& free,
                  GradientRoute route, bool events_depend, Prediction* out, Objective::Evaluation* ev) {
  Eigen::VectorXd& yhat = ev->predictions;
  const bool ode = IntegratesOde(d.propagator);
  const int pm = free.num_model();
  PreparedSubject s = d.prepared;
  RebindParameters(d.layout, values.head(d.L()), &s);
  if (route == GradientRoute::kCompanion) {
    PredictCompanion(d, s, free, &yhat, &out->jacobian);
  } else if (ode && route == GradientRoute::kForward && pm > 0) {
    OdeForwardSensitivities(d.ode, s, DualSets(s, d.layout, free), pm, &yhat, &out->jacobian, &out->continuous_loss,
                            &out->continuous_gradient, &ev->ode_statistics);
  } else if (ode && route == GradientRoute::kAdjoint && pm > 0) {
    out->ode_adjoint.reset(new OdeAdjoint(d.ode, s, DualSets(s, d.layout, free), pm));
    out->ode_adjoint->Forward(&yhat, &out->continuous_loss);
  } else if (route == GradientRoute::kForward && pm > 0) {
    ForwardSensitivities(*d.linear, d.layout, s, DualSets(s, d.layout, free), pm, events_depend, &yhat,
                         &out->jacobian);
  } else if (route == GradientRoute::kAdjoint && pm > 0) {
    out->adjoint.reset(new DiscreteAdjoint(*d.linear, d.layout, s, DualSets(s, d.layout, free), pm, events_depend));
    out->adjoint->Forward(&yhat);
  } else {
    PredictAt(d, values, &yhat, &out->continuous_loss, &ev->ode_statistics);
    out->jacobian = Eigen::MatrixXd::Zero(yhat.size(), pm);
  }
}

// The output offsets d(θ) (output_offsets.h), which the exact paths above leave out: ŷ += d, and
// ∂d/∂p into the Jacobian or, on the adjoint routes, beside it for ModelGradient.
void AddOffsets(const ObjectiveState& d, const Eigen::VectorXd& values, const FreeParameters& free,
                Objective::Need need, Prediction* out, Eigen::VectorXd* yhat) {
  PreparedSubject s = d.prepared;
  RebindParameters(d.layout, values.head(d.L()), &s);
  AddOutputOffsets(*d.linear, s, yhat);
  const int pm = free.num_model();
  if (need == Objective::Need::kValue || pm == 0) return;
  Eigen::MatrixXd jd = OutputOffsetJacobian(*d.linear, s, DualSets(s, d.layout, free), pm);
  if (out->adjoint || out->modal) {
    out->offset_jacobian = std::move(jd);
  } else {
    out->jacobian.topRows(jd.rows()) += jd;
  }
}

bool Failed(const std::string& why, Objective::Evaluation* ev) {
  ev->ok = false;
  ev->message = why;
  ev->predictions.resize(0);
  return false;
}

}  // namespace

bool MovesDoses(const ObjectiveState& d, int i) {
  const std::vector<int>& computed = d.layout.computed_reads();  // F1 = … in $PK reads them
  return i >= d.model->num_parameters() || std::binary_search(computed.begin(), computed.end(), i);
}

// Each parameter set with the free layout parameters seeded as dual numbers (those a data
// column supplies stay constant), and the computed modifiers computed from them.
std::vector<DualVector> DualSets(const PreparedSubject& s, const ParameterLayout& layout, const FreeParameters& free) {
  const int layout_size = layout.size();
  const int pm = free.num_model();
  const std::vector<int>& model_free = free.model();
  std::vector<DualVector> sets(s.sets.size());
  for (size_t k = 0; k < s.sets.size(); ++k) {
    sets[k].resize(layout_size);
    for (int i = 0; i < layout_size; ++i) sets[k](i) = Dual(s.sets[k](i));
    for (int a = 0; a < pm; ++a) {
      if (!s.from_data[k][model_free[a]]) sets[k](model_free[a]) = Dual(s.sets[k](model_free[a]), pm, a);
    }
    layout.ComputeModifiers(&sets[k]);
  }
  return sets;
}

bool Predict(const ObjectiveState& d, const Eigen::VectorXd& values, const FreeParameters& free,
             Objective::Need need, GradientRoute route, Prediction* out, Objective::Evaluation* ev) {
  const bool events_depend = EventsDepend(d, free);
  try {
    bool done = false;
    // Covariates hold NaN in `values` when a data column supplies them: Reset checks the values used.
    if (!IntegratesOde(d.propagator) && d.linear && d.options.modal_propagation && !events_depend &&
        ModalRoute(route)) {
      done = PredictModal(d, values, free, need, route, out, &ev->predictions);
      ev->modal = done;
    }
    if (!done) PredictRoute(d, values, free, route, events_depend, out, ev);
    if (route == GradientRoute::kFiniteDifference && need == Objective::Need::kJacobian) {
      FdJacobian(d, values, free, &out->jacobian, &ev->ode_statistics);
    }
    if (!IntegratesOde(d.propagator) && d.linear && d.linear->has_output_offsets()) {
      AddOffsets(d, values, free, need, out, &ev->predictions);
    }
  } catch (const NumericalFailure& e) {
    return Failed(e.what(), ev);
  }
  if (!ev->predictions.allFinite()) return Failed("a prediction is not finite", ev);
  return true;
}

}  // namespace internal
}  // namespace pk
