// A population problem: the subjects bound to the model, and the objective at fixed parameters.
#include <algorithm>
#include <cmath>

#include "events.h"
#include "internal_text.h"
#include "pk/output.h"
#include "pk/error.h"
#include "pk/initial_estimates.h"
#include "pk/model_file.h"
#include "pk/propagator.h"
#include "population/conditional.h"
#include "population/problem_impl.h"

namespace pk {

const char* ToString(PopulationMethod m) {
  switch (m) {
    case PopulationMethod::kFo: return "fo";
    case PopulationMethod::kFoce: return "foce";
    case PopulationMethod::kFocei: return "focei";
    case PopulationMethod::kLaplace: return "laplace";
  }
  return "?";
}

PopulationMethod ParsePopulationMethod(const std::string& text) {
  const std::string t = internal::ToUpper(text);
  if (t == "FO") return PopulationMethod::kFo;
  if (t == "FOCE") return PopulationMethod::kFoce;
  if (t == "FOCEI") return PopulationMethod::kFocei;
  if (t == "LAPLACE") return PopulationMethod::kLaplace;
  throw InputError("unknown population method '" + text + "': expected fo, foce, focei or laplace");
}

const char* ToString(CovarianceMatrix m) {
  switch (m) {
    case CovarianceMatrix::kSandwich: return "sandwich";
    case CovarianceMatrix::kR: return "r";
    case CovarianceMatrix::kS: return "s";
  }
  return "";
}

const char* Describe(CovarianceMatrix m) {
  switch (m) {
    case CovarianceMatrix::kSandwich: return "sandwich R⁻¹SR⁻¹ (NONMEM's default)";
    case CovarianceMatrix::kR: return "2R⁻¹ (NONMEM's MATRIX=R)";
    case CovarianceMatrix::kS: return "4S⁻¹ (NONMEM's MATRIX=S)";
  }
  return "";
}

CovarianceMatrix ParseCovarianceMatrix(const std::string& text) {
  const std::string t = internal::ToUpper(text);
  if (t == "SANDWICH") return CovarianceMatrix::kSandwich;
  if (t == "R") return CovarianceMatrix::kR;
  if (t == "S") return CovarianceMatrix::kS;
  throw InputError("unknown covariance matrix '" + text + "': expected sandwich (R⁻¹SR⁻¹), r (2R⁻¹) or s (4S⁻¹)");
}

PopulationGradient ParsePopulationGradient(const std::string& text) {
  const std::string t = internal::ToUpper(text);
  if (t == "AUTO") return PopulationGradient::kAuto;
  if (t == "IMPLICIT") return PopulationGradient::kImplicit;
  if (t == "FD") return PopulationGradient::kFiniteDifference;
  throw InputError("unknown outer gradient '" + text + "': expected auto, implicit or fd");
}

namespace {

int IndexOf(const std::vector<std::string>& names, const std::string& name) {
  const std::string u = internal::ToUpper(name);
  for (size_t i = 0; i < names.size(); ++i) {
    if (internal::ToUpper(names[i]) == u) return static_cast<int>(i);
  }
  return -1;
}

// The subject's observations on the error model's scale; a DV the log cannot take names its line.
// The observations on their error model's scale: log DV where it compares log y.
Eigen::VectorXd Observations(const Objective& o, const Dataset& data, int subject,
                             const Eigen::Array<bool, Eigen::Dynamic, 1>& logs) {
  Eigen::VectorXd y = o.observations();
  const std::vector<int> records = o.sample_records();
  for (Eigen::Index j = 0; j < y.size(); ++j) {
    if (!logs(j)) continue;
    if (y(j) > 0) {
      y(j) = std::log(y(j));
      continue;
    }
    const Record& r = data.subjects[static_cast<size_t>(subject)].records[static_cast<size_t>(records[j])];
    throw InputError(data.source, r.line, data.ColumnNumber("DV"),
                     "the exponential error takes log DV, and DV is " + std::to_string(r.dv) +
                         " (give MDV=1 to leave the sample out)");
  }
  return y;
}

bool HasEtas(const Model& model) {
  for (int i = 0; i < model.num_parameters(); ++i) {
    if (model.is_eta(i)) return true;
  }
  return false;
}

// The model's name of a model file's η parameter `e` (pk::RandomEffects::kParameters).
std::string EtaParameter(const PopulationProblem::Impl& d, const std::string& e) {
  const int i = d.model->ParameterIndex(e);
  if (i < 0 || !d.model->is_eta(i)) {
    throw InputError("--eta: '" + e + "' is not an estimable parameter" + (HasEtas(*d.model) ? " or a random effect" : "") +
                     " of " + d.model->name());
  }
  const std::string& name = d.model->parameter_names()[static_cast<size_t>(i)];
  if (d.data->ExtraColumn(name) >= 0) {
    throw InputError(d.data->source, 1, d.data->ColumnNumber(name),
                     "the column " + name + " would hold the random effect " + name + " of " + d.model->name() +
                         " fixed; rename or drop it");
  }
  return name;
}

// Where each η acts: on a θ (log-normal, φ = θ·exp(η)), or as a model file's η parameter
// (φ = η), which follow the θ in the φ list.
struct EtaBindings {
  std::vector<int> phi;                 ///< per η: its φ (index into θ, then `parameters`)
  std::vector<std::string> parameters;  ///< the file's η parameters, in φ order after θ
};

// Binds `etas` and fills d's eta_names and eta_log_normal.
EtaBindings BindEtas(const std::vector<std::string>& etas, PopulationProblem::Impl* d) {
  EtaBindings b;
  for (const std::string& e : etas) {
    int k = IndexOf(d->theta_names, e);
    const bool log_normal = k >= 0;
    const std::string name = log_normal ? d->theta_names[static_cast<size_t>(k)] : EtaParameter(*d, e);
    if (std::find(d->eta_names.begin(), d->eta_names.end(), name) != d->eta_names.end()) {
      throw InputError("--eta: '" + e + "' is given twice");
    }
    if (!log_normal) {
      k = static_cast<int>(d->theta_names.size() + b.parameters.size());
      b.parameters.push_back(name);
    }
    b.phi.push_back(k);
    d->eta_log_normal.push_back(log_normal);
    d->eta_names.push_back(name);
  }
  if (b.phi.empty()) throw InputError("a population model needs at least one parameter with an η");
  return b;
}

}  // namespace

PopulationProblem::PopulationProblem(std::shared_ptr<const Model> model, std::shared_ptr<const Dataset> data,
                                     std::vector<std::string> etas, const ObjectiveOptions& options)
    : impl_(std::make_unique<Impl>()) {
  Impl& d = *impl_;
  d.model = std::move(model);
  d.data = std::move(data);
  d.options = options;
  if (!options.error_model || !options.error_model->is_likelihood()) {
    throw InputError("population estimation needs a residual-error model (additive, proportional, combined or "
                     "exponential), not least squares");
  }
  for (int i = 0; i < d.model->num_parameters(); ++i) {
    if (d.model->is_covariate(i) || d.model->is_eta(i)) continue;
    d.theta_names.push_back(d.model->parameter_names()[static_cast<size_t>(i)]);
    d.theta_model_index.push_back(i);
  }
  const EtaBindings etas_bound = BindEtas(etas, &d);
  d.sigma_names = options.error_model->sigma_names();
  ObjectiveOptions ls = options;  // predictions and their sensitivities only: least squares, forward
  ls.error_model = LeastSquares();
  ls.weighting = Weighting::kUniform;
  ls.gradient = GradientRoute::kForward;
  ls.keep_censored = true;  // M3: the conditional objective forms their likelihood
  const ResidualErrorModel& error = *options.error_model;
  internal::CheckColumns(*d.model, *d.data, true);  // as pkfit: e.g. a column for a modifier the model computes
  const bool ode = IntegratesOde(ResolvePropagator(*d.model, options.propagator));
  for (int i = 0; i < static_cast<int>(d.data->subjects.size()); ++i) {
    internal::SubjectModel s;
    s.objective = std::make_unique<Objective>(d.model, d.data, i, ls);
    if (s.objective->has_continuous_records()) {
      throw InputError(d.data->source, 0, d.data->ColumnNumber("CONT"),
                       "ID " + FormatNumber(d.data->subjects[static_cast<size_t>(i)].id) +
                           " has continuous records (CONT=1), which population estimation does not take: its "
                           "conditional likelihood is over samples; give them CONT=0 or leave them out");
    }
    s.base = s.objective->DefaultValues();
    const std::vector<int> outputs = s.objective->sample_outputs();
    s.outputs = Eigen::Map<const Eigen::VectorXi>(outputs.data(), static_cast<Eigen::Index>(outputs.size()));
    s.logs.resize(s.outputs.size());
    for (Eigen::Index j = 0; j < s.outputs.size(); ++j) s.logs(j) = OutputLogTransformed(error, s.outputs(j));
    s.any_logs = s.logs.any();
    s.y = Observations(*s.objective, *d.data, i, s.logs);
    for (const std::string& name : d.theta_names) s.theta_index.push_back(s.objective->ParameterIndex(name));
    s.phi_index = s.theta_index;
    for (const std::string& name : etas_bound.parameters) s.phi_index.push_back(s.objective->ParameterIndex(name));
    s.eta_phi = etas_bound.phi;
    s.eta_log = d.eta_log_normal;
    for (int k : etas_bound.phi) s.eta_free.push_back(s.phi_index[static_cast<size_t>(k)]);
    if (ode) {
      s.step_tolerance = std::max(1e-10, 100 * options.ode.relative_tolerance);
      s.relative_noise = std::max(1e-10, 10 * options.ode.relative_tolerance);
      s.newton_exact_hessian = true;
    }
    s.censoring = s.objective->censoring();
    d.num_censored += s.objective->num_censored();
    d.num_observations += static_cast<int>(s.y.size());
    d.subjects.push_back(std::move(s));
  }
}

PopulationProblem::~PopulationProblem() = default;
PopulationProblem::PopulationProblem(PopulationProblem&&) noexcept = default;

const std::vector<std::string>& PopulationProblem::theta_names() const { return impl_->theta_names; }
int PopulationProblem::num_censored() const { return impl_->num_censored; }
const std::vector<std::string>& PopulationProblem::eta_names() const { return impl_->eta_names; }
const std::vector<std::string>& PopulationProblem::sigma_names() const { return impl_->sigma_names; }
int PopulationProblem::num_subjects() const { return static_cast<int>(impl_->subjects.size()); }
int PopulationProblem::num_observations() const { return impl_->num_observations; }
const Model& PopulationProblem::model() const { return *impl_->model; }
const Dataset& PopulationProblem::data() const { return *impl_->data; }
const ObjectiveOptions& PopulationProblem::options() const { return impl_->options; }

int PopulationProblem::EtaPosition(const std::string& name) const {
  const std::vector<std::string>& etas = impl_->eta_names;
  for (size_t k = 0; k < etas.size(); ++k) {
    if (etas[k] == name && !impl_->eta_log_normal[k]) return static_cast<int>(k);
  }
  return -1;
}

PopulationStructure PopulationProblem::DeclaredStructure() const {
  const Impl& d = *impl_;
  PopulationStructure s;
  std::vector<int> size(d.eta_names.size(), 1);  // per η: the size of the block it starts, 0 inside one
  std::vector<char> fixed(d.eta_names.size(), 0), same(d.eta_names.size(), 0);
  int previous_end = -1;  // one past the last η of the block declared before, or -1
  for (const OmegaBlockDeclaration& b : d.model->declarations().omega_blocks) {
    std::vector<int> at;
    for (const std::string& e : b.etas) at.push_back(EtaPosition(e));
    const bool all = std::all_of(at.begin(), at.end(), [](int k) { return k >= 0; });
    if (!all && b.etas.size() > 1) {
      throw InputError(d.model->declarations().source, 0, 0,
                       "$OMEGA: the block of " + b.etas.front() + "… needs each of its random effects in the population model");
    }
    for (size_t k = 1; k < at.size(); ++k) {
      if (at[k] != at[0] + static_cast<int>(k)) {
        throw InputError(d.model->declarations().source, 0, 0,
                         "$OMEGA: the random effects of the block of " + b.etas.front() + "… must be consecutive among the η");
      }
    }
    const bool any = std::any_of(at.begin(), at.end(), [](int k) { return k >= 0; });
    if (b.same && any && (!all || previous_end != at[0])) {
      throw InputError(d.model->declarations().source, 0, 0,
                       "$OMEGA: " + b.etas.front() + " ~ SAME needs the block before it in the population model, its "
                       "random effects just before " + b.etas.front() + "'s");
    }
    previous_end = all ? at.back() + 1 : -1;
    if (!all) continue;
    size[static_cast<size_t>(at[0])] = static_cast<int>(at.size());
    for (size_t k = 1; k < at.size(); ++k) size[static_cast<size_t>(at[k])] = 0;
    fixed[static_cast<size_t>(at[0])] = b.fixed;
    same[static_cast<size_t>(at[0])] = b.same;
  }
  for (size_t k = 0; k < size.size(); ++k) {
    if (size[k] == 0) continue;
    s.omega_blocks.push_back(size[k]);
    s.omega_block_fixed.push_back(fixed[k] != 0);
    s.omega_block_same.push_back(same[k] != 0);
  }
  return s;
}

PopulationParameters PopulationProblem::DefaultParameters() const {
  const Impl& d = *impl_;
  PopulationParameters p;
  p.theta.resize(static_cast<Eigen::Index>(d.theta_names.size()));
  std::vector<std::vector<double>> found(d.theta_names.size());  // data-driven values per subject
  if (d.model->initial_structure().kind != InitialStructure::Kind::kNone) {
    for (int i = 0; i < num_subjects(); ++i) {
      const InitialEstimate e = EstimateInitialValues(*d.model, *d.data, i);
      for (size_t k = 0; e.ok && k < d.theta_names.size(); ++k) {
        const auto it = e.values.find(d.theta_names[k]);
        if (it != e.values.end() && std::isfinite(it->second)) found[k].push_back(it->second);
      }
    }
  }
  for (size_t k = 0; k < d.theta_names.size(); ++k) {
    std::vector<double>& v = found[k];
    double value = d.model->default_parameters()(d.theta_model_index[k]);
    if (!v.empty()) {
      std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
      value = v[v.size() / 2];
    }
    p.theta(static_cast<Eigen::Index>(k)) = value;
  }
  const Eigen::Index q = static_cast<Eigen::Index>(d.eta_names.size());
  p.omega = 0.1 * Eigen::MatrixXd::Identity(q, q);
  for (Eigen::Index m = 0; m < q; ++m) {  // a model file's $OMEGA gives its η's variances
    const auto mm = static_cast<size_t>(m);
    if (d.eta_log_normal[mm]) continue;
    const int i = d.model->ParameterIndex(d.eta_names[mm]);
    p.omega(m, m) = d.model->declarations().parameters[static_cast<size_t>(i)].variance;
  }
  for (const OmegaBlockDeclaration& b : d.model->declarations().omega_blocks) {  // and covariances
    for (size_t i = 0; i < b.etas.size(); ++i) {
      for (size_t j = 0; j < i; ++j) {
        const int a = EtaPosition(b.etas[i]), c = EtaPosition(b.etas[j]);
        if (a >= 0 && c >= 0) p.omega(a, c) = p.omega(c, a) = b.omega(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j));
      }
    }
  }
  // The observed values pooled, with their outputs (a censored sample's DV is its limit, not a value).
  Eigen::VectorXd pooled(d.num_observations - d.num_censored);
  Eigen::VectorXi outputs(pooled.size());
  Eigen::Index at = 0;
  for (const auto& s : d.subjects) {
    const Eigen::VectorXd& y = s.objective->observations();
    for (Eigen::Index j = 0; j < y.size(); ++j) {
      if (s.censoring.size() == y.size() && s.censoring(j) != 0) continue;
      outputs(at) = s.outputs(j);
      pooled(at++) = y(j);
    }
  }
  std::vector<double> sigma = DefaultSigmas(*d.options.error_model, pooled, outputs);
  // A model file's $ERROR values, as NONMEM's $SIGMA initial estimates, where it gives them.
  const std::vector<double> declared = DeclaredSigmas(*d.model, *d.options.error_model);
  for (size_t j = 0; j < sigma.size() && j < declared.size(); ++j) {
    if (!std::isnan(declared[j])) sigma[j] = declared[j];
  }
  p.sigma = Eigen::Map<const Eigen::VectorXd>(sigma.data(), static_cast<Eigen::Index>(sigma.size()));
  return p;
}

bool PopulationOptions::IsValid(std::string* error) const {
  if (max_iterations < 0) {
    *error = "max_iterations must be at least 0 (0: evaluate at the initial estimates, NONMEM's MAXEVAL=0)";
  } else if (!(function_tolerance >= 0) || !(parameter_tolerance >= 0)) {
    *error = "tolerances must be non-negative";
  } else if (threads < 1) {
    *error = "threads must be at least 1";
  } else {
    return true;
  }
  return false;
}

namespace internal {

/// Throws pk::InputError when the parameters' sizes do not match the problem.
void CheckSizes(const PopulationProblem& problem, const PopulationParameters& p) {
  const auto q = static_cast<Eigen::Index>(problem.eta_names().size());
  if (p.theta.size() != static_cast<Eigen::Index>(problem.theta_names().size())) {
    throw InputError("expected " + std::to_string(problem.theta_names().size()) + " θ values, got " +
                     std::to_string(p.theta.size()));
  }
  if (p.omega.rows() != q || p.omega.cols() != q) {
    throw InputError("expected Ω of size " + std::to_string(q) + "×" + std::to_string(q));
  }
  if (p.sigma.size() != static_cast<Eigen::Index>(problem.sigma_names().size())) {
    throw InputError("expected " + std::to_string(problem.sigma_names().size()) + " σ values, got " +
                     std::to_string(p.sigma.size()));
  }
}

/// Throws pk::InputError when censored samples meet a method other than Laplace.
void CheckMethod(const PopulationProblem& problem, PopulationMethod method) {
  if (problem.num_censored() > 0 && method != PopulationMethod::kLaplace) {
    throw InputError("the data have " + std::to_string(problem.num_censored()) +
                     " censored samples (CENS): their likelihood (Beal's M3) needs --method laplace, as NONMEM "
                     "requires LAPLACIAN for it; or give them MDV=1 to leave them out (M1)");
  }
}

}  // namespace internal

PopulationEvaluation EvaluatePopulation(const PopulationProblem& problem, const PopulationParameters& parameters,
                                        PopulationMethod method, int threads) {
  internal::CheckSizes(problem, parameters);
  internal::CheckMethod(problem, method);
  const auto& d = problem.impl();
  const internal::PopulationPoint point =
      internal::PopulationPoint::Make(parameters, *d.options.error_model, method);
  const int n = problem.num_subjects();
  std::vector<internal::SubjectMode> modes(static_cast<size_t>(n));
  const Eigen::VectorXd zero = Eigen::VectorXd::Zero(parameters.omega.rows());
  internal::ParallelFor(n, threads, [&](int i) {
    modes[static_cast<size_t>(i)] = internal::SolveSubject(d.subjects[static_cast<size_t>(i)], point, zero);
  });
  PopulationEvaluation out;
  out.ofv = 0;
  for (int i = 0; i < n; ++i) {
    const internal::SubjectMode& m = modes[static_cast<size_t>(i)];
    PopulationSubject s;
    s.id = d.data->subjects[static_cast<size_t>(i)].id;
    s.subject = i;
    s.ok = m.ok;
    s.message = m.message;
    s.eta = m.eta;
    s.ofv = m.ofv;
    s.eta_covariance = internal::EtaCovariance(m);
    internal::DescribeIndividual(d.subjects[static_cast<size_t>(i)], point, m.eta, &s);
    if (!m.ok && out.ok) {
      out.ok = false;
      out.message = "subject " + FormatNumber(s.id) + ": " + m.message;
    }
    out.ofv += m.ofv;
    out.subjects.push_back(std::move(s));
  }
  if (!out.ok) out.ofv = std::numeric_limits<double>::quiet_NaN();
  return out;
}

}  // namespace pk
