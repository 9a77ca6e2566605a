// Parameter sets drawn from the estimates' uncertainty (pk/uncertainty.h).
#include "pk/uncertainty.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <string>
#include <vector>

#include <Eigen/Cholesky>

#include "internal_text.h"
#include "pk/error.h"
#include "pk/output.h"
#include "pk/residual_error.h"
#include "simulation/normal_stream.h"

namespace pk {
namespace {

constexpr int kMaxTries = 1000;

int EtaPosition(const PopulationEstimates& p, const Model& model, const std::string& name) {
  const int i = model.ParameterIndex(name);
  for (size_t k = 0; i >= 0 && k < p.etas.size(); ++k) {
    if (p.etas[k] == model.parameter_names()[static_cast<size_t>(i)]) return static_cast<int>(k);
  }
  return -1;
}

// A model file's SAME blocks repeat the block declared before them: their Ω follows that block's,
// where the run held the tie (its covariance names none of the block's variances; a run whose
// --block regrouped the block estimated it on its own, and the covariance names it). The copies, as
// positions in Ω: {to row, to column, from row, from column}, found once for every draw.
std::vector<std::array<int, 4>> SameCopies(const Model& model, const PopulationEstimates& p,
                                           const std::vector<bool>& named_variance) {
  std::vector<std::array<int, 4>> copies;
  const auto& blocks = model.declarations().omega_blocks;
  for (size_t b = 1; b < blocks.size(); ++b) {
    if (!blocks[b].same || blocks[b].etas.size() != blocks[b - 1].etas.size()) continue;
    std::vector<int> to, from;
    for (size_t i = 0; i < blocks[b].etas.size(); ++i) {
      to.push_back(EtaPosition(p, model, blocks[b].etas[i]));
      from.push_back(EtaPosition(p, model, blocks[b - 1].etas[i]));
    }
    const bool held = std::all_of(to.begin(), to.end(), [&](int at) { return at >= 0 && !named_variance[static_cast<size_t>(at)]; }) &&
                      std::all_of(from.begin(), from.end(), [](int at) { return at >= 0; });
    for (size_t i = 0; held && i < to.size(); ++i) {
      for (size_t j = 0; j < to.size(); ++j) copies.push_back({to[i], to[j], from[i], from[j]});
    }
  }
  return copies;
}

// Where a named natural value sits in a set of estimates.
struct Slot {
  enum Kind { kTheta, kOmega, kSigma } kind = kTheta;
  std::string theta;  // the canonical name
  Eigen::Index a = 0, b = 0;  // Ω's (a, b), or σ's a
};

Slot Resolve(const PopulationEstimates& base, const std::string& name, const Model& model) {
  Slot s;
  const std::string upper = internal::ToUpper(name);
  const std::vector<std::string> omega = internal::OmegaArguments(upper);
  if (!omega.empty()) {
    s.kind = Slot::kOmega;
    const int a = EtaPosition(base, model, omega.front()), b = EtaPosition(base, model, omega.back());
    if (a < 0 || b < 0) throw InputError(base.source + " has no η for " + name);
    s.a = a;
    s.b = b;
    return s;
  }
  if (IsResidualErrorName(upper)) {
    s.kind = Slot::kSigma;
    while (s.a < static_cast<Eigen::Index>(base.sigma_names.size()) && base.sigma_names[static_cast<size_t>(s.a)] != upper) ++s.a;
    if (s.a == static_cast<Eigen::Index>(base.sigma_names.size())) throw InputError(base.source + " has no " + name);
    return s;
  }
  const int i = model.ParameterIndex(name);
  if (i >= 0) s.theta = model.parameter_names()[static_cast<size_t>(i)];
  if (i < 0 || !base.theta.count(s.theta)) throw InputError(base.source + " has no typical value " + name);
  return s;
}

double Get(const PopulationEstimates& p, const Slot& s) {
  if (s.kind == Slot::kOmega) return p.omega(s.a, s.b);
  if (s.kind == Slot::kSigma) return p.sigma(s.a);
  return p.theta.at(s.theta);
}

void Set(const Slot& s, double v, PopulationEstimates* p) {
  if (s.kind == Slot::kOmega) {
    p->omega(s.a, s.b) = p->omega(s.b, s.a) = v;
  } else if (s.kind == Slot::kSigma) {
    p->sigma(s.a) = v;
  } else {
    p->theta[s.theta] = v;
  }
}

}  // namespace

bool InParameterSpace(const PopulationEstimates& p, const Model& model, std::string* why) {
  const auto& declared = model.declarations().parameters;
  for (const auto& [name, value] : p.theta) {
    const int i = model.ParameterIndex(name);
    const bool bounded = i >= 0 && static_cast<size_t>(i) < declared.size();
    if (!std::isfinite(value) || (i >= 0 && model.must_be_positive(i) && !(value > 0))) {
      *why = name + " = " + FormatNumber(value) + " is not positive";
      return false;
    }
    if (bounded && !(value >= declared[static_cast<size_t>(i)].lower && value <= declared[static_cast<size_t>(i)].upper)) {
      *why = name + " = " + FormatNumber(value) + " is outside its bounds in the model file";
      return false;
    }
  }
  if (p.omega.size() > 0 && Eigen::LLT<Eigen::MatrixXd>(p.omega).info() != Eigen::Success) {
    *why = "Ω is not positive definite";
    return false;
  }
  if (!((p.sigma.array() > 0).all() && p.sigma.allFinite())) {
    *why = "a σ is not positive";
    return false;
  }
  return true;
}

PopulationEstimates WithNaturalValues(const PopulationEstimates& base, const std::vector<std::string>& names,
                                      const Eigen::VectorXd& values, const Model& model) {
  PopulationEstimates out = base;
  for (size_t k = 0; k < names.size(); ++k) Set(Resolve(base, names[k], model), values(static_cast<Eigen::Index>(k)), &out);
  return out;
}

std::vector<PopulationEstimates> DrawFromCovariance(const PopulationEstimates& estimates,
                                                    const EstimatesCovariance& covariance, const Model& model,
                                                    int count, std::uint64_t seed, int* redrawn) {
  const auto m = static_cast<Eigen::Index>(covariance.names.size());
  if (covariance.covariance.rows() != m || covariance.covariance.cols() != m) {
    throw InputError("the estimates' covariance is not square over its names");
  }
  Eigen::MatrixXd factor;
  try {
    factor = internal::OmegaFactor(covariance.covariance);
  } catch (const InputError&) {
    throw InputError("the estimates' covariance is not symmetric positive semi-definite");
  }
  // The centre: the estimates' own values of the covariance's names (an unknown name throws here).
  std::vector<Slot> slots;
  Eigen::VectorXd centre(m);
  std::vector<bool> named_variance(estimates.etas.size(), false);
  for (Eigen::Index k = 0; k < m; ++k) {
    slots.push_back(Resolve(estimates, covariance.names[static_cast<size_t>(k)], model));
    centre(k) = Get(estimates, slots.back());
    if (slots.back().kind == Slot::kOmega && slots.back().a == slots.back().b) {
      named_variance[static_cast<size_t>(slots.back().a)] = true;
    }
  }
  const std::vector<std::array<int, 4>> same = SameCopies(model, estimates, named_variance);
  std::vector<PopulationEstimates> out;
  int rejected = 0;
  for (int r = 0; r < count; ++r) {
    internal::NormalStream stream(seed, r, 0, internal::kUncertaintyStream);
    bool drawn = false;
    for (int tries = 0; tries < kMaxTries && !drawn; ++tries) {
      Eigen::VectorXd z(m);
      for (Eigen::Index k = 0; k < m; ++k) z(k) = stream.Next();
      PopulationEstimates set = estimates;
      const Eigen::VectorXd x = centre + factor * z;
      for (Eigen::Index k = 0; k < m; ++k) Set(slots[static_cast<size_t>(k)], x(k), &set);
      for (const auto& [ti, tj, fi, fj] : same) set.omega(ti, tj) = set.omega(fi, fj);
      std::string why;
      if (InParameterSpace(set, model, &why)) {
        out.push_back(std::move(set));
        drawn = true;
      } else {
        ++rejected;
      }
    }
    if (!drawn) {
      throw InputError("parameter uncertainty: set " + std::to_string(r + 1) + " fell outside the parameter space in " +
                       std::to_string(kMaxTries) + " draws (a variance or θ whose SE is large beside it)");
    }
  }
  if (redrawn) *redrawn = rejected;
  return out;
}

}  // namespace pk
