// The covariance step (engine.h), NONMEM's default $COV: the sandwich R⁻¹SR⁻¹ with
//
//   R = ∇²OFV                        (over the estimated natural parameters z: θ, Ω's elements, σ)
//   S = Σ_i ∇OFV_i ∇OFV_iᵀ
//
// Where the outer gradient is exact (the implicit function theorem on the modes, outer_gradient.h),
// ∇OFV_i are the exact per-subject gradients at the estimate and R is the
// central difference of the exact gradient, 1 + 2p gradients in all: a first difference of an
// exact gradient, where NONMEM takes second differences of the OFV (1 + 2p² OFVs). The gradient
// is in the optimiser's x (packing.h); ∇_z = Dᵀ∇_x with D = ∂x/∂z. Otherwise (differences asked
// for, or a subject the exact derivatives do not reach) both come from central differences of the
// OFV, as NONMEM forms them.
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
#include "pk/population.h"

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
//
// A first difference of the exact gradient balances h² against ε/h: ε^⅓ on the ODE propagator
// (2e-3 at pkpop's rtol 1e-9), 1e-4 on Φ/Γ.
double RelativeStep(const PopulationEngine& engine, bool exact_gradient) {
  double noise = 0;
  for (const SubjectModel& s : engine.problem().impl().subjects) noise = std::max(noise, s.relative_noise);
  if (exact_gradient) return noise > 1e-10 ? std::max(1e-4, std::cbrt(noise)) : 1e-4;
  return noise > 1e-10 ? std::max(kRelativeStep, std::pow(noise, 0.25)) : kRelativeStep;
}

// The steps h_a = c·max(|z_a|, 0.01) over the estimated `est`, c as above.
Eigen::VectorXd Steps(const PopulationEngine& engine, const Eigen::VectorXd& z, const std::vector<int>& est,
                      bool exact_gradient) {
  const double c = RelativeStep(engine, exact_gradient);
  Eigen::VectorXd h(static_cast<Eigen::Index>(est.size()));
  for (Eigen::Index a = 0; a < h.size(); ++a) h(a) = c * std::max(std::abs(z(est[static_cast<size_t>(a)])), 0.01);
  return h;
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

// R (p×p) and the per-subject gradients G (n×p) over the estimated natural parameters `est`, by
// central differences of the OFV. False, with *why, where the OFV cannot be evaluated.
// Without `need_r` (MATRIX=S) only G, from the ± evaluations.
bool FromOfvDifferences(const Differences& diff, const std::vector<int>& est, const Eigen::VectorXd& h, bool need_r,
                        Eigen::MatrixXd* r, Eigen::MatrixXd* g, std::string* why) {
  const int p = static_cast<int>(est.size());
  PopulationEngine::Result centre, plus, minus, pp, pm, mp, mm;
  if (!diff.At(diff.z0, &centre)) {
    *why = "the OFV cannot be evaluated at the estimate";
    return false;
  }
  r->setZero(p, p);
  g->resize(centre.per_subject.size(), p);
  auto shifted = [&](int a, double sa, int b, double sb) {
    Eigen::VectorXd z = diff.z0;
    z(est[a]) += sa * h(a);
    if (b >= 0) z(est[b]) += sb * h(b);
    return z;
  };
  for (int a = 0; a < p; ++a) {
    if (!diff.At(shifted(a, 1, -1, 0), &plus) || !diff.At(shifted(a, -1, -1, 0), &minus)) {
      *why = "the OFV cannot be evaluated next to the estimate of " +
             diff.packing.natural_names()[static_cast<size_t>(est[a])] + " (" + (plus.ok ? minus.message : plus.message) +
             ")";
      return false;
    }
    (*r)(a, a) = (plus.ofv - 2 * centre.ofv + minus.ofv) / (h(a) * h(a));
    g->col(a) = (plus.per_subject - minus.per_subject) / (2 * h(a));
    for (int b = 0; b < a && need_r; ++b) {
      if (!diff.At(shifted(a, 1, b, 1), &pp) || !diff.At(shifted(a, 1, b, -1), &pm) ||
          !diff.At(shifted(a, -1, b, 1), &mp) || !diff.At(shifted(a, -1, b, -1), &mm)) {
        *why = "the OFV cannot be evaluated next to the estimate";
        return false;
      }
      (*r)(a, b) = (*r)(b, a) = (pp.ofv - pm.ofv - mp.ofv + mm.ofv) / (4 * h(a) * h(b));
    }
  }
  return true;
}

// D = ∂x/∂z over `est` (q×p) at z: central differences of Pack∘FromNatural, a cheap smooth
// bijection (logs, logits and a Cholesky factor), at steps where their error (about 1e-10 of D)
// is far below the R's own differencing error.
Eigen::MatrixXd PackingJacobian(const Packing& packing, const Eigen::VectorXd& z, const std::vector<int>& est) {
  Eigen::MatrixXd d(packing.size(), static_cast<Eigen::Index>(est.size()));
  for (size_t a = 0; a < est.size(); ++a) {
    const double step = 1e-6 * std::max(std::abs(z(est[a])), 0.01);
    Eigen::VectorXd up = z, down = z;
    up(est[a]) += step;
    down(est[a]) -= step;
    d.col(static_cast<Eigen::Index>(a)) =
        (packing.Pack(packing.FromNatural(up)) - packing.Pack(packing.FromNatural(down))) / (2 * step);
  }
  return d;
}

// ∇_z OFV over `est` at z, and the per-subject rows when `per_subject` is given, from the exact
// outer gradient. False, with *why, where a mode or a gradient cannot be formed.
bool ExactGradient(const Differences& diff, const Eigen::VectorXd& z, const std::vector<int>& est,
                   Eigen::VectorXd* gradient, Eigen::MatrixXd* per_subject, std::string* why) {
  PopulationEngine::Result r;
  PopulationParameters p;
  try {
    p = diff.packing.FromNatural(z);
    r = diff.engine.Evaluate(p, diff.starts, true);
  } catch (const std::exception& e) {  // a perturbed Ω that is not positive definite
    r.ok = false;
    r.message = e.what();
  }
  if (!r.ok) {
    *why = r.message;
    return false;
  }
  Eigen::VectorXd gx;
  Eigen::MatrixXd gx_subjects;
  PopulationEngine::Differenced differenced;
  if (!diff.engine.Gradient(diff.packing, diff.packing.Pack(p), r.modes, &gx, per_subject ? &gx_subjects : nullptr,
                            why, &differenced)) {
    return false;
  }
  // A subject's second order differenced (its higher orders failed) leaves the gradient
  // off by 1e-4 or so: too coarse to difference again.
  if (differenced.subjects > 0) {
    *why = "a subject's second-order sensitivities were differences (" + differenced.reason + ")";
    return false;
  }
  const Eigen::MatrixXd d = PackingJacobian(diff.packing, z, est);
  *gradient = d.transpose() * gx;
  if (per_subject) *per_subject = gx_subjects * d;
  if (!gradient->allFinite() || (per_subject && !per_subject->allFinite())) {
    *why = "the gradient is not finite (a step across a bound of θ?)";
    return false;
  }
  return true;
}

// R and G as FromOfvDifferences gives them, from the exact gradient: R's column a is the central
// difference of ∇_z OFV along z_a, symmetrised.
bool FromExactGradient(const Differences& diff, const std::vector<int>& est, const Eigen::VectorXd& h, bool need_r,
                       Eigen::MatrixXd* r, Eigen::MatrixXd* g, std::string* why) {
  const int p = static_cast<int>(est.size());
  Eigen::VectorXd centre, plus, minus;
  if (!ExactGradient(diff, diff.z0, est, &centre, g, why)) return false;
  r->setZero(p, p);
  for (int a = 0; a < p && need_r; ++a) {
    Eigen::VectorXd up = diff.z0, down = diff.z0;
    up(est[a]) += h(a);
    down(est[a]) -= h(a);
    if (!ExactGradient(diff, up, est, &plus, nullptr, why) || !ExactGradient(diff, down, est, &minus, nullptr, why)) {
      *why = "the gradient cannot be formed next to the estimate of " +
             diff.packing.natural_names()[static_cast<size_t>(est[a])] + " (" + *why + ")";
      return false;
    }
    r->col(a) = (plus - minus) / (2 * h(a));
  }
  *r = (0.5 * (*r + r->transpose())).eval();
  return true;
}

// The covariance from R and S as NONMEM's MATRIX= asks: R⁻¹SR⁻¹, 2R⁻¹ or 4S⁻¹ (on the
// log-likelihood scale R_LL = R/2, S_LL = S/4: R_LL⁻¹, S_LL⁻¹ and the sandwich of the two).
bool Combine(CovarianceMatrix matrix, const Eigen::MatrixXd& r, const Eigen::MatrixXd& s, Eigen::MatrixXd* cov,
             std::string* why) {
  const Eigen::MatrixXd identity = Eigen::MatrixXd::Identity(r.rows(), r.cols());
  if (matrix == CovarianceMatrix::kS) {
    // S = GᵀG has rank at most the number of subjects; rounding may leave a singular one a tiny
    // positive pivot, so a pivot below 1e-12 of the largest is singular too.
    Eigen::LLT<Eigen::MatrixXd> llt(s);
    const Eigen::VectorXd pivots = llt.matrixLLT().diagonal().cwiseAbs2();
    if (llt.info() != Eigen::Success || !(pivots.minCoeff() > 1e-12 * pivots.maxCoeff())) {
      *why = "the S matrix (cross-product of the subjects' gradients) is singular at the estimate: it has rank at "
             "most the number of subjects";
      return false;
    }
    *cov = 4 * llt.solve(identity);
    return true;
  }
  Eigen::LLT<Eigen::MatrixXd> llt(r);
  if (llt.info() != Eigen::Success) {
    *why = "the R matrix (Hessian of the OFV) is not positive definite at the estimate";
    return false;
  }
  const Eigen::MatrixXd r_inv = llt.solve(identity);
  *cov = matrix == CovarianceMatrix::kR ? Eigen::MatrixXd(2 * r_inv) : Eigen::MatrixXd(r_inv * s * r_inv);
  return true;
}

}  // namespace

void PopulationCovariance(const PopulationEngine& engine, const Packing& packing,
                          const std::vector<Eigen::VectorXd>& starts, bool exact_gradient,
                          CovarianceMatrix matrix, PopulationSummary* summary) {
  std::vector<int> est;
  for (size_t k = 0; k < packing.natural_fixed().size(); ++k) {
    if (!packing.natural_fixed()[k]) est.push_back(static_cast<int>(k));
  }
  const int p = static_cast<int>(est.size());
  if (p == 0) return;
  const Differences diff{engine, packing, starts, packing.Natural(summary->parameters)};
  Eigen::VectorXd h = Steps(engine, diff.z0, est, exact_gradient);
  Eigen::MatrixXd r, g;
  std::string why;
  const bool need_r = matrix != CovarianceMatrix::kS;
  // Where the exact gradient cannot serve (a subject's second order differenced, a gradient that
  // fails), the OFV's differences, as NONMEM forms them, at their own step.
  if (exact_gradient && !FromExactGradient(diff, est, h, need_r, &r, &g, &why)) {
    exact_gradient = false;
    h = Steps(engine, diff.z0, est, false);
  }
  if (!exact_gradient && !FromOfvDifferences(diff, est, h, need_r, &r, &g, &why)) {
    summary->covariance_message = why;
    return;
  }
  const std::string r_from = exact_gradient ? "R from central differences of the exact gradient"
                                            : "R from central differences of the OFV";
  const std::string s_from = exact_gradient ? "S from exact per-subject gradients"
                                            : "S from central differences of each subject's OFV";
  summary->covariance_derivatives = matrix == CovarianceMatrix::kR   ? r_from
                                    : matrix == CovarianceMatrix::kS ? s_from
                                                                     : r_from + ", " + s_from;
  summary->covariance_matrix = matrix;
  if (!Combine(matrix, r, g.transpose() * g, &summary->covariance, &summary->covariance_message)) return;
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
  // A SAME block's elements are its source's parameters: the same SE (as NONMEM lists them).
  for (size_t k = 0; k < summary->estimates.size(); ++k) {
    if (!packing.natural_same()[k]) continue;
    const PopulationEstimate& source = summary->estimates[static_cast<size_t>(packing.NaturalSource(k))];
    summary->estimates[k].se = source.se;
    summary->estimates[k].rse_pct = source.rse_pct;
  }
}

}  // namespace internal
}  // namespace pk
