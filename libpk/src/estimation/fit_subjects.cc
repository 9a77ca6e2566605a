#include "pk/fit_subjects.h"

#include "events.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <mutex>
#include <thread>

#include "censoring.h"
#include "events.h"
#include "pk/conversion.h"
#include "pk/error.h"
#include "pk/linear_model.h"

namespace pk {
namespace {

// The covariance of the objective's first k parameters from a fit's (over the
// estimated ones; a fixed parameter has zero variance), or empty without one.
Eigen::MatrixXd LeadingCovariance(const Objective& objective, const FitSummary& summary, int k) {
  if (summary.covariance.size() == 0) return Eigen::MatrixXd();
  Eigen::MatrixXd cov = Eigen::MatrixXd::Zero(k, k);
  const auto& names = summary.estimated;
  for (size_t i = 0; i < names.size(); ++i) {
    for (size_t j = 0; j < names.size(); ++j) {
      const int a = objective.ParameterIndex(names[i]), b = objective.ParameterIndex(names[j]);
      if (a < k && b < k) cov(a, b) = summary.covariance(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j));
    }
  }
  return cov;
}

// With an error model per output, the σ of an output this subject has no samples of cannot be
// estimated (zero gradient, zero information): held at its start, as a fixed parameter.
void HoldAbsentOutputSigmas(const Objective& objective, std::vector<ParameterSpec>* specs) {
  const ResidualErrorModel& error = objective.error_model();
  if (error.num_outputs() == 0) return;
  const std::vector<int> outputs = objective.sample_outputs(), sigma = objective.sigma_indices();
  const Eigen::VectorXd defaults = objective.DefaultValues();
  for (int k = 1; k <= error.num_outputs(); ++k) {
    if (std::find(outputs.begin(), outputs.end(), k) != outputs.end()) continue;
    int first = 0;
    const ResidualErrorModel& e = error.ForOutput(k, &first);
    for (int j = 0; j < e.num_sigma(); ++j) {
      const int index = sigma[static_cast<size_t>(first + j)];
      for (ParameterSpec& spec : *specs) {
        if (objective.ParameterIndex(spec.name) != index || spec.fixed) continue;
        spec.fixed = true;
        if (std::isnan(spec.initial)) spec.initial = defaults(index);
      }
    }
  }
}

// The specs with their starting values for this subject: given, from the data, or from an
// earlier fit of it; out->initial_method says where they came from.
std::vector<ParameterSpec> StartingValues(const FitSubjectsRequest& req, const Objective& objective, int subject,
                                          SubjectFit* out) {
  std::vector<ParameterSpec> specs = req.parameters;
  out->initial_method = "catalogue defaults";
  if (req.initial_from_data) {
    const InitialEstimate est = EstimateInitialValues(*req.model, *req.data, subject);
    if (est.ok) {
      out->initial_method = "data (" + est.method + ")";
      for (ParameterSpec& spec : specs) {
        auto it = est.values.find(spec.name);
        if (std::isnan(spec.initial) && it != est.values.end()) spec.initial = it->second;
      }
    } else {
      out->initial_method = "catalogue defaults (from the data: " + est.message + ")";
    }
  }
  for (const auto& entry : req.initial_by_subject) {
    if (entry.first != out->id) continue;
    int taken = 0, estimated = 0;
    for (ParameterSpec& spec : specs) {
      if (spec.fixed) continue;
      ++estimated;
      for (const auto& kv : entry.second) {
        if (objective.ParameterIndex(kv.first) == objective.ParameterIndex(spec.name)) {
          spec.initial = kv.second;
          ++taken;
        }
      }
    }
    if (taken == estimated) {
      out->initial_method = "the values given for this subject";
    } else if (taken > 0) {
      out->initial_method = "the values given for this subject (" + std::to_string(taken) + " of " +
                            std::to_string(estimated) + "); the others from " + out->initial_method;
    }
  }
  HoldAbsentOutputSigmas(objective, &specs);
  const Eigen::VectorXd defaults = objective.DefaultValues();
  for (const ParameterSpec& spec : specs) {
    if (!spec.fixed) {
      out->initial[spec.name] = std::isnan(spec.initial) ? defaults(objective.ParameterIndex(spec.name)) : spec.initial;
    }
  }
  return specs;
}

// Linear models: exponents and half-lives of the fit, or a tf<n> model's compartmental readings.
void Derived(const FitSubjectsRequest& req, const Objective& objective, SubjectFit* out) {
  const auto* linear = dynamic_cast<const LinearModel*>(req.model.get());
  if (linear != nullptr && linear->transfer_function_order() > 0) {
    // The coefficients a₁..aₙ, b₁..bₙ and their covariance.
    const int n2 = 2 * linear->transfer_function_order();
    out->derived = ConvertTransferFunction(out->summary.values.head(n2), LeadingCovariance(objective, out->summary, n2));
  } else if (linear != nullptr) {
    // Exponents and half-lives of the fitted compartment model, SEs from the model parameters' covariance.
    const int m = req.model->num_parameters();
    out->derived = {ModelExponents(*req.model, out->summary.values.head(m), LeadingCovariance(objective, out->summary, m))};
  }
}

// Predictions and scaled residuals at the estimate.
void Residuals(const Objective& objective, SubjectFit* out) {
  const Objective::Evaluation ev = objective.Evaluate(out->summary.values, {}, Objective::Need::kValue);
  if (!ev.ok) return;
  out->ipred = ev.predictions;
  out->iwres = objective.ScaledResiduals(out->summary.values, out->ipred);
  if (!objective.error_model().is_likelihood()) {
    // Least squares leaves σ to the residuals: σ̂² = 2V/(N − p).
    const Eigen::VectorXd r = out->dv - out->ipred;
    const int n = objective.num_samples();
    const int p = static_cast<int>(out->summary.estimated.size());
    const double v = 0.5 * (objective.weights().array() * r.array().square()).sum();
    out->iwres /= n > p ? std::sqrt(2 * v / (n - p)) : NAN;
  }
}

// The fitted curve from the first record to a little past the last sample, per output.
void Curves(const FitSubjectsRequest& req, const Objective& objective, int subject, SubjectFit* out) {
  const auto& records = req.data->subjects[subject].records;
  double t0 = records.front().time, t1 = t0;
  for (const Record& rec : records) t1 = std::max(t1, rec.time);
  if (t1 <= t0) t1 = t0 + 1;
  const int m = std::max(2, req.curve_points);
  for (int k = 0; k < m; ++k) out->curve_times.push_back(t0 + (t1 - t0) * k / (m - 1));
  out->curve = objective.PredictAt(out->summary.values, out->curve_times);
  const Model& model = *req.model;
  if (model.num_outputs() <= 1) return;
  out->sample_output = objective.sample_outputs();
  out->output_names = model.output_names();
  out->output_curves.push_back(out->curve);
  for (int k = 2; k <= model.num_outputs(); ++k) {
    out->output_curves.push_back(objective.PredictAt(out->summary.values, out->curve_times, k));
  }
}

void FitOne(const FitSubjectsRequest& req, int subject, SubjectFit* out) {
  out->subject = subject;
  out->id = req.data->subjects[subject].id;
  out->occurrence = req.data->subjects[subject].occurrence;
  try {
    const Objective objective(req.model, req.data, subject, req.objective, req.priors);
    out->times = objective.sample_times();
    out->sample_records = objective.sample_records();
    out->dv = objective.observations();
    out->censoring = objective.censoring();
    if (objective.num_samples() == 0) {
      out->error = "no samples (every observation has MDV=1 or no DV)";
      return;
    }
    const std::vector<ParameterSpec> specs = StartingValues(req, objective, subject, out);
    out->summary = Fit(objective, specs, req.fit);
    out->ok = true;
    Derived(req, objective, out);
    Residuals(objective, out);
    Curves(req, objective, subject, out);
  } catch (const InputError& e) {
    out->ok = false;
    out->error = e.what();
  } catch (const std::exception& e) {
    out->ok = false;
    out->error = std::string("unexpected error: ") + e.what();
  }
}

}  // namespace

std::vector<SubjectFit> FitSubjects(const FitSubjectsRequest& request, const std::function<void(int, int)>& progress) {
  std::string why;
  if (!request.objective.IsValid(&why) || !request.fit.IsValid(&why) ||
      !IsCompatible(request.fit, request.objective, &why)) {
    throw InputError(why);
  }
  internal::CheckColumns(*request.model, *request.data, true);
  std::vector<int> subjects = request.subjects;
  if (subjects.empty()) {
    for (int i = 0; i < static_cast<int>(request.data->subjects.size()); ++i) subjects.push_back(i);
  }
  // A CENS value the request cannot take (least squares, say) is the request's error, not one subject's.
  const int cens_col = request.data->ExtraColumn("CENS");
  for (int i = 0; cens_col >= 0 && i < static_cast<int>(subjects.size()); ++i) {
    for (const Record& r : request.data->subjects[static_cast<size_t>(subjects[i])].records) {
      if (r.IsSample()) {
        internal::CheckedCensoring(*request.data, r, cens_col, request.objective.error_model->is_likelihood());
      }
    }
  }
  std::vector<SubjectFit> out(subjects.size());
  int jobs = request.jobs > 0 ? request.jobs : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  jobs = std::min<int>(jobs, static_cast<int>(subjects.size()));
  std::atomic<int> next{0};
  std::mutex mutex;
  int done = 0;
  auto worker = [&]() {
    for (int k = next++; k < static_cast<int>(subjects.size()); k = next++) {
      FitOne(request, subjects[k], &out[k]);
      if (progress) {
        std::lock_guard<std::mutex> lock(mutex);
        progress(++done, static_cast<int>(subjects.size()));
      }
    }
  };
  if (jobs <= 1) {
    worker();
  } else {
    std::vector<std::thread> threads;
    for (int j = 0; j < jobs; ++j) threads.emplace_back(worker);
    for (std::thread& t : threads) t.join();
  }
  return out;
}

}  // namespace pk
