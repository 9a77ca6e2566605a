// A FitSubjectsRequest from what a user gives: the parameters by name, the optimiser's default,
// subjects by ID, and the checks that run before any fit.
#include <algorithm>
#include <cmath>
#include <map>

#include "estimation/minimizer.h"
#include "events.h"
#include "internal_text.h"
#include "pk/error.h"
#include "pk/fit_subjects.h"
#include "pk/model_file.h"
#include "pk/ode_model.h"
#include "pk/output.h"
#include "pk/parameters.h"

namespace pk {
namespace {

// Every name of `settings` must be one of the objective's parameters.
// A modifier the model computes in $PK cannot be set.
void CheckNames(const Objective& probe, const ParameterSettings& settings) {
  const ParameterLayout layout(probe.model());
  for (const ParameterValues* group : {&settings.initial, &settings.fixed, &settings.lower, &settings.upper}) {
    for (const auto& kv : *group) {
      if (probe.ParameterIndex(kv.first) < 0) {
        throw InputError(probe.model().UnknownParameter(kv.first, probe.parameter_names()));
      }
      layout.CheckNotComputed(kv.first, "a value, bound or --fix given for it");
    }
  }
}

// Settings that cannot make a fit: bounds the wrong way round, a start outside its bounds or not
// positive on the log scale, a parameter that must be positive given as zero or below.
void CheckSpecs(const FitSubjectsRequest& request, const std::vector<ParameterSpec>& specs) {
  const Model& model = *request.model;
  for (const ParameterSpec& s : specs) {
    const int i = model.ParameterIndex(s.name);
    const bool positive = i >= 0 && model.must_be_positive(i);
    const std::string value = FormatNumber(s.initial);
    if (positive && !std::isnan(s.initial) && s.initial <= 0) {
      throw InputError(s.name + " of " + model.name() + " must be positive, not " + value);
    }
    if (s.fixed) continue;
    if (!(s.lower < s.upper)) {
      throw InputError(s.name + ": the lower bound " + FormatNumber(s.lower) + " is not below the upper bound " +
                       FormatNumber(s.upper));
    }
    if (!std::isnan(s.initial) && !(s.initial > s.lower && s.initial < s.upper)) {
      throw InputError("the initial value of " + s.name + " (" + value + ") must lie strictly within its bounds (" +
                       FormatNumber(s.lower) + ", " + FormatNumber(s.upper) + ")");
    }
    if (request.fit.log_scale && !std::isnan(s.initial) && !(s.initial > 0)) {
      throw InputError(s.name + " is estimated on the log scale, so its initial value must be positive, not " + value +
                       " (--linear-scale estimates it on its own scale)");
    }
  }
}

bool HasContinuousRecords(const Dataset& data) {
  const int cont_col = data.ExtraColumn("CONT");
  for (const Subject& s : data.subjects) {
    for (const Record& r : s.records) {
      if (cont_col >= 0 && r.extra[cont_col] == 1) return true;
    }
  }
  return false;
}

}  // namespace

std::vector<ParameterSpec> MakeParameterSpecs(const FitSubjectsRequest& request, const ParameterSettings& settings) {
  internal::CheckColumns(*request.model, *request.data, true);
  const Objective probe(request.model, request.data, request.subjects.empty() ? 0 : request.subjects[0],
                        request.objective, request.priors);
  CheckNames(probe, settings);
  std::map<std::string, ParameterSpec> specs;
  std::vector<std::string> order;
  auto add = [&](const std::string& name) {
    if (!specs.count(name)) {
      ParameterSpec s;
      s.name = name;
      s.initial = NAN;
      specs[name] = s;
      order.push_back(name);
    }
    return &specs[name];
  };
  const Model& model = *request.model;
  const ModelDeclarations& declared = model.declarations();
  for (int i = 0; i < model.num_parameters(); ++i) {
    const std::string& name = probe.parameter_names()[i];
    if (request.data->ExtraColumn(name) >= 0 || model.is_covariate(i)) continue;  // the data supply it
    ParameterSpec* s = add(name);
    if (!declared.parameters.empty()) {  // a model file's bounds
      s->lower = declared.parameters[static_cast<size_t>(i)].lower;
      s->upper = declared.parameters[static_cast<size_t>(i)].upper;
    }
  }
  for (const DeclaredParameter& m : declared.modifiers) {
    ParameterSpec* s = add(m.name);
    s->initial = m.initial;
    s->lower = m.lower;
    s->upper = m.upper;
  }
  const std::vector<int> sigmas = probe.sigma_indices();
  // A model file's initial σ, when its error model is the one in use (NaN: the data's start).
  const std::vector<double> declared_sigma = DeclaredSigmas(model, *request.objective.error_model);
  for (size_t j = 0; j < sigmas.size(); ++j) {
    ParameterSpec* s = add(probe.parameter_names()[sigmas[j]]);
    if (j < declared_sigma.size() && !std::isnan(declared_sigma[j])) s->initial = declared_sigma[j];
  }
  for (const auto& kv : settings.initial) add(internal::ToUpper(kv.first))->initial = kv.second;
  for (const auto& kv : settings.fixed) {
    ParameterSpec* s = add(internal::ToUpper(kv.first));
    s->initial = kv.second;
    s->fixed = true;
  }
  for (const auto& kv : settings.lower) add(internal::ToUpper(kv.first))->lower = kv.second;
  for (const auto& kv : settings.upper) add(internal::ToUpper(kv.first))->upper = kv.second;
  std::vector<ParameterSpec> out;
  for (const std::string& name : order) out.push_back(specs[name]);
  CheckSpecs(request, out);
  return out;
}

std::string ChooseOptimizer(const FitSubjectsRequest& request, const std::string& requested) {
  const bool likelihood = request.objective.error_model->is_likelihood();
  std::string optimizer = requested.empty() ? (likelihood ? "newton" : "lm") : requested;
  std::string why;
  const auto minimizer = internal::MakeMinimizer(optimizer, &why);
  if (!minimizer) return optimizer;  // FitOptions::IsValid says why
  if (minimizer->needs_residuals() && likelihood) {
    throw InputError(optimizer + " minimises a sum of squares; with maximum likelihood use bfgs, newton or nlopt:NAME");
  }
  // Continuous records (CONT=1) give a loss without residuals or a Jacobian.
  if (HasContinuousRecords(*request.data) && minimizer->needs_jacobian()) {
    if (!requested.empty()) {
      throw InputError(optimizer + " needs the residual Jacobian, which continuous records (CONT=1) do not give: use "
                       "bfgs or nlopt:NAME");
    }
    optimizer = "bfgs";
  }
  return optimizer;
}

std::vector<int> SubjectIndices(const Dataset& data, const std::vector<double>& ids) {
  std::vector<int> out;
  for (double id : ids) {
    bool found = false;
    for (int i = 0; i < static_cast<int>(data.subjects.size()); ++i) {
      if (data.subjects[i].id == id) {
        out.push_back(i);
        found = true;
      }
    }
    if (!found) throw InputError("no ID " + FormatNumber(id) + " in " + data.source);
  }
  return out;
}

std::vector<int> SelectedSubjects(const FitSubjectsRequest& request) {
  std::vector<int> all = request.subjects;
  if (all.empty()) {
    for (int i = 0; i < static_cast<int>(request.data->subjects.size()); ++i) all.push_back(i);
  }
  return all;
}

std::vector<std::string> CheckSubjects(const FitSubjectsRequest& request) {
  const std::vector<int> all = SelectedSubjects(request);
  for (int i : all) {
    const Objective objective(request.model, request.data, i, request.objective, request.priors);
    // The doses must find the modifiers they need (R1 for RATE=-1, ...) at the starting values, as pksim
    // requires of its values: missing ones are the request's error, not one subject's.
    Eigen::VectorXd values = objective.DefaultValues();
    for (const ParameterSpec& s : request.parameters) {
      const int k = objective.ParameterIndex(s.name);
      if (k >= 0 && !std::isnan(s.initial)) values(k) = s.initial;
    }
    try {
      objective.CheckValues(values);
    } catch (const internal::ParameterValueError&) {
      // An impossible value in this subject's own data: it fails alone when it is fitted.
    }
  }
  std::vector<std::string> notes;
  for (const auto& repeated : request.data->repeated_ids) {
    notes.push_back("ID " + FormatNumber(repeated.first) + " comes back at " + request.data->source + ":" +
                    std::to_string(repeated.second) + " after other IDs: as in NONMEM it is another subject, " +
                    "whose results are marked as a further occurrence of the ID");
  }
  // A nonlinear model's observations measure the output their DVID names, whatever their CMT.
  if (dynamic_cast<const OdeModel*>(request.model.get()) != nullptr) return notes;
  const Model& model = *request.model;
  // So does a linear model file's, when it names outputs and the observation has a DVID.
  const int dvid = model.num_outputs() > 0 ? request.data->ExtraColumn("DVID") : -1;
  std::map<int, int> elsewhere;
  for (int i : all) {
    for (const Record& r : request.data->subjects[static_cast<size_t>(i)].records) {
      if (dvid >= 0 && !std::isnan(r.extra[static_cast<size_t>(dvid)])) continue;
      if (r.IsSample() && r.cmt > 0 && r.cmt != model.central_compartment()) ++elsewhere[r.cmt];
    }
  }
  for (const auto& kv : elsewhere) {
    notes.push_back(std::to_string(kv.second) + " observation" + (kv.second > 1 ? "s" : "") + " with CMT " +
                    std::to_string(kv.first) + " measure " + model.compartment_names()[static_cast<size_t>(kv.first - 1)] +
                    ", not " + model.compartment_names()[static_cast<size_t>(model.central_compartment() - 1)] +
                    " (CMT " + std::to_string(model.central_compartment()) + ") of " + model.name());
  }
  return notes;
}

std::vector<SubjectEvaluation> EvaluateSubjects(const FitSubjectsRequest& request) {
  internal::CheckColumns(*request.model, *request.data, true);
  std::vector<SubjectEvaluation> out;
  for (int i : SelectedSubjects(request)) {
    const Objective objective(request.model, request.data, i, request.objective, request.priors);
    SubjectEvaluation e;
    e.id = objective.subject_id();
    Eigen::VectorXd values = objective.DefaultValues();
    std::vector<int> free;
    for (const ParameterSpec& s : request.parameters) {
      const int k = objective.ParameterIndex(s.name);
      if (k < 0) {
        throw InputError(objective.model().UnknownParameter(s.name, objective.parameter_names()));
      }
      if (!std::isnan(s.initial)) values(k) = s.initial;
      free.push_back(k);
      e.names.push_back(objective.parameter_names()[k]);
    }
    objective.CheckValues(values);
    const Objective::Evaluation ev = objective.Evaluate(values, free, Objective::Need::kGradient);
    e.ok = ev.ok;
    e.message = ev.message;
    e.values = values(free);
    e.value = ev.value;
    e.gradient = ev.gradient;
    out.push_back(std::move(e));
  }
  return out;
}

}  // namespace pk
