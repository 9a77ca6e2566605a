// Objective: one evaluation is the prediction stage (prediction.h), the per-sample loss
// (sample_loss.h) and the priors, assembled into V, ∂V/∂θ and, for the Jacobian optimisers,
// residuals and the information matrix.
#include "pk/objective.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "internal_text.h"
#include "objective/objective_state.h"
#include "objective/prediction.h"
#include "objective/sample_loss.h"
#include "pk/error.h"
#include "pk/ode_model.h"
#include "pk/output.h"
#include "pk/parameters.h"
#include "pk/regimen.h"
#include "pk/simulate.h"

namespace pk {

const char* ToString(Weighting w) {
  switch (w) {
    case Weighting::kUniform: return "uniform";
    case Weighting::kInverseDvSquared: return "dv2";
    case Weighting::kInverseDv: return "dv";
    case Weighting::kColumn: return "column";
  }
  return "?";
}

void ParseWeighting(const std::string& text, ObjectiveOptions* options) {
  if (text == "uniform") {
    options->weighting = Weighting::kUniform;
  } else if (text == "dv2") {
    options->weighting = Weighting::kInverseDvSquared;
  } else if (text == "dv") {
    options->weighting = Weighting::kInverseDv;
  } else if (text.rfind("column:", 0) == 0 && text.size() > 7) {
    options->weighting = Weighting::kColumn;
    options->weight_column = text.substr(7);
  } else {
    throw InputError("expected uniform, dv2, dv or column:NAME, got '" + text + "'");
  }
}

const char* ToString(GradientRoute r) {
  switch (r) {
    case GradientRoute::kAuto: return "auto";
    case GradientRoute::kForward: return "forward";
    case GradientRoute::kAdjoint: return "adjoint";
    case GradientRoute::kFiniteDifference: return "fd";
    case GradientRoute::kCompanion: return "companion";
  }
  return "?";
}

GradientRoute ParseGradientRoute(const std::string& text) {
  for (GradientRoute r : {GradientRoute::kAuto, GradientRoute::kForward, GradientRoute::kAdjoint,
                          GradientRoute::kFiniteDifference, GradientRoute::kCompanion}) {
    if (text == ToString(r)) return r;
  }
  throw InputError("expected auto, forward, adjoint, fd or companion, got '" + text + "'");
}

bool ObjectiveOptions::IsValid(std::string* error) const {
  auto fail = [&](const std::string& why) {
    if (error) *error = why;
    return false;
  };
  if (!error_model) return fail("no residual-error model");
  if (weighting == Weighting::kColumn && weight_column.empty()) return fail("column weighting needs a column name");
  if (error_model->is_likelihood() && weighting != Weighting::kUniform) {
    return fail("weights apply to least squares; maximum likelihood weights samples by its error model");
  }
  if (!(fd_relative_step >= 0 && fd_relative_step < 0.1)) {
    return fail("fd_relative_step must be in (0, 0.1), or 0 for automatic");
  }
  return ode.IsValid(error);
}

namespace {

std::unique_ptr<internal::ObjectiveState> MakeState(std::shared_ptr<const Model> model,
                                                    std::shared_ptr<const Dataset> data, int subject,
                                                    const ObjectiveOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw InputError(why);
  return std::make_unique<internal::ObjectiveState>(std::move(model), std::move(data), subject, options);
}

}  // namespace

Objective::Objective(std::shared_ptr<const Model> model, std::shared_ptr<const Dataset> data, int subject,
                     const ObjectiveOptions& options, std::vector<LogNormalPrior> priors)
    : impl_(MakeState(std::move(model), std::move(data), subject, options)) {
  internal::BindSamples(impl_.get(), priors);
}

Objective::~Objective() = default;
Objective::Objective(Objective&&) noexcept = default;

const std::vector<std::string>& Objective::parameter_names() const { return impl_->names; }

int Objective::ParameterIndex(const std::string& name) const {
  const std::string upper = internal::ToUpper(name);
  for (size_t i = 0; i < impl_->names.size(); ++i) {
    if (impl_->names[i] == upper) return static_cast<int>(i);
  }
  return -1;
}

Eigen::VectorXd Objective::DefaultValues() const {
  const internal::ObjectiveState& d = *impl_;
  Eigen::VectorXd v(d.names.size());
  v.head(d.L()) = d.layout.Defaults();
  const std::vector<double> sigma = DefaultSigmas(*d.error, d.y, d.outputs);
  for (size_t j = 0; j < d.sigma.size(); ++j) v(d.sigma[j]) = sigma[j];
  return v;
}

Eigen::VectorXd Objective::RecordParameters(const Eigen::VectorXd& values, int record) const {
  const internal::ObjectiveState& d = *impl_;
  internal::PreparedSubject s = d.prepared;
  internal::RebindParameters(d.layout, values.head(d.L()), &s);
  const auto r = static_cast<size_t>(record);
  if (r >= s.set_of_record.size()) throw std::out_of_range("Objective::RecordParameters: no record " + std::to_string(record));
  return s.sets[static_cast<size_t>(s.set_of_record[r])].head(d.model->num_parameters());
}

int Objective::num_samples() const { return static_cast<int>(impl_->y.size()); }
bool Objective::has_continuous_records() const { return !impl_->ode.continuous.empty(); }
Propagator Objective::propagator() const { return impl_->propagator; }
int Objective::num_residuals() const { return num_samples() + static_cast<int>(impl_->priors.size()); }
const Eigen::VectorXd& Objective::observations() const { return impl_->y; }
const Eigen::VectorXd& Objective::weights() const { return impl_->w; }
const Eigen::VectorXi& Objective::censoring() const { return impl_->cens; }
int Objective::num_censored() const { return static_cast<int>(impl_->cens.cwiseAbs().sum()); }
std::vector<double> Objective::sample_times() const { return impl_->times; }
std::vector<int> Objective::sample_records() const {
  std::vector<int> out;
  for (size_t r = 0; r < impl_->ode.sample_of_record.size(); ++r) {
    if (impl_->ode.sample_of_record[r] >= 0) out.push_back(static_cast<int>(r));
  }
  return out;
}
std::vector<int> Objective::sample_outputs() const {
  std::vector<int> out;
  for (size_t r = 0; r < impl_->ode.sample_of_record.size(); ++r) {
    if (impl_->ode.sample_of_record[r] >= 0) out.push_back(internal::OutputOfKey(*impl_->model, impl_->ode.key_of_record[r]));
  }
  return out;
}
double Objective::subject_id() const { return impl_->data->subjects[impl_->subject].id; }
const Model& Objective::model() const { return *impl_->model; }
const ObjectiveOptions& Objective::options() const { return impl_->options; }
const ResidualErrorModel& Objective::error_model() const { return *impl_->error; }
std::vector<int> Objective::sigma_indices() const { return impl_->sigma; }

Objective::Evaluation Objective::Evaluate(const Eigen::VectorXd& values, const std::vector<int>& free,
                                          Need need) const {
  return Evaluate(values, free, need, impl_->options.gradient);
}

namespace {

using Need = Objective::Need;

// The route that computes the derivatives `need` asks for.
GradientRoute ResolveRoute(GradientRoute route, Need need, int num_model, bool ode, bool adjoint) {
  if (route == GradientRoute::kAuto) {
    if (need == Need::kJacobian) {
      route = GradientRoute::kForward;
    } else if (ode) {
      route = num_model > kOdeAdjointThreshold ? GradientRoute::kAdjoint : GradientRoute::kForward;
    } else {
      route = GradientRoute::kAdjoint;
    }
  }
  if (need == Need::kJacobian && route == GradientRoute::kAdjoint) route = GradientRoute::kForward;
  if (!adjoint && route == GradientRoute::kAdjoint) route = GradientRoute::kForward;
  if (need == Need::kValue) route = GradientRoute::kAuto;
  return route;
}

void AddPriorTerms(const internal::ObjectiveState& d, const Eigen::VectorXd& values, double* value) {
  for (const auto& p : d.priors) {
    const double z = (std::log(values(p.index)) - p.log_median) / p.sd;
    *value += 0.5 * z * z;
  }
}

// ∂V/∂θ by central differences of V.
void FdGradient(const Objective& objective, double step, const Eigen::VectorXd& values, const std::vector<int>& free,
                Objective::Evaluation* ev) {
  const int p = static_cast<int>(free.size());
  ev->gradient = Eigen::VectorXd::Zero(p);
  for (int k = 0; k < p; ++k) {
    const int i = free[k];
    const double h = std::max(std::fabs(values(i)), 1e-8) * step;
    Eigen::VectorXd vp = values, vm = values;
    vp(i) += h;
    vm(i) -= h;
    const Objective::Evaluation ep = objective.Evaluate(vp, free, Need::kValue);
    const Objective::Evaluation em = objective.Evaluate(vm, free, Need::kValue);
    if (!ep.ok || !em.ok) {
      ev->ok = false;
      ev->message = "finite differences: " + (ep.ok ? em.message : ep.message);
      return;
    }
    ev->gradient(k) = (ep.value - em.value) / (2 * h);
  }
}

// The σ and prior terms of the gradient; the priors' Hessian (diagonal) when `prior_hess` is sized.
void AddSigmaAndPriorGradient(const internal::ObjectiveState& d, const internal::SampleLoss& loss,
                              const Eigen::VectorXd& values, const std::vector<int>& free, Eigen::VectorXd* gradient,
                              Eigen::VectorXd* prior_hess) {
  const int p = static_cast<int>(free.size());
  for (size_t q = 0; q < d.sigma.size(); ++q) {
    for (int k = 0; k < p; ++k) {
      if (free[k] != d.sigma[q]) continue;
      for (Eigen::Index j = 0; j < loss.dl_dv.size(); ++j) {
        (*gradient)(k) += loss.dl_dv(j) * loss.dv_dsigma(j, static_cast<Eigen::Index>(q));
      }
    }
  }
  for (const auto& prior : d.priors) {
    for (int k = 0; k < p; ++k) {
      if (free[k] != prior.index) continue;
      const double th = values(prior.index);
      (*gradient)(k) += (std::log(th) - prior.log_median) / (prior.sd * prior.sd * th);
      if (prior_hess->size()) (*prior_hess)(k) += 1 / (prior.sd * prior.sd * th * th);
    }
  }
}

// Least squares: the samples' residuals r_k = √W_k (y_k − ŷ_k), then one row per prior, so that
// ½‖r‖² = V exactly; their Jacobian and the Gauss–Newton matrix.
void LeastSquaresJacobian(const internal::ObjectiveState& d, const internal::SampleLoss& loss,
                          const internal::FreeParameters& fp, const Eigen::MatrixXd& jm,
                          const Eigen::VectorXd& values, const std::vector<int>& free, Objective::Evaluation* ev) {
  const Eigen::Index n = d.y.size();
  const int np = static_cast<int>(d.priors.size()), p = static_cast<int>(free.size());
  const Eigen::ArrayXd sw = d.w.array().sqrt();
  ev->residuals.resize(n + np);
  ev->jacobian = Eigen::MatrixXd::Zero(n + np, p);
  ev->residuals.head(n) = (sw * loss.r.array()).matrix();
  for (int a = 0; a < fp.num_model(); ++a) ev->jacobian.col(fp.Position(a)).head(n) = -(jm.col(a).array() * sw).matrix();
  for (int q = 0; q < np; ++q) {
    const auto& prior = d.priors[static_cast<size_t>(q)];
    const double th = values(prior.index);
    ev->residuals(n + q) = (std::log(th) - prior.log_median) / prior.sd;
    for (int k = 0; k < p; ++k) {
      if (free[k] == prior.index) ev->jacobian(n + q, k) = 1 / (prior.sd * th);
    }
  }
  ev->information = ev->jacobian.transpose() * ev->jacobian;
}

// Maximum likelihood: the expected information over every free parameter (σ columns of ∇μ are 0).
void LikelihoodInformation(const internal::ObjectiveState& d, const internal::SampleLoss& loss,
                           const internal::FreeParameters& fp, const Eigen::MatrixXd& jm, const std::vector<int>& free,
                           Objective::Evaluation* ev) {
  const int p = static_cast<int>(free.size());
  Eigen::MatrixXd jy = Eigen::MatrixXd::Zero(d.y.size(), p);  // ∇μ, μ = ŷ or log ŷ
  for (int a = 0; a < fp.num_model(); ++a) {
    jy.col(fp.Position(a)) = (jm.col(a).array() * loss.dmu_dy.array()).matrix();
  }
  std::vector<int> sigma_of(static_cast<size_t>(p), -1);
  for (int k = 0; k < p; ++k) {
    for (size_t q = 0; q < d.sigma.size(); ++q) {
      if (free[k] == d.sigma[q]) sigma_of[static_cast<size_t>(k)] = static_cast<int>(q);
    }
  }
  ev->information = internal::SampleInformation(loss, d.cens, jy, sigma_of);
}

}  // namespace

Objective::Evaluation Objective::Evaluate(const Eigen::VectorXd& values, const std::vector<int>& free, Need need,
                                          GradientRoute route) const {
  const internal::ObjectiveState& d = *impl_;
  Evaluation ev;
  const internal::FreeParameters fp(free, d.L());
  const int pm = fp.num_model();
  ev.propagator = ToString(d.propagator);
  // The Runge–Kutta integrator's adjoint does not cover continuous records: route (a) there.
  route = ResolveRoute(route, need, pm, IntegratesOde(d.propagator),
                       d.propagator != Propagator::kRungeKutta || d.ode.continuous.empty());
  ev.route = need == Need::kValue ? "none" : ToString(route);
  if (need == Need::kJacobian && !d.ode.continuous.empty()) {
    ev.ok = false;
    ev.message = "continuous records (CONT=1) give no residual vector: use a gradient optimiser (bfgs or nlopt:...)";
    return ev;
  }
  internal::Prediction pred;
  if (!internal::Predict(d, values, fp, need, route, &pred, &ev)) return ev;

  internal::SampleLoss loss;
  Eigen::VectorXd dl_dy_here;
  Eigen::VectorXd& dl_dy = *pred.LossGradientStorage(&dl_dy_here);  // ∂ℓ/∂ŷ
  std::vector<double> sigma(d.sigma.size());
  d.Sigmas(values, sigma.data());
  if (!internal::ComputeSampleLoss(*d.error, {&d.y, &d.w, &d.cens, &d.times, &d.outputs}, sigma.data(), ev.predictions,
                                   need == Need::kJacobian, &loss, &dl_dy, &ev.message)) {
    ev.ok = false;
    return ev;
  }
  ev.value = loss.value;
  ev.value += pred.continuous_loss;
  AddPriorTerms(d, values, &ev.value);
  if (!std::isfinite(ev.value)) {
    ev.ok = false;
    ev.message = "the objective is not finite";
    return ev;
  }
  if (need == Need::kValue) return ev;
  if (route == GradientRoute::kFiniteDifference && need == Need::kGradient) {
    FdGradient(*this, d.FdStep(), values, free, &ev);
    return ev;
  }
  Eigen::VectorXd gm;  // ∂V/∂θ over the free model parameters
  if (!pred.ModelGradient(dl_dy, pm, &gm, &ev)) return ev;
  if (fp.all_model()) {
    ev.gradient = std::move(gm);
  } else {
    ev.gradient = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(free.size()));
    for (int a = 0; a < pm; ++a) ev.gradient(fp.Position(a)) = gm(a);
  }
  Eigen::VectorXd prior_hess;  // for the information matrix
  if (need == Need::kJacobian) prior_hess.setZero(static_cast<Eigen::Index>(free.size()));
  AddSigmaAndPriorGradient(d, loss, values, free, &ev.gradient, &prior_hess);
  if (need != Need::kJacobian) return ev;
  if (!d.likelihood()) {
    LeastSquaresJacobian(d, loss, fp, pred.jacobian, values, free, &ev);
    return ev;
  }
  LikelihoodInformation(d, loss, fp, pred.jacobian, free, &ev);
  ev.information.diagonal() += prior_hess;
  return ev;
}

bool Objective::Sensitivities(const Eigen::VectorXd& values, const std::vector<int>& free,
                              Eigen::VectorXd* predictions, Eigen::MatrixXd* jacobian, std::string* why) const {
  const internal::ObjectiveState& d = *impl_;
  if (!d.ode.continuous.empty()) {
    *why = "continuous records (CONT=1) are a loss, not predictions at samples";
    return false;
  }
  const internal::FreeParameters fp(free, d.L());
  const Need need = jacobian ? Need::kJacobian : Need::kValue;
  const GradientRoute route = jacobian ? GradientRoute::kForward : GradientRoute::kAuto;
  Evaluation ev;
  internal::Prediction pred;
  if (!internal::Predict(d, values, fp, need, route, &pred, &ev)) {
    *why = ev.message;
    return false;
  }
  *predictions = std::move(ev.predictions);
  if (!jacobian) return true;
  const Eigen::Index n = predictions->size();
  if (fp.all_model()) {
    *jacobian = pred.jacobian.topRows(n);
    return true;
  }
  jacobian->setZero(n, static_cast<Eigen::Index>(free.size()));
  for (int a = 0; a < fp.num_model(); ++a) jacobian->col(fp.Position(a)) = pred.jacobian.col(a).head(n);
  return true;
}

Eigen::VectorXd Objective::ScaledResiduals(const Eigen::VectorXd& values, const Eigen::VectorXd& predictions) const {
  const internal::ObjectiveState& d = *impl_;
  const Eigen::VectorXd r = d.y - predictions;
  if (!d.likelihood()) return (d.w.array().sqrt() * r.array()).matrix();
  std::vector<double> sigma(d.sigma.size());
  d.Sigmas(values, sigma.data());
  Eigen::VectorXd out(r.size());
  for (Eigen::Index k = 0; k < r.size(); ++k) {
    const double sd = OutputStandardDeviation(*d.error, d.outputs(k), predictions(k), sigma.data());
    if (d.cens(k) != 0) {
      out(k) = std::numeric_limits<double>::quiet_NaN();
    } else if (OutputLogTransformed(*d.error, d.outputs(k))) {
      out(k) = (std::log(d.y(k)) - std::log(predictions(k))) / sd;
    } else {
      out(k) = r(k) / sd;
    }
  }
  return out;
}

void Objective::CheckValues(const Eigen::VectorXd& values) const {
  internal::PrepareSubject(*impl_->model, impl_->layout, *impl_->data, impl_->subject, values.head(impl_->L()), true);
}

std::vector<double> Objective::PredictAt(const Eigen::VectorXd& values, const std::vector<double>& times,
                                         int output) const {
  const internal::ObjectiveState& d = *impl_;
  // This subject alone (not a copy of the whole dataset), with output records at `times`.
  std::vector<std::string> read = d.names;  // the columns a simulation reads (as in SimulateSubject)
  read.push_back("DVID");
  const Dataset one = SubjectWithOutputTimes(*d.data, d.subject, times, read);
  ParameterValues named;
  for (int i = 0; i < d.L(); ++i) {
    // A modifier computed in $PK follows from the others (and cannot be given).
    if (std::isfinite(values(i)) && !d.layout.is_computed(i)) named[d.names[i]] = values(i);
  }
  SimulationOptions opts;
  opts.track_auc = false;
  opts.check_values = false;  // fitted values, possibly at the edge of their range
  opts.propagator = d.propagator;
  opts.ode = d.options.ode;
  const SubjectSimulation sim = SimulateSubject(*d.model, one, 0, named, opts);
  std::vector<double> out;
  if (!sim.ok) return std::vector<double>(times.size(), std::numeric_limits<double>::quiet_NaN());
  for (size_t i = 0; i < sim.rows.size(); ++i) {
    const SimulatedRecord& row = sim.rows[i];
    // A reset that sets TIME back gives each later period the times again: the curve is the first period's.
    if (out.size() == times.size()) break;
    if (one.subjects[0].records[row.record].line != -1) continue;
    out.push_back(output > 1 && output <= sim.outputs.rows() ? sim.outputs(output - 1, static_cast<Eigen::Index>(i))
                                                              : row.cp);
  }
  return out;
}

}  // namespace pk
