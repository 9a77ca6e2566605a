#include "pk/objective.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <mutex>
#include <sstream>

#include "autodiff.h"
#include "censoring.h"
#include "events.h"
#include "exact/exact_propagator.h"
#include "exact/companion_route.h"
#include "exact/exact_routes.h"
#include "exact/modal.h"
#include "internal_text.h"
#include "pk/error.h"
#include "pk/linear_model.h"
#include "pk/ode_model.h"
#include "pk/output.h"
#include "ode/ode_routes.h"
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

const char* ToString(ErrorModel e) {
  switch (e) {
    case ErrorModel::kLeastSquares: return "least-squares";
    case ErrorModel::kAdditive: return "additive";
    case ErrorModel::kProportional: return "proportional";
    case ErrorModel::kCombined: return "combined";
    case ErrorModel::kExponential: return "exponential";
  }
  return "?";
}

bool IsResidualErrorName(const std::string& name) {
  return name == kSigmaAdd || name == kSigmaProp || name == kSigmaLog;
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

bool ObjectiveOptions::IsValid(std::string* error) const {
  auto fail = [&](const std::string& why) {
    if (error) *error = why;
    return false;
  };
  if (weighting == Weighting::kColumn && weight_column.empty()) return fail("column weighting needs a column name");
  if (error_model != ErrorModel::kLeastSquares && weighting != Weighting::kUniform) {
    return fail("weights apply to least squares; maximum likelihood weights samples by its error model");
  }
  if (!(fd_relative_step >= 0 && fd_relative_step < 0.1)) {
    return fail("fd_relative_step must be in (0, 0.1), or 0 for automatic");
  }
  return ode.IsValid(error);
}

struct Objective::Impl {
  std::shared_ptr<const Model> model;
  const LinearModel* linear = nullptr;
  std::shared_ptr<const Dataset> data;
  int subject = 0;
  ObjectiveOptions options;
  ParameterLayout layout;
  internal::PreparedSubject prepared;
  std::vector<std::string> names;
  // σ_k² = a² + (b ŷ_k)² with a = values(sigma_add), b = values(sigma_prop)
  // (−1: absent); the exponential model's SIGMA_LOG takes a's place, on log scale.
  int sigma_add = -1, sigma_prop = -1;
  bool log_scale = false;  // exponential error: samples and predictions compared as logarithms
  Eigen::VectorXd y, w;
  Eigen::VectorXi cens;  // per sample: 0, or ±1 for a value beyond DV (CENS)
  std::vector<double> times;
  Propagator propagator = Propagator::kExact;
  std::unique_ptr<internal::OdeSystem> ode_system;
  internal::OdeSubject ode;
  struct Prior {
    int index;
    double log_median, sd;
  };
  std::vector<Prior> priors;
  double default_sigma_add = 1;

  Impl(std::shared_ptr<const Model> m, std::shared_ptr<const Dataset> d, int subj, const ObjectiveOptions& o)
      : model(std::move(m)), data(std::move(d)), subject(subj), options(o), layout(*model) {}

  int L() const { return layout.size(); }
  // The event schedule for the modal path, recorded for the dose-modifier values it was last asked for.
  mutable std::mutex schedule_mutex;
  mutable std::shared_ptr<const internal::EventSchedule> schedule;

  std::shared_ptr<const internal::EventSchedule> Schedule(const Eigen::VectorXd& values) const {
    const int m = model->num_parameters();
    const auto key = values.segment(m, L() - m);
    {
      std::lock_guard<std::mutex> lock(schedule_mutex);
      // Unused modifiers are NaN: NaN matches NaN.
      if (schedule && internal::SameValues(schedule->key, key)) return schedule;
    }
    internal::PreparedSubject s = prepared;
    internal::RebindParameters(layout, values.head(L()), &s);
    auto made = std::make_shared<internal::EventSchedule>(internal::RecordSchedule(layout, s, m));
    made->key = key;
    std::lock_guard<std::mutex> lock(schedule_mutex);
    schedule = made;
    return made;
  }

  // Modal evaluators with what they last replayed, kept between evaluations
  // for their storage (one per concurrent evaluation). The last one handed back
  // waits in `modal_spare`, which a sequential caller (an optimiser) takes and
  // returns without a lock; concurrent callers use the pool behind the mutex.
  struct ModalWork {
    std::unique_ptr<internal::ModalEvaluator> evaluator;
    std::shared_ptr<const internal::EventSchedule> schedule;  // the schedule it replays
    Eigen::VectorXd dl_dy;  // Evaluate's ∂ℓ/∂ŷ, kept for its storage
  };
  mutable std::atomic<ModalWork*> modal_spare{nullptr};
  mutable std::mutex modal_mutex;
  mutable std::vector<std::unique_ptr<ModalWork>> modal_pool;
  ~Impl() { delete modal_spare.load(); }

  // Hands a ModalWork back when the evaluation ends.
  struct ModalLease {
    const Impl* owner = nullptr;
    std::unique_ptr<ModalWork> work;
    ModalLease() = default;
    ModalLease(const ModalLease&) = delete;
    ModalLease& operator=(const ModalLease&) = delete;
    ~ModalLease() {
      if (owner == nullptr || !work) return;
      ModalWork* empty = nullptr;
      if (owner->modal_spare.compare_exchange_strong(empty, work.get())) {
        work.release();
        return;
      }
      std::lock_guard<std::mutex> lock(owner->modal_mutex);
      owner->modal_pool.push_back(std::move(work));
    }
  };

  // The modal evaluator at `values`, leased into `lease` (null when some set's A
  // is unsuitable; see exact/modal.h). Its schedule is re-recorded only when
  // the dose modifiers' values changed.
  internal::ModalEvaluator* Modal(const Eigen::VectorXd& values, const std::vector<int>& model_free,
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
      lease->work->evaluator = internal::NewModalEvaluator(*linear);
    }
    lease->owner = this;
    ModalWork& w = *lease->work;
    const int m = model->num_parameters();
    if (!w.schedule || !internal::SameValues(w.schedule->key, values.segment(m, L() - m))) {
      w.schedule = Schedule(values);
    }
    if (!w.evaluator->Reset(*w.schedule, values, prepared, model_free)) return nullptr;
    return w.evaluator.get();
  }

  double FdStep() const {
    if (options.fd_relative_step > 0) return options.fd_relative_step;
    return propagator == Propagator::kOde ? std::cbrt(options.ode.relative_tolerance) : 1e-5;
  }
};

Objective::Objective(std::shared_ptr<const Model> model, std::shared_ptr<const Dataset> data, int subject,
                     const ObjectiveOptions& options, std::vector<LogNormalPrior> priors)
    : impl_(new Impl(std::move(model), std::move(data), subject, options)) {
  Impl& d = *impl_;
  std::string why;
  if (!options.IsValid(&why)) throw InputError("", 0, 0, why);
  d.linear = dynamic_cast<const LinearModel*>(d.model.get());
  d.propagator = ResolvePropagator(*d.model, options.propagator);
  // Dose modifiers (R, D, ...) are checked when values are given (CheckValues).
  d.prepared = internal::PrepareSubject(*d.model, d.layout, *d.data, subject, d.layout.Defaults(), false);
  const int cont_col = d.data->ExtraColumn("CONT");
  const int dvid_col = d.data->ExtraColumn("DVID");
  const int cens_col = d.data->ExtraColumn("CENS");
  const bool ml = options.error_model != ErrorModel::kLeastSquares;
  const auto* ode_model = dynamic_cast<const OdeModel*>(d.model.get());
  if (d.propagator == Propagator::kOde) {
    d.ode_system.reset(new internal::OdeSystem(*d.model));
    d.ode.system = d.ode_system.get();
    d.ode.layout = &d.layout;
    d.ode.options = options.ode;
  }
  d.names = d.layout.names();
  if (options.error_model == ErrorModel::kAdditive || options.error_model == ErrorModel::kCombined) {
    d.sigma_add = static_cast<int>(d.names.size());
    d.names.push_back(kSigmaAdd);
  }
  if (options.error_model == ErrorModel::kExponential) {
    d.sigma_add = static_cast<int>(d.names.size());
    d.names.push_back(kSigmaLog);
    d.log_scale = true;
  }
  if (options.error_model == ErrorModel::kProportional || options.error_model == ErrorModel::kCombined) {
    d.sigma_prop = static_cast<int>(d.names.size());
    d.names.push_back(kSigmaProp);
  }
  const int weight_col = options.weighting == Weighting::kColumn ? d.data->ExtraColumn(options.weight_column) : -1;
  if (options.weighting == Weighting::kColumn && weight_col < 0) {
    throw InputError(d.data->source, 0, 0, "no weight column '" + options.weight_column + "'");
  }
  std::vector<double> ys, ws;
  std::vector<int> cs;
  double sum_abs = 0;
  const std::vector<Record>& records = d.prepared.records();
  d.ode.key_of_record.assign(records.size(), 0);
  d.ode.sample_of_record.assign(records.size(), -1);
  for (size_t ri = 0; ri < records.size(); ++ri) {
    const Record& r = records[ri];
    d.ode.key_of_record[ri] = ode_model ? internal::OutputOfRecord(*ode_model, *d.data, r, dvid_col)
                                        : d.prepared.cmt[ri] + 1;
    if (!r.IsSample()) continue;
    // A nonlinear model's outputs are g(x, θ), chosen by DVID; a CMT that names
    // another compartment would otherwise be ignored without a word.
    if (ode_model && r.cmt > 0 && r.cmt != ode_model->central_compartment() &&
        (dvid_col < 0 || std::isnan(r.extra[dvid_col]))) {
      std::string outputs;
      for (int k = 0; k < ode_model->num_outputs(); ++k) {
        outputs += (k ? ", " : "") + std::to_string(k + 1) + "=" + ode_model->output_names()[k];
      }
      throw InputError(d.data->source, r.line, d.data->ColumnNumber("CMT"),
                       "CMT " + std::to_string(r.cmt) + " on an observation: model " + ode_model->name() +
                           " predicts its outputs (" + outputs + "), chosen by DVID, not a compartment's amount; give " +
                           "CMT 0 or " + std::to_string(ode_model->central_compartment()) +
                           " (the central compartment), or a DVID");
    }
    const bool continuous = cont_col >= 0 && r.extra[cont_col] == 1;
    const int censored = internal::CheckedCensoring(*d.data, r, cens_col, ml);
    if (continuous && censored != 0) {
      throw InputError(d.data->source, r.line, d.data->ColumnNumber("CENS"),
                       "a continuous record (CONT=1) cannot be censored");
    }
    if (continuous && d.propagator != Propagator::kOde) {
      throw InputError(d.data->source, r.line, d.data->ColumnNumber("CONT"),
                       "continuous records (CONT=1) need the ODE propagator (--propagator ode)");
    }
    if (continuous && ml) {
      throw InputError(d.data->source, r.line, d.data->ColumnNumber("CONT"),
                       "continuous records (CONT=1) are fitted by least squares, not maximum likelihood");
    }
    double w = 1;
    const auto bad = [&](const std::string& what) {
      throw InputError(d.data->source, r.line, d.data->ColumnNumber(what == "weight" ? options.weight_column : "DV"),
                       std::string("weighting ") + ToString(options.weighting) + " needs " +
                           (what == "weight" ? "a finite weight >= 0" : "DV != 0") + " on every sample");
    };
    switch (options.weighting) {
      case Weighting::kUniform: break;
      case Weighting::kInverseDvSquared:
        if (r.dv == 0) bad("DV");
        w = 1 / (r.dv * r.dv);
        break;
      case Weighting::kInverseDv:
        if (r.dv == 0) bad("DV");
        w = 1 / std::fabs(r.dv);
        break;
      case Weighting::kColumn:
        w = r.extra[weight_col];
        if (!std::isfinite(w) || w < 0) bad("weight");
        break;
    }
    if (continuous) {
      const int key = d.ode.key_of_record[ri];
      auto& series = d.ode.continuous.series;
      auto it = std::find_if(series.begin(), series.end(), [&](const auto& x) { return x.key == key; });
      if (it == series.end()) {
        series.push_back({});
        series.back().key = key;
        it = series.end() - 1;
      }
      if (!it->t.empty() && !(r.time > it->t.back())) {
        throw InputError(d.data->source, r.line, d.data->ColumnNumber("TIME"),
                         "continuous records (CONT=1) of one output need increasing times");
      }
      it->t.push_back(r.time);
      it->y.push_back(r.dv);
      it->w.push_back(w);
      continue;
    }
    if (d.log_scale && !(r.dv > 0)) {
      throw InputError(d.data->source, r.line, d.data->ColumnNumber("DV"),
                       "the exponential error model compares log DV with log PRED, so DV must be > 0, not " +
                           FormatNumber(r.dv) + (censored != 0 ? " (a censored sample's limit)" : "") +
                           "; give a sample below the limit of quantification CENS=1 and DV = the limit, or MDV=1");
    }
    d.ode.sample_of_record[ri] = static_cast<int>(ys.size());
    ys.push_back(r.dv);
    ws.push_back(w);
    cs.push_back(censored);
    d.times.push_back(r.time);
    sum_abs += std::fabs(r.dv);
  }
  d.ode.num_samples = static_cast<int>(ys.size());
  d.y = Eigen::Map<Eigen::VectorXd>(ys.data(), static_cast<Eigen::Index>(ys.size()));
  d.w = Eigen::Map<Eigen::VectorXd>(ws.data(), static_cast<Eigen::Index>(ws.size()));
  d.cens = Eigen::Map<Eigen::VectorXi>(cs.data(), static_cast<Eigen::Index>(cs.size()));
  d.default_sigma_add = ys.empty() || sum_abs == 0 ? 1.0 : 0.1 * sum_abs / static_cast<double>(ys.size());
  for (const LogNormalPrior& p : priors) {
    const int i = ParameterIndex(p.parameter);
    if (i < 0) throw InputError("", 0, 0, "prior on unknown parameter '" + p.parameter + "'");
    if (!(p.median > 0) || !(p.sd_log > 0)) throw InputError("", 0, 0, "prior on " + p.parameter + " needs median > 0 and sd > 0");
    d.priors.push_back({i, std::log(p.median), p.sd_log});
  }
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
  Eigen::VectorXd v(impl_->names.size());
  v.head(impl_->L()) = impl_->layout.Defaults();
  if (impl_->sigma_add >= 0) v(impl_->sigma_add) = impl_->log_scale ? 0.2 : impl_->default_sigma_add;
  if (impl_->sigma_prop >= 0) v(impl_->sigma_prop) = 0.1;
  return v;
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
std::vector<int> Objective::sample_outputs() const {
  std::vector<int> out;
  const bool ode_model = dynamic_cast<const OdeModel*>(impl_->model.get()) != nullptr;
  for (size_t r = 0; r < impl_->ode.sample_of_record.size(); ++r) {
    if (impl_->ode.sample_of_record[r] >= 0) out.push_back(ode_model ? impl_->ode.key_of_record[r] : 1);
  }
  return out;
}
double Objective::subject_id() const { return impl_->data->subjects[impl_->subject].id; }
const Model& Objective::model() const { return *impl_->model; }
const ObjectiveOptions& Objective::options() const { return impl_->options; }

Objective::Evaluation Objective::Evaluate(const Eigen::VectorXd& values, const std::vector<int>& free,
                                          Need need) const {
  return Evaluate(values, free, need, impl_->options.gradient);
}

namespace {
const std::vector<int> kNoParameters;  // a value alone: no parameter needs derivatives
}  // namespace

Objective::Evaluation Objective::Evaluate(const Eigen::VectorXd& values, const std::vector<int>& free, Need need,
                                          GradientRoute route) const {
  const Impl& d = *impl_;
  const int L = d.L();
  const int N = num_samples();
  const int P = static_cast<int>(free.size());
  Evaluation ev;
  // Free layout parameters get dual-number seeds; σ are handled analytically.
  // The free layout parameters (model parameters and dose modifiers) and their positions in `free`: `free`
  // itself, in order, unless some σ is free too.
  bool all_model = true;
  for (int k = 0; k < P; ++k) all_model = all_model && free[k] < L;
  std::vector<int> model_free_subset, model_pos_subset;
  if (!all_model) {
    for (int k = 0; k < P; ++k) {
      if (free[k] < L) {
        model_free_subset.push_back(free[k]);
        model_pos_subset.push_back(k);
      }
    }
  }
  const std::vector<int>& model_free = all_model ? free : model_free_subset;  // layout indices
  const auto model_pos = [&](int a) { return all_model ? a : model_pos_subset[static_cast<size_t>(a)]; };
  const int pm = static_cast<int>(model_free.size());
  const bool ode = d.propagator == Propagator::kOde;
  ev.propagator = ToString(d.propagator);
  if (route == GradientRoute::kAuto) {
    if (need == Need::kJacobian) {
      route = GradientRoute::kForward;
    } else if (ode) {
      route = pm > kOdeAdjointThreshold ? GradientRoute::kAdjoint : GradientRoute::kForward;
    } else {
      route = GradientRoute::kAdjoint;
    }
  }
  if (need == Need::kJacobian && route == GradientRoute::kAdjoint) route = GradientRoute::kForward;
  if (route == GradientRoute::kCompanion && need == Need::kValue) route = GradientRoute::kAuto;
  if (need == Need::kValue) route = GradientRoute::kAuto;
  ev.route = need == Need::kValue ? "none" : ToString(route);
  if (need == Need::kJacobian && !d.ode.continuous.empty()) {
    ev.ok = false;
    ev.message = "continuous records (CONT=1) give no residual vector: use a gradient optimiser (bfgs or nlopt:...)";
    return ev;
  }

  Eigen::VectorXd& yhat = ev.predictions;  // ŷ (emptied again if the evaluation fails)
  Eigen::MatrixXd jm;  // N × pm, ∂ŷ/∂(free model parameters)
  std::unique_ptr<internal::DiscreteAdjoint> adjoint;
  Impl::ModalLease modal_lease;               // holds the modal evaluator and its schedule
  internal::ModalEvaluator* modal = nullptr;  // route (b) in eigen-coordinates
  std::unique_ptr<internal::OdeAdjoint> ode_adjoint;
  double cont_loss = 0;                                    // ½∫ w (y − y_m)² of the continuous records
  Eigen::RowVectorXd cont_grad;                            // its gradient (ODE forward route)
  // Predictions alone at other values (finite differences).
  auto predict = [&](const Eigen::VectorXd& v, Eigen::VectorXd* y, double* cl) {
    internal::PreparedSubject sv = d.prepared;
    internal::RebindParameters(d.layout, v.head(L), &sv);
    *cl = 0;
    if (ode) {
      internal::OdePredict(d.ode, sv, y, cl, &ev.ode_statistics);
    } else {
      internal::Predict(*d.linear, d.layout, sv, y);
    }
  };
  // Dose modifiers move event times and amounts; model parameters do not.
  bool events_depend = false;
  const int num_model_parameters = d.model->num_parameters();
  for (int i : model_free) events_depend = events_depend || i >= num_model_parameters;
  const bool modal_route =
      route == GradientRoute::kAuto || route == GradientRoute::kForward || route == GradientRoute::kAdjoint;
  bool done = false;
  if (!ode && d.linear && d.options.modal_propagation && !events_depend && modal_route &&
      values.head(num_model_parameters).allFinite()) {
    try {
      // A value alone needs no partials of A.
      internal::ModalEvaluator* ev_modal =
          d.Modal(values, need == Need::kValue ? kNoParameters : model_free, &modal_lease);
      if (ev_modal) {
        if (route == GradientRoute::kForward && pm > 0) {
          ev_modal->Jacobian(&yhat, &jm);
        } else if (route == GradientRoute::kAdjoint && pm > 0) {
          ev_modal->AdjointForward(&yhat);
          modal = ev_modal;
        } else {
          ev_modal->Predict(&yhat);
          jm = Eigen::MatrixXd::Zero(N, pm);
        }
        done = true;
        ev.modal = true;
      }
    } catch (const internal::NumericalFailure& e) {
      ev.ok = false;
      ev.message = e.what();
      yhat.resize(0);
      return ev;
    }
  }
  internal::PreparedSubject s;  // the subject at `values`, for the other paths
  try {
    if (!done) {
      s = d.prepared;
      internal::RebindParameters(d.layout, values.head(L), &s);
    }
    auto dual_sets = [&]() {
      std::vector<internal::DualVector> sets(s.sets.size());
      for (size_t k = 0; k < s.sets.size(); ++k) {
        sets[k].resize(L);
        for (int i = 0; i < L; ++i) sets[k](i) = internal::Dual(s.sets[k](i));
        for (int a = 0; a < pm; ++a) {
          if (!s.from_data[k][model_free[a]]) sets[k](model_free[a]) = internal::Dual(s.sets[k](model_free[a]), pm, a);
        }
      }
      return sets;
    };
    if (done) {
      // The modal path above has ŷ (and ∂ŷ/∂p, or the adjoint's record).
    } else if (route == GradientRoute::kCompanion) {
      // Only the transfer function's coefficients (layout entries 0..2n−1).
      const int order = d.linear == nullptr || ode ? 0 : d.linear->transfer_function_order();
      if (order == 0) {
        throw internal::NumericalFailure("the companion route applies to tf<n> models only (with the exact propagator)");
      }
      for (int i : model_free) {
        if (i >= 2 * order) {
          throw internal::NumericalFailure("the companion route differentiates a_i and b_i only, not " +
                                           d.layout.name(i));
        }
      }
      Eigen::MatrixXd j_all;
      internal::CompanionJacobian(*d.linear, d.layout, s, &yhat, &j_all);
      jm.resize(N, pm);
      for (int a2 = 0; a2 < pm; ++a2) jm.col(a2) = j_all.col(model_free[a2]);
    } else if (ode && route == GradientRoute::kForward && pm > 0) {
      const auto sets = dual_sets();
      internal::OdeForwardSensitivities(d.ode, s, sets, pm, &yhat, &jm, &cont_loss, &cont_grad, &ev.ode_statistics);
    } else if (ode && route == GradientRoute::kAdjoint && pm > 0) {
      ode_adjoint.reset(new internal::OdeAdjoint(d.ode, s, dual_sets(), pm));
      ode_adjoint->Forward(&yhat, &cont_loss);
    } else if (route == GradientRoute::kForward && pm > 0) {
      const auto sets = dual_sets();
      internal::ForwardSensitivities(*d.linear, d.layout, s, sets, pm, events_depend, &yhat, &jm);
    } else if (route == GradientRoute::kAdjoint && pm > 0) {
      adjoint.reset(new internal::DiscreteAdjoint(*d.linear, d.layout, s, dual_sets(), pm, events_depend));
      adjoint->Forward(&yhat);
    } else {
      predict(values, &yhat, &cont_loss);
      jm = Eigen::MatrixXd::Zero(N, pm);
    }
    if (route == GradientRoute::kFiniteDifference && need == Need::kJacobian) {
      for (int a = 0; a < pm; ++a) {
        const int i = model_free[a];
        const double h = std::max(std::fabs(values(i)), 1e-8) * d.FdStep();
        Eigen::VectorXd vp = values, vm = values, yp, ym;
        vp(i) += h;
        vm(i) -= h;
        double cp, cm;
        predict(vp, &yp, &cp);
        predict(vm, &ym, &cm);
        jm.col(a) = (yp - ym) / (2 * h);
      }
    }
  } catch (const internal::NumericalFailure& e) {
    ev.ok = false;
    ev.message = e.what();
    yhat.resize(0);
    return ev;
  }
  if (!yhat.allFinite()) {
    ev.ok = false;
    ev.message = "a prediction is not finite";
    yhat.resize(0);
    return ev;
  }

  // Per-sample loss terms: value, ∂ℓ/∂ŷ, and ∂ℓ/∂σ for ML.
  Eigen::VectorXd r;  // y − ŷ, where kept (maximum likelihood, the Jacobian's residuals)
  Eigen::VectorXd dl_dy_here;
  Eigen::VectorXd& dl_dy = modal_lease.work ? modal_lease.work->dl_dy : dl_dy_here;  // ∂ℓ/∂ŷ
  dl_dy.resize(N);
  Eigen::VectorXd sigma2, ds2_dy, dl_ds2;  // maximum likelihood only
  Eigen::VectorXd dmu_dy;  // ∂μ/∂ŷ of the compared prediction μ: 1, or 1/ŷ on log scale
  Eigen::VectorXd z;  // censored samples: s(DV − ŷ)/σ, where Φ(z) is their probability (else unused)
  double value = 0;
  const double a = d.sigma_add >= 0 ? values(d.sigma_add) : 0.0;
  const double b = d.sigma_prop >= 0 ? values(d.sigma_prop) : 0.0;
  const bool ml = d.options.error_model != ErrorModel::kLeastSquares;
  if (ml || need == Need::kJacobian) r = d.y - yhat;
  if (!ml) {
    value = 0.5 * (d.w.array() * (d.y - yhat).array().square()).sum();
    dl_dy = -(d.w.array() * (d.y - yhat).array()).matrix();
  } else {
    sigma2.resize(N);
    ds2_dy.resize(N);
    dl_ds2.resize(N);
    dmu_dy.setOnes(N);
    z.setZero(N);
    // A prediction below kZeroPredictionLevel of the subject's largest is zero to rounding: the modal form gives
    // about 1e-15 for a compartment the drug has not reached yet (a sample at the time of an oral dose). With a
    // proportional error alone its variance is then zero too, and its log-variance term would be rounding noise
    // of about −70 that optimisers chase.
    const double zero_level = a == 0 ? kZeroPredictionLevel * yhat.cwiseAbs().maxCoeff() : -1.0;
    for (int k = 0; k < N; ++k) {
      sigma2(k) = a * a + b * b * yhat(k) * yhat(k);
      ds2_dy(k) = 2 * b * b * yhat(k);
      // The compared quantities: y and μ = ŷ, or log y and μ = log ŷ (exponential error).
      double y = d.y(k), mu = yhat(k);
      if (d.log_scale) {
        y = std::log(d.y(k));
        mu = std::log(yhat(k));
        dmu_dy(k) = 1 / yhat(k);
        if (!(yhat(k) > 0) && !(d.cens(k) == 1)) {  // a sample censored below its limit is certain there
          ev.ok = false;
          ev.message = "the prediction of the sample at TIME " + FormatNumber(d.times[static_cast<size_t>(k)]) +
                       " is " + FormatNumber(yhat(k)) + ": the exponential error model needs a positive prediction " +
                       "(give the sample MDV=1, or CENS=1 if it lies below a limit)";
          return ev;
        }
      }
      if (const int s = d.cens(k)) {
        // Beal's M3: the probability that the value lies beyond its limit DV,
        // ℓ_k = −log Φ(z), z = s(DV − μ)/σ (DV and μ = ŷ as logarithms for the
        // exponential error). With h = φ(z)/Φ(z): ∂ℓ/∂ŷ = −h ∂z/∂ŷ,
        // ∂z/∂ŷ = −(s/σ) ∂μ/∂ŷ − z/(2σ²) ∂σ²/∂ŷ, and ∂ℓ/∂σ² = h z/(2σ²).
        const double beyond = s * (y - mu);
        if (d.log_scale && !(yhat(k) > 0)) {  // CENS=1 with log ŷ = −∞: certainly below
          z(k) = std::numeric_limits<double>::infinity();
          dmu_dy(k) = 0;
          dl_dy(k) = 0;
          dl_ds2(k) = 0;
          continue;
        }
        if (!(sigma2(k) > 0)) {
          if (beyond > 0) {  // certainly beyond: probability 1, no information
            z(k) = std::numeric_limits<double>::infinity();
            dl_dy(k) = 0;
            dl_ds2(k) = 0;
            continue;
          }
          ev.ok = false;
          ev.message = "the censored sample at TIME " + FormatNumber(d.times[static_cast<size_t>(k)]) + " (CENS=" +
                       std::to_string(s) + ") has probability 0: its prediction " + FormatNumber(yhat(k)) +
                       " is not beyond its limit " + FormatNumber(d.y(k)) + " and its σ is 0";
          return ev;
        }
        z(k) = beyond / std::sqrt(sigma2(k));
        double log_cdf, h;
        internal::LogNormalCdf(z(k), &log_cdf, &h);
        value -= log_cdf;
        dl_dy(k) = h == 0 ? 0.0 : -h * (-s / std::sqrt(sigma2(k)) * dmu_dy(k) - z(k) / (2 * sigma2(k)) * ds2_dy(k));
        dl_ds2(k) = h == 0 ? 0.0 : h * z(k) / (2 * sigma2(k));
        continue;
      }
      if (!(sigma2(k) > 0) || std::fabs(yhat(k)) <= zero_level) {
        ev.ok = false;
        std::ostringstream os;
        os << "the residual variance of the sample at TIME " << FormatNumber(d.times[static_cast<size_t>(k)])
           << " is zero: " << (b > 0 && a == 0 ? "its prediction is 0 with a proportional error (give it MDV=1, "
                                                 "or use a combined error with SIGMA_ADD fixed)" : "a σ of 0");
        ev.message = os.str();
        return ev;
      }
      // The exponential error's density of y is that of log y over y: the log y term
      // keeps V comparable with the other error models' (it does not depend on θ).
      if (d.log_scale) {
        r(k) = y - mu;
        value += y;
      }
      value += 0.5 * (std::log(2 * M_PI * sigma2(k)) + r(k) * r(k) / sigma2(k));
      dl_ds2(k) = 0.5 * (1 / sigma2(k) - r(k) * r(k) / (sigma2(k) * sigma2(k)));
      dl_dy(k) = -r(k) / sigma2(k) * dmu_dy(k) + dl_ds2(k) * ds2_dy(k);
    }
  }
  value += cont_loss;
  for (const Impl::Prior& p : d.priors) {
    const double z = (std::log(values(p.index)) - p.log_median) / p.sd;
    value += 0.5 * z * z;
  }
  ev.value = value;
  if (!std::isfinite(value)) {
    ev.ok = false;
    ev.message = "the objective is not finite";
    return ev;
  }
  if (need == Need::kValue) return ev;

  if (route == GradientRoute::kFiniteDifference && need == Need::kGradient) {
    ev.gradient = Eigen::VectorXd::Zero(P);
    for (int k = 0; k < P; ++k) {
      const int i = free[k];
      const double h = std::max(std::fabs(values(i)), 1e-8) * d.FdStep();
      Eigen::VectorXd vp = values, vm = values;
      vp(i) += h;
      vm(i) -= h;
      const Evaluation ep = Evaluate(vp, free, Need::kValue), em = Evaluate(vm, free, Need::kValue);
      if (!ep.ok || !em.ok) {
        ev.ok = false;
        ev.message = "finite differences: " + (ep.ok ? em.message : ep.message);
        return ev;
      }
      ev.gradient(k) = (ep.value - em.value) / (2 * h);
    }
    return ev;
  }
  // ∂V/∂θ for the model parameters: the adjoint gives Σ ∂ℓ/∂ŷ ∂ŷ/∂θ directly.
  Eigen::VectorXd gm;
  if (adjoint) {
    gm = adjoint->Gradient(dl_dy);
  } else if (modal) {
    gm = modal->AdjointGradient(dl_dy);
  } else if (ode_adjoint) {
    try {
      gm = ode_adjoint->Gradient(dl_dy);  // includes the continuous records' term
      ev.ode_statistics = ode_adjoint->statistics();
    } catch (const internal::NumericalFailure& e) {
      ev.ok = false;
      ev.message = e.what();
      return ev;
    }
  } else if (pm > 0) {
    gm = jm.transpose() * dl_dy;
    if (cont_grad.size()) gm += cont_grad.transpose();
  } else {
    gm.setZero(pm);
  }
  if (all_model) {
    ev.gradient = std::move(gm);
  } else {
    ev.gradient = Eigen::VectorXd::Zero(P);
    for (int a2 = 0; a2 < pm; ++a2) ev.gradient(model_pos(a2)) = gm(a2);
  }
  // σ and the priors.
  Eigen::VectorXd ds2_dsigma_add, ds2_dsigma_prop;
  if (ml) {
    ds2_dsigma_add.resize(N);
    ds2_dsigma_prop.resize(N);
    for (int k = 0; k < N; ++k) {
      ds2_dsigma_add(k) = 2 * a;
      ds2_dsigma_prop(k) = 2 * b * yhat(k) * yhat(k);
    }
  }
  for (int k = 0; ml && k < P; ++k) {
    if (free[k] != d.sigma_add && free[k] != d.sigma_prop) continue;
    const Eigen::VectorXd& ds2 = free[k] == d.sigma_add ? ds2_dsigma_add : ds2_dsigma_prop;
    for (int j = 0; j < N; ++j) ev.gradient(k) += dl_ds2(j) * ds2(j);
  }
  Eigen::VectorXd prior_hess;  // for the information matrix
  if (need == Need::kJacobian) prior_hess.setZero(P);
  for (const Impl::Prior& p : d.priors) {
    for (int k = 0; k < P; ++k) {
      if (free[k] != p.index) continue;
      const double th = values(p.index);
      ev.gradient(k) += (std::log(th) - p.log_median) / (p.sd * p.sd * th);
      if (prior_hess.size()) prior_hess(k) += 1 / (p.sd * p.sd * th * th);
    }
  }
  if (need != Need::kJacobian) return ev;

  if (!ml) {
    // Samples first, then one row per prior, so that ½‖r‖² = V exactly.
    const int np = static_cast<int>(d.priors.size());
    const Eigen::ArrayXd sw = d.w.array().sqrt();
    ev.residuals.resize(N + np);
    ev.jacobian = Eigen::MatrixXd::Zero(N + np, P);
    ev.residuals.head(N) = (sw * r.array()).matrix();
    for (int a2 = 0; a2 < pm; ++a2) ev.jacobian.col(model_pos(a2)).head(N) = -(jm.col(a2).array() * sw).matrix();
    for (int q = 0; q < np; ++q) {
      const Impl::Prior& p = d.priors[q];
      const double th = values(p.index);
      ev.residuals(N + q) = (std::log(th) - p.log_median) / p.sd;
      for (int k = 0; k < P; ++k) {
        if (free[k] == p.index) ev.jacobian(N + q, k) = 1 / (p.sd * th);
      }
    }
    ev.information = ev.jacobian.transpose() * ev.jacobian;
    return ev;
  } else {
    // The full ∂μ/∂θ over all free parameters (σ columns are zero); μ = ŷ, or log ŷ.
    Eigen::MatrixXd jy = Eigen::MatrixXd::Zero(N, P);
    for (int a2 = 0; a2 < pm; ++a2) jy.col(model_pos(a2)) = (jm.col(a2).array() * dmu_dy.array()).matrix();
    // Expected information: Σ ∇μ∇μᵀ/σ² + ∇σ²∇σ²ᵀ/(2σ⁴) over the values; a
    // censored sample's is the Tobit model's in (μ, σ) = (μ, √σ²), ∇σ = ∇σ²/(2σ)
    // (internal::CensoredInformation).
    ev.information = Eigen::MatrixXd::Zero(P, P);
    for (int k = 0; k < N; ++k) {
      // ∇σ² = ∂σ²/∂ŷ ∇ŷ + its σ terms; ∂σ²/∂ŷ = 0 on log scale, where jy holds ∇μ = ∇ŷ/ŷ.
      Eigen::VectorXd gs = ds2_dy(k) * jy.row(k).transpose();
      for (int j = 0; j < P; ++j) {
        if (free[j] == d.sigma_add) gs(j) += ds2_dsigma_add(k);
        if (free[j] == d.sigma_prop) gs(j) += ds2_dsigma_prop(k);
      }
      if (d.cens(k) == 0) {
        ev.information +=
            jy.row(k).transpose() * jy.row(k) / sigma2(k) + gs * gs.transpose() / (2 * sigma2(k) * sigma2(k));
      } else if (sigma2(k) > 0) {
        double i_mm, i_ms, i_ss;
        internal::CensoredInformation(z(k), d.cens(k), &i_mm, &i_ms, &i_ss);
        const Eigen::VectorXd gm_k = jy.row(k).transpose();
        const Eigen::VectorXd gsd = gs / (2 * std::sqrt(sigma2(k)));
        ev.information += (i_mm * gm_k * gm_k.transpose() + i_ms * (gm_k * gsd.transpose() + gsd * gm_k.transpose()) +
                           i_ss * gsd * gsd.transpose()) /
                          sigma2(k);
      }
    }
  }
  ev.information.diagonal() += prior_hess;
  return ev;
}

Eigen::VectorXd Objective::ScaledResiduals(const Eigen::VectorXd& values, const Eigen::VectorXd& predictions) const {
  const Impl& d = *impl_;
  const Eigen::VectorXd r = d.y - predictions;
  if (d.options.error_model == ErrorModel::kLeastSquares) return (d.w.array().sqrt() * r.array()).matrix();
  const double a = d.sigma_add >= 0 ? values(d.sigma_add) : 0.0;
  const double b = d.sigma_prop >= 0 ? values(d.sigma_prop) : 0.0;
  Eigen::VectorXd out(r.size());
  for (Eigen::Index k = 0; k < r.size(); ++k) {
    if (d.cens(k) != 0) {
      out(k) = std::numeric_limits<double>::quiet_NaN();
    } else if (d.log_scale) {
      out(k) = (std::log(d.y(k)) - std::log(predictions(k))) / a;
    } else {
      out(k) = r(k) / std::sqrt(a * a + b * b * predictions(k) * predictions(k));
    }
  }
  return out;
}

void Objective::CheckValues(const Eigen::VectorXd& values) const {
  internal::PrepareSubject(*impl_->model, impl_->layout, *impl_->data, impl_->subject, values.head(impl_->L()), true);
}

std::vector<double> Objective::PredictAt(const Eigen::VectorXd& values, const std::vector<double>& times,
                                         int output) const {
  const Impl& d = *impl_;
  // This subject alone (not a copy of the whole dataset), with output records at `times`.
  Dataset one;
  one.source = d.data->source;
  one.columns = d.data->columns;
  one.extra_columns = d.data->extra_columns;
  one.subjects = {d.data->subjects[d.subject]};
  one = AddOutputTimes(one, times);
  ParameterValues named;
  for (int i = 0; i < d.L(); ++i) {
    if (std::isfinite(values(i))) named[d.names[i]] = values(i);
  }
  SimulationOptions opts;
  opts.track_auc = false;
  opts.propagator = d.propagator;
  opts.ode = d.options.ode;
  const SubjectSimulation sim = SimulateSubject(*d.model, one, 0, named, opts);
  std::vector<double> out;
  if (!sim.ok) return std::vector<double>(times.size(), std::numeric_limits<double>::quiet_NaN());
  for (const SimulatedRecord& row : sim.rows) {
    // A reset that sets TIME back gives each later period the times again: the curve is the first period's.
    if (out.size() == times.size()) break;
    if (one.subjects[0].records[row.record].line != -1) continue;
    out.push_back(output > 1 && output <= row.outputs.size() ? row.outputs(output - 1) : row.cp);
  }
  return out;
}

}  // namespace pk
