// The covariance step (engine.h), NONMEM's default $COV: the sandwich R⁻¹SR⁻¹ with
//
//   R = ∇²OFV                        (second central differences over the estimated
//                                     natural parameters θ, Ω's elements, σ)
//   S = Σ_i ∇OFV_i ∇OFV_iᵀ           (central differences of each subject's OFV_i)
//
// On the log-likelihood scale R_LL = R/2 and S_LL = S/4, and R_LL⁻¹S_LL R_LL⁻¹ = R⁻¹SR⁻¹: the
// sandwich is the same on either scale. Every perturbed OFV starts its subjects' searches from
// the estimate's modes. The condition number is that of the estimates' correlation matrix,
// largest over smallest eigenvalue, as NONMEM prints it.
#include <algorithm>
#include <cmath>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include "population/engine.h"
#include "population/problem_impl.h"

namespace pk {
namespace internal {
namespace {

constexpr double kRelativeStep = 1e-3;

// The relative step of the differences: 1e-3 where the OFV is exact to rounding (Φ/Γ, whose
// relative_noise is the floor 1e-10), and on
// the ODE propagator ε^¼ for the OFV's relative error ε (SubjectModel::relative_noise, 10·rtol),
// which balances a second difference's truncation (h²) against its noise (ε/h²): with rtol 1e-8,
// 0.018. At 1e-3 there the noise swung pheno_pop's SE(ω²) by a factor of 3 between two points
// 1e-4 apart.
double RelativeStep(const PopulationEngine& engine) {
  double noise = 0;
  for (const SubjectModel& s : engine.problem().impl().subjects) noise = std::max(noise, s.relative_noise);
  return noise > 1e-10 ? std::max(kRelativeStep, std::pow(noise, 0.25)) : kRelativeStep;
}

struct Differences {
  const PopulationEngine& engine;
  const Packing& packing;
  const std::vector<Eigen::VectorXd>& starts;
  Eigen::VectorXd z0;

  bool At(const Eigen::VectorXd& z, PopulationEngine::Result* r) const {
    try {
      *r = engine.Evaluate(packing.FromNatural(z), starts, false);
    } catch (const std::exception& e) {  // a perturbed Ω that is not positive definite
      r->ok = false;
      r->message = e.what();
    }
    return r->ok;
  }
};

}  // namespace

void PopulationCovariance(const PopulationEngine& engine, const Packing& packing,
                          const std::vector<Eigen::VectorXd>& starts, PopulationSummary* summary) {
  std::vector<int> est;
  for (size_t k = 0; k < packing.natural_fixed().size(); ++k) {
    if (!packing.natural_fixed()[k]) est.push_back(static_cast<int>(k));
  }
  const int p = static_cast<int>(est.size());
  if (p == 0) return;
  const Differences diff{engine, packing, starts, packing.Natural(summary->parameters)};
  Eigen::VectorXd h(p);
  const double step = RelativeStep(engine);
  for (int a = 0; a < p; ++a) h(a) = step * std::max(std::abs(diff.z0(est[a])), 0.01);
  PopulationEngine::Result centre, plus, minus, pp, pm, mp, mm;
  if (!diff.At(diff.z0, &centre)) {
    summary->covariance_message = "the OFV cannot be evaluated at the estimate";
    return;
  }
  const Eigen::Index n = centre.per_subject.size();
  Eigen::MatrixXd r(p, p), g(n, p);
  auto shifted = [&](int a, double sa, int b, double sb) {
    Eigen::VectorXd z = diff.z0;
    z(est[a]) += sa * h(a);
    if (b >= 0) z(est[b]) += sb * h(b);
    return z;
  };
  for (int a = 0; a < p; ++a) {
    if (!diff.At(shifted(a, 1, -1, 0), &plus) || !diff.At(shifted(a, -1, -1, 0), &minus)) {
      summary->covariance_message = "the OFV cannot be evaluated next to the estimate of " +
                                    packing.natural_names()[static_cast<size_t>(est[a])] + " (" +
                                    (plus.ok ? minus.message : plus.message) + ")";
      return;
    }
    r(a, a) = (plus.ofv - 2 * centre.ofv + minus.ofv) / (h(a) * h(a));
    g.col(a) = (plus.per_subject - minus.per_subject) / (2 * h(a));
    for (int b = 0; b < a; ++b) {
      if (!diff.At(shifted(a, 1, b, 1), &pp) || !diff.At(shifted(a, 1, b, -1), &pm) ||
          !diff.At(shifted(a, -1, b, 1), &mp) || !diff.At(shifted(a, -1, b, -1), &mm)) {
        summary->covariance_message = "the OFV cannot be evaluated next to the estimate";
        return;
      }
      r(a, b) = r(b, a) = (pp.ofv - pm.ofv - mp.ofv + mm.ofv) / (4 * h(a) * h(b));
    }
  }
  Eigen::LLT<Eigen::MatrixXd> llt(r);
  if (llt.info() != Eigen::Success) {
    summary->covariance_message = "the R matrix (Hessian of the OFV) is not positive definite at the estimate";
    return;
  }
  const Eigen::MatrixXd r_inv = llt.solve(Eigen::MatrixXd::Identity(p, p));
  const Eigen::MatrixXd s = g.transpose() * g;
  summary->covariance = r_inv * s * r_inv;
  const Eigen::VectorXd se = summary->covariance.diagonal().cwiseMax(0).cwiseSqrt();
  summary->correlation = se.cwiseInverse().asDiagonal() * summary->covariance * se.cwiseInverse().asDiagonal();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(summary->correlation, Eigen::EigenvaluesOnly);
  // A singular sandwich (S has rank at most the number of subjects) has no finite condition number.
  const double smallest = es.eigenvalues().minCoeff();
  summary->condition_number = smallest > 0 ? es.eigenvalues().maxCoeff() / smallest : HUGE_VAL;
  for (int a = 0; a < p; ++a) {
    PopulationEstimate& e = summary->estimates[static_cast<size_t>(est[a])];
    e.se = se(a);
    e.rse_pct = 100 * se(a) / std::abs(e.estimate);
  }
}

}  // namespace internal
}  // namespace pk
