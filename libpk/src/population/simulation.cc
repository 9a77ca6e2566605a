// Simulation from a population model (pk/population_simulation.h): η from N(0, Ω), ε from the
// residual-error model, on each subject's design.
#include "pk/population_simulation.h"

#include <algorithm>
#include <cmath>
#include <exception>
#include <limits>
#include <string>

#include <Eigen/Cholesky>

#include "pk/error.h"
#include "pk/output.h"
#include "pk/residual_error.h"
#include "population/conditional.h"
#include "ordered_parallel.h"
#include "population/problem_impl.h"
#include "population/simulator.h"
#include "simulation/normal_stream.h"

namespace pk {
namespace internal {
namespace {

// The point the subjects' predictions are evaluated at (Ω⁻¹ is not used: l is not formed).
PopulationPoint SimulationPoint(const PopulationProblem& problem, const PopulationParameters& p) {
  CheckSizes(problem, p);
  for (Eigen::Index k = 0; k < p.sigma.size(); ++k) {
    if (!(p.sigma(k) >= 0) || !std::isfinite(p.sigma(k))) {
      throw InputError(problem.sigma_names()[static_cast<size_t>(k)] + " must be a finite σ ≥ 0, not " +
                       FormatNumber(p.sigma(k)));
    }
  }
  PopulationPoint point;
  point.theta = p.theta;
  point.sigma = p.sigma;
  point.error = problem.impl().options.error_model.get();
  return point;
}

// ŷ at η, or false with `why`.
bool Predict(const SubjectModel& s, const PopulationPoint& point, const Eigen::VectorXd& eta, Eigen::VectorXd* yhat,
             std::string* why) {
  try {
    const Eigen::VectorXd phi = IndividualValues(s, point, eta);
    if (!s.objective->Sensitivities(phi, s.eta_free, yhat, nullptr, why)) return false;
  } catch (const std::exception& e) {
    *why = e.what();
    return false;
  }
  if (!yhat->allFinite()) {
    *why = "a prediction is not finite";
    return false;
  }
  return true;
}

// T(ŷ) + √V ε on the error model's scale, back to y.
bool AddResidualError(const SubjectModel& s, const PopulationPoint& point, NormalStream* epsilon, SimulatedSubject* out,
                      std::string* why) {
  std::vector<double> dsigma(static_cast<size_t>(std::max<Eigen::Index>(point.sigma.size(), 1)));
  for (Eigen::Index j = 0; j < out->ipred.size(); ++j) {
    const double e = epsilon->Next(), f = out->ipred(j);
    double v = 0, dv = 0;
    OutputVariance(*point.error, s.outputs(j), f, point.sigma.data(), &v, &dv, dsigma.data());
    const bool log = s.logs.size() == out->ipred.size() && s.logs(j);
    if (!(v >= 0) || !std::isfinite(v) || (log && !(f > 0))) {
      *why = "sample " + std::to_string(j + 1) + ": the prediction " + FormatNumber(f) +
             (log ? " is not positive, and the exponential error takes its logarithm" : " gives no residual variance");
      return false;
    }
    out->dv(j) = log ? std::exp(std::log(f) + std::sqrt(v) * e) : f + std::sqrt(v) * e;
  }
  return true;
}

SimulatedSubject SimulateSubject(const SubjectModel& s, const PopulationPoint& point, const Eigen::MatrixXd& factor,
                                 const PopulationSimulationOptions& options, int replicate, int subject) {
  SimulatedSubject out;
  NormalStream eta_stream(options.seed, replicate, subject, kEtaStream);
  Eigen::VectorXd z(factor.cols());
  for (Eigen::Index k = 0; k < z.size(); ++k) z(k) = eta_stream.Next();
  out.eta = factor * z;
  std::string why;
  if (!Predict(s, point, out.eta, &out.ipred, &why)) {
    out.ok = false;
    out.message = why;
    return out;
  }
  out.dv = out.ipred;
  if (!options.residual_error) return out;
  NormalStream epsilon(options.seed, replicate, subject, kEpsilonStream);
  if (!AddResidualError(s, point, &epsilon, &out, &why)) {
    out.ok = false;
    out.message = why;
  }
  return out;
}

}  // namespace

Eigen::MatrixXd OmegaFactor(const Eigen::MatrixXd& omega) {
  const double scale = std::max(omega.diagonal().cwiseAbs().maxCoeff(), 1e-300);
  if ((omega - omega.transpose()).cwiseAbs().maxCoeff() > 1e-12 * scale) {
    throw InputError("Ω is not symmetric");
  }
  Eigen::LLT<Eigen::MatrixXd> llt(omega);
  if (llt.info() == Eigen::Success) return llt.matrixL();
  Eigen::LDLT<Eigen::MatrixXd> ldlt(omega);
  const Eigen::VectorXd d = ldlt.vectorD();
  if (ldlt.info() != Eigen::Success || (d.array() < -1e-12 * scale).any()) {
    throw InputError("Ω is not positive semi-definite");
  }
  Eigen::MatrixXd l = ldlt.matrixL();
  l = l * d.cwiseMax(0).cwiseSqrt().asDiagonal();
  return ldlt.transpositionsP().transpose() * l;
}

}  // namespace internal

bool PopulationSimulationOptions::IsValid(std::string* error) const {
  if (replicates < 1) {
    *error = "replicates must be at least 1, not " + std::to_string(replicates);
    return false;
  }
  if (threads < 1) {
    *error = "threads must be at least 1, not " + std::to_string(threads);
    return false;
  }
  return true;
}

SimulationDesign MakeSimulationDesign(const PopulationProblem& problem, const PopulationParameters& parameters,
                                      const std::string& stratify) {
  const internal::PopulationPoint point = internal::SimulationPoint(problem, parameters);
  const auto& d = problem.impl();
  SimulationDesign design;
  const int column = stratify.empty() ? -1 : d.data->ExtraColumn(stratify);
  if (!stratify.empty() && column < 0) {
    std::string columns;
    for (const std::string& c : d.data->extra_columns) columns += (columns.empty() ? "" : ", ") + c;
    throw InputError("stratify by '" + stratify + "': " + d.data->source + " has no such column" +
                     (columns.empty() ? "" : " (its covariate columns: " + columns + ")"));
  }
  if (column >= 0) design.stratify = d.data->extra_columns[static_cast<size_t>(column)];
  const Eigen::VectorXd zero = Eigen::VectorXd::Zero(parameters.omega.rows());
  for (size_t i = 0; i < d.subjects.size(); ++i) {
    const internal::SubjectModel& s = d.subjects[i];
    SimulationDesign::Subject out;
    out.id = d.data->subjects[i].id;
    out.subject = static_cast<int>(i);
    out.time = s.objective->sample_times();
    out.dvid = s.objective->sample_outputs();
    out.dv = s.objective->observations();
    if (column >= 0) {
      const Subject& data_subject = d.data->subjects[i];
      for (int record : s.objective->sample_records()) {
        out.stratum.push_back(data_subject.records[static_cast<size_t>(record)].extra[static_cast<size_t>(column)]);
      }
    }
    const Eigen::Index n = out.dv.size();
    out.censored.assign(static_cast<size_t>(n), 0);
    for (Eigen::Index j = 0; j < n && s.censoring.size() == n; ++j) out.censored[static_cast<size_t>(j)] = s.censoring(j);
    std::string why;
    if (!internal::Predict(s, point, zero, &out.pred, &why)) {
      out.pred = Eigen::VectorXd::Constant(n, std::numeric_limits<double>::quiet_NaN());
    }
    design.subjects.push_back(std::move(out));
  }
  return design;
}

namespace internal {

PopulationSimulator::PopulationSimulator(const PopulationProblem& problem, const PopulationParameters& parameters,
                                         const PopulationSimulationOptions& options)
    : subjects_(problem.impl().subjects), point_(SimulationPoint(problem, parameters)),
      factor_(OmegaFactor(parameters.omega)), options_(options) {
  std::string why;
  if (!options.IsValid(&why)) throw InputError("population simulation: " + why);
}

SimulatedSubject PopulationSimulator::Subject(int replicate, int subject) const {
  return SimulateSubject(subjects_[static_cast<size_t>(subject)], point_, factor_, options_, replicate, subject);
}

SimulatedReplicate PopulationSimulator::Replicate(int r, int threads) const {
  const int n = num_subjects();
  SimulatedReplicate replicate;
  replicate.replicate = r;
  replicate.subjects.resize(static_cast<size_t>(n));
  ParallelFor(n, threads, [&](int i) { replicate.subjects[static_cast<size_t>(i)] = Subject(r, i); });
  for (const SimulatedSubject& s : replicate.subjects) replicate.failed += s.ok ? 0 : 1;
  return replicate;
}

}  // namespace internal

SimulatedReplicate SimulateReplicate(const PopulationProblem& problem, const PopulationParameters& parameters,
                                     const PopulationSimulationOptions& options, int replicate) {
  return internal::PopulationSimulator(problem, parameters, options).Replicate(replicate, options.threads);
}

void SimulatePopulation(const PopulationProblem& problem, const PopulationParameters& parameters,
                        const PopulationSimulationOptions& options,
                        const std::function<void(const SimulatedReplicate&)>& consume) {
  const internal::PopulationSimulator simulator(problem, parameters, options);
  const auto simulate = [&](int r, int threads) { return simulator.Replicate(r, threads); };
  // Whole replicates on the threads when there are enough of them (a replicate of a small design
  // takes less than starting a thread), delivered in order, a few held at once; else the subjects.
  if (options.replicates >= 2 * options.threads) {
    internal::OrderedParallel<SimulatedReplicate>(
        options.replicates, options.threads, 4 * options.threads, [&](int r) { return simulate(r, 1); },
        [&](int, SimulatedReplicate&& r) { consume(r); });
    return;
  }
  for (int r = 0; r < options.replicates; ++r) consume(simulate(r, options.threads));
}

}  // namespace pk
