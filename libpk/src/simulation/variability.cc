// Simulation of a dataset or regimen with a population's between-subject and residual variability
// (pk/population_simulation.h, SimulateEachWithVariability).
#include <cmath>
#include <set>
#include <string>

#include "pk/error.h"
#include "pk/model_file.h"
#include "pk/output.h"
#include "pk/population_simulation.h"
#include "events.h"
#include "simulation/normal_stream.h"
#include "simulation/stream.h"

namespace pk {
namespace {

// The error model and σ (in its order) of a population, or none without residual error.
struct ResidualError {
  std::shared_ptr<const ResidualErrorModel> model;
  Eigen::VectorXd sigma;
};

ResidualError BindResidualError(const Model& model, const PopulationEstimates& p, bool wanted) {
  ResidualError out;
  if (!wanted) return out;
  if (p.sigma_names.empty()) {
    throw InputError(p.source + ": no σ (SIGMA_ADD, SIGMA_PROP, ...) for the residual error; leave it out to simulate "
                                "without one");
  }
  out.model = PopulationErrorModel(model, p);
  const std::vector<std::string> names = out.model->sigma_names();
  out.sigma.resize(static_cast<Eigen::Index>(names.size()));
  for (size_t k = 0; k < names.size(); ++k) {
    size_t j = 0;
    while (j < p.sigma_names.size() && p.sigma_names[j] != names[k]) ++j;
    if (j == p.sigma_names.size()) {
      throw InputError(p.source + ": the " + out.model->name() + " error model needs " + names[k] + ", which is not there");
    }
    out.sigma(static_cast<Eigen::Index>(k)) = p.sigma(static_cast<Eigen::Index>(j));
  }
  return out;
}

// Subject i's parameters: the overrides, else θ, with its η applied.
ParameterValues Individual(const PopulationEstimates& p, const ParameterValues& overrides, const Eigen::VectorXd& eta) {
  ParameterValues values = p.theta;
  for (const auto& [name, value] : overrides) values[name] = value;
  for (size_t k = 0; k < p.etas.size(); ++k) {
    const double e = eta(static_cast<Eigen::Index>(k));
    const std::string& name = p.etas[k];
    if (!p.eta_log_normal[k]) {
      if (!overrides.count(name)) values[name] = e;  // --param ETA_CL=0 holds it
      continue;
    }
    const auto it = values.find(name);
    if (it == values.end()) throw InputError(p.source + ": OMEGA(" + name + ") without a typical value " + name);
    it->second *= std::exp(e);
  }
  return values;
}

// Each output at each row given its residual error, on the error model's scale: y = ŷ + √V ε, or
// y = ŷ·exp(√V ε) for a log-transformed output (0 where ŷ is 0, as the limit).
void AddResidualError(const ResidualError& error, internal::NormalStream* epsilon, SubjectSimulation* s) {
  const Eigen::Index rows = static_cast<Eigen::Index>(s->rows.size());
  const Eigen::Index outputs = std::max<Eigen::Index>(s->outputs.rows(), 1);
  s->observations.resize(outputs, rows);
  std::vector<double> dsigma(static_cast<size_t>(std::max<Eigen::Index>(error.sigma.size(), 1)));
  for (Eigen::Index i = 0; i < rows; ++i) {
    for (Eigen::Index k = 0; k < outputs; ++k) {
      const double yhat = s->outputs.rows() > 0 ? s->outputs(k, i) : s->rows[static_cast<size_t>(i)].cp;
      const int output = static_cast<int>(k) + 1;
      double v = 0, dv = 0;
      OutputVariance(*error.model, output, yhat, error.sigma.data(), &v, &dv, dsigma.data());
      const double e = epsilon->Next() * std::sqrt(std::max(v, 0.0));
      s->observations(k, i) = OutputLogTransformed(*error.model, output) ? yhat * std::exp(e) : yhat + e;
    }
  }
}

}  // namespace

bool VariabilityOptions::IsValid(std::string* error) const {
  if (replicates < 1) {
    *error = "replicates must be at least 1, not " + std::to_string(replicates);
    return false;
  }
  if (subjects < 0) {
    *error = "subjects must be 0 (the dataset's) or positive, not " + std::to_string(subjects);
    return false;
  }
  return true;
}

std::shared_ptr<const ResidualErrorModel> PopulationErrorModel(const Model& model, const PopulationEstimates& p) {
  const std::set<std::string> names(p.sigma_names.begin(), p.sigma_names.end());
  // The file's $ERROR, unless the run replaced it (pkpop --error): then its σ are not these.
  if (auto declared = DeclaredErrorModel(model)) {
    const std::vector<std::string> needed = declared->sigma_names();
    if (std::set<std::string>(needed.begin(), needed.end()) == names) return declared;
  }
  const std::string kind = names == std::set<std::string>{kSigmaAdd}                ? "additive"
                           : names == std::set<std::string>{kSigmaProp}              ? "proportional"
                           : names == std::set<std::string>{kSigmaAdd, kSigmaProp}   ? "combined"
                           : names == std::set<std::string>{kSigmaLog}               ? "exponential"
                                                                                     : "";
  if (kind.empty()) {
    std::string listed;
    for (const auto& n : p.sigma_names) listed += (listed.empty() ? "" : ", ") + n;
    throw InputError(p.source + ": no error model has the σ " + listed +
                     " (SIGMA_ADD: additive, SIGMA_PROP: proportional, both: combined, SIGMA_LOG: exponential; a "
                     "model file's $ERROR names its own)");
  }
  return MakeResidualError(kind);
}

void SimulateEachWithVariability(const Model& model, const Dataset& data, const PopulationEstimates& population,
                                 const ParameterValues& overrides, const SimulationOptions& options,
                                 const VariabilityOptions& variability, const SimulationSink& sink) {
  std::string why;
  if (!variability.IsValid(&why)) throw InputError("simulation with variability: " + why);
  if (variability.subjects > 0 && data.subjects.size() != 1) {
    throw InputError(data.source + ": a regimen to simulate for " + std::to_string(variability.subjects) +
                     " subjects has one subject, not " + std::to_string(data.subjects.size()));
  }
  internal::CheckColumns(model, data, false);
  // The population, or each replicate's set of the estimates' uncertainty: its θ, Ω's factor and σ.
  const std::vector<PopulationEstimates> one = {population};
  const std::vector<PopulationEstimates>& sets = variability.parameter_sets.empty() ? one : variability.parameter_sets;
  std::vector<Eigen::MatrixXd> factors;
  std::vector<ResidualError> errors;
  for (const PopulationEstimates& p : sets) {
    if (p.omega.rows() != static_cast<Eigen::Index>(p.etas.size()) || p.etas != population.etas) {
      throw InputError(p.source + ": Ω is not over the population's η");
    }
    factors.push_back(internal::OmegaFactor(p.omega));
    errors.push_back(BindResidualError(model, p, variability.residual_error));
  }
  const int per_replicate = variability.subjects > 0 ? variability.subjects : static_cast<int>(data.subjects.size());
  if (static_cast<double>(per_replicate) * variability.replicates > 2e9) {
    throw InputError("simulation with variability: " + std::to_string(variability.replicates) + " replicates of " +
                     std::to_string(per_replicate) + " subjects are too many (at most 2·10⁹ subjects in all)");
  }
  const internal::SubjectSimulator simulator(model, options);
  const auto simulate = [&](int item) {
    const int r = item / per_replicate, i = item % per_replicate;
    const size_t set = static_cast<size_t>(r) % sets.size();
    const Eigen::MatrixXd& factor = factors[set];
    const ResidualError& error = errors[set];
    internal::NormalStream eta_stream(variability.seed, r, i, internal::kEtaStream);
    Eigen::VectorXd z(factor.cols());
    for (Eigen::Index k = 0; k < z.size(); ++k) z(k) = eta_stream.Next();
    const Eigen::VectorXd eta = factor * z;
    const int subject = variability.subjects > 0 ? 0 : i;
    SubjectSimulation s = simulator(data, subject, Individual(sets[set], overrides, eta));
    if (variability.subjects > 0) s.id = i + 1;
    s.replicate = r;
    s.eta = eta;
    if (s.ok && error.model) {
      internal::NormalStream epsilon(variability.seed, r, i, internal::kEpsilonStream);
      AddResidualError(error, &epsilon, &s);
    }
    return s;
  };
  internal::StreamSimulations(per_replicate * variability.replicates, options, simulate, sink);
}

}  // namespace pk
