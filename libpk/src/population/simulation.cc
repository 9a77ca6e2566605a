// Simulation from a population model (pk/population_simulation.h): η from N(0, Ω), ε from the
// residual-error model, on each subject's design.
#include "pk/population_simulation.h"

#include <cmath>
#include <exception>
#include <string>

#include <Eigen/Cholesky>

#include "pk/error.h"
#include "pk/output.h"
#include "pk/residual_error.h"
#include "population/conditional.h"
#include "population/problem_impl.h"

namespace pk {
namespace internal {
namespace {

constexpr double kPi = 3.14159265358979323846;

// SplitMix64 (Steele, Lea & Flood, OOPSLA 2014): one step of its sequence from state z.
std::uint64_t SplitMix(std::uint64_t* z) {
  std::uint64_t x = (*z += 0x9e3779b97f4a7c15ULL);
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

// Standard normal numbers from a stream of its own: xoshiro256** (Blackman & Vigna 2018), seeded
// by SplitMix64 from (seed, replicate, subject, kind), through Box–Muller. Both are fixed
// arithmetic on 64-bit integers, so a seed gives the same numbers on every platform (up to the
// last bits of log, sin and cos); its state is four words, so a stream costs nothing to start.
class NormalStream {
 public:
  NormalStream(std::uint64_t seed, int replicate, int subject, int kind) {
    std::uint64_t z = seed;
    z = SplitMix(&z) ^ static_cast<std::uint64_t>(replicate);
    z = SplitMix(&z) ^ (static_cast<std::uint64_t>(subject) << 1 | static_cast<std::uint64_t>(kind));
    for (std::uint64_t& word : s_) word = SplitMix(&z);
  }
  double Next() {
    if (has_spare_) {
      has_spare_ = false;
      return spare_;
    }
    const double r = std::sqrt(-2 * std::log(Uniform())), angle = 2 * kPi * Uniform();
    spare_ = r * std::sin(angle);
    has_spare_ = true;
    return r * std::cos(angle);
  }

 private:
  static std::uint64_t Rotate(std::uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
  std::uint64_t Bits() {
    const std::uint64_t result = Rotate(s_[1] * 5, 7) * 9, t = s_[1] << 17;
    s_[2] ^= s_[0];
    s_[3] ^= s_[1];
    s_[1] ^= s_[2];
    s_[0] ^= s_[3];
    s_[2] ^= t;
    s_[3] = Rotate(s_[3], 45);
    return result;
  }
  // In (0, 1): the top 53 bits, centred in their interval, so that log never sees 0.
  double Uniform() { return (static_cast<double>(Bits() >> 11) + 0.5) * 0x1p-53; }
  std::uint64_t s_[4];
  double spare_ = 0;
  bool has_spare_ = false;
};

enum StreamKind { kEtaStream = 0, kEpsilonStream = 1 };

// F with FFᵀ = Ω: the Cholesky factor, or for a singular Ω (a variance fixed at 0) the pivoted
// LDLᵀ one, PᵀL√D. Throws when Ω is not symmetric positive semi-definite.
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

SimulationDesign MakeSimulationDesign(const PopulationProblem& problem, const PopulationParameters& parameters) {
  const internal::PopulationPoint point = internal::SimulationPoint(problem, parameters);
  const auto& d = problem.impl();
  SimulationDesign design;
  const Eigen::VectorXd zero = Eigen::VectorXd::Zero(parameters.omega.rows());
  for (size_t i = 0; i < d.subjects.size(); ++i) {
    const internal::SubjectModel& s = d.subjects[i];
    SimulationDesign::Subject out;
    out.id = d.data->subjects[i].id;
    out.subject = static_cast<int>(i);
    out.time = s.objective->sample_times();
    out.dvid = s.objective->sample_outputs();
    out.dv = s.objective->observations();
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

void SimulatePopulation(const PopulationProblem& problem, const PopulationParameters& parameters,
                        const PopulationSimulationOptions& options,
                        const std::function<void(const SimulatedReplicate&)>& consume) {
  std::string why;
  if (!options.IsValid(&why)) throw InputError("population simulation: " + why);
  const internal::PopulationPoint point = internal::SimulationPoint(problem, parameters);
  const Eigen::MatrixXd factor = internal::OmegaFactor(parameters.omega);
  const auto& subjects = problem.impl().subjects;
  const int n = static_cast<int>(subjects.size());
  for (int r = 0; r < options.replicates; ++r) {
    SimulatedReplicate replicate;
    replicate.replicate = r;
    replicate.subjects.resize(static_cast<size_t>(n));
    internal::ParallelFor(n, options.threads, [&](int i) {
      replicate.subjects[static_cast<size_t>(i)] =
          internal::SimulateSubject(subjects[static_cast<size_t>(i)], point, factor, options, r, i);
    });
    for (const SimulatedSubject& s : replicate.subjects) replicate.failed += s.ok ? 0 : 1;
    consume(replicate);
  }
}

}  // namespace pk
