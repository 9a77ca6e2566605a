// The gradient of OFV_i with respect to the packed population parameters x, for FOCE, FOCEI and
// Laplace, by the implicit function theorem on the conditional mode (Almquist, Leander & Jirstrand,
// J Pharmacokinet Pharmacodyn 2015;42:191-209; docs/population.md), and for FO at η = 0, which does
// not move (FirstOrderGradient):
//
//   OFV_i(x) = L(η̂(x), x),   L(η, x) = l(η, x) + log det Ω + log det H(η, x),   ∇_η l(η̂, x) = 0
//   dOFV_i/dx = ∂L/∂x + (∂L/∂η)ᵀ dη̂/dx,    dη̂/dx = −(∇²_ηη l)⁻¹ ∇²_ηx l.
//
// H contains ∂f/∂η, so these need second derivatives of the predictions ŷ(φ). The subject's ŷ is
// replaced by its second-order Taylor model about φ̂ = φ(η̂), which has the same value, gradient
// and Hessian there, and l and L are evaluated on HyperDual in z = (η, x): ∇L and the η rows of
// ∇²l (all the formula needs) are then exact given ŷ's first and second derivatives. The first derivatives J = ∂ŷ/∂φ are the exact
// forward sensitivities; the second, T = ∂J/∂φ_k for each η'd φ_k, are exact too on Φ/Γ (the
// second-order sensitivities of exact/second_order.h) and integrated with the state on the ODE
// propagator (ode/second_order.h), steady states included, with doses that move with η on the
// event engine on jets (exact/ and ode/moving_events.h). Where they fail (a hand-built model's
// computed modifier without an evaluation on HyperDual3, a numerical failure) they are central
// differences of J, Richardson-extrapolated.
// The residual variance v(ŷ, σ) enters by its own second-order Taylor model, its second
// derivatives differences of its exact first ones.
//
// Laplace's H is the exact ½∇²_ηη l, which holds ∂²ŷ/∂η² and ∂²v/∂ŷ²: log det H's gradient needs
// them to first order in z, i.e. U = ∂³ŷ/∂φ_a∂φ_b∂φ_c for η'd a, b (the third-order sensitivities,
// Objective::ThirdDerivatives) and ∂³v/∂ŷ²∂(ŷ, σ). H's terms are formed on HyperDual from them, one
// by one as ExactConditionalHessian forms them in doubles (M3's censored samples included), and
// only their gradients are used.
#include "population/outer_gradient.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <vector>

#include <Eigen/Cholesky>

#include "censoring.h"
#include "population/half_hessian_term.h"
#include "population/hyper_dual.h"

namespace pk {
namespace internal {
namespace {

constexpr double kPhiStep = 1e-3;  // relative step in φ for T (Richardson with h and h/2)

// FOCE and FO hold the residual variance at η = 0 (no interaction).
bool NoInteraction(PopulationMethod m) { return m == PopulationMethod::kFoce || m == PopulationMethod::kFo; }

// ŷ and J = ∂ŷ/∂φ over every φ (the θ, then a model file's η parameters) at φ.
bool Sensitivities(const SubjectModel& s, const Eigen::VectorXd& phi, Eigen::VectorXd* yhat, Eigen::MatrixXd* j,
                   std::string* why) {
  return s.objective->Sensitivities(phi, s.phi_index, yhat, j, why);
}

// T[j](k, l) = ∂²ŷ_j/∂φ_k∂φ_l for k or l η'd (others 0) from the second-order sensitivities
// (Objective::SecondDerivatives). False when the subject's route has none, with `why`.
bool ExactSecondOrder(const SubjectModel& s, const Eigen::VectorXd& phi, std::vector<Eigen::MatrixXd>* t,
                      std::string* why) {
  const auto p = static_cast<int>(s.phi_index.size());
  std::vector<bool> etad(static_cast<size_t>(p), false);
  for (int k : s.eta_phi) etad[static_cast<size_t>(k)] = true;
  std::vector<std::pair<int, int>> pairs;
  for (int k : s.eta_phi) {
    for (int l = 0; l < p; ++l) {
      if (!etad[static_cast<size_t>(l)] || l >= k) pairs.emplace_back(k, l);  // a pair of η'd φ once
    }
  }
  std::vector<Eigen::VectorXd> second;
  if (!s.objective->SecondDerivatives(phi, s.phi_index, pairs, &second, why)) return false;
  const Eigen::Index n = second.empty() ? 0 : second.front().size();
  t->assign(static_cast<size_t>(n), Eigen::MatrixXd::Zero(p, p));
  for (size_t i = 0; i < pairs.size(); ++i) {
    const auto [k, l] = pairs[i];
    for (Eigen::Index j = 0; j < n; ++j) (*t)[static_cast<size_t>(j)](k, l) = (*t)[static_cast<size_t>(j)](l, k) = second[i](j);
  }
  return true;
}

// T as above by Richardson-extrapolated central differences of the exact first-order
// sensitivities, where no second-order sensitivities exist. The step is relative to φ_k, or for a
// file's η parameter (φ = η, near 0) to the η's prior scale 1/√(Ω⁻¹)_mm.
bool SecondOrderByDifferences(const SubjectModel& s, const PopulationPoint& point, const Eigen::VectorXd& phi,
                              std::vector<Eigen::MatrixXd>* t, std::string* why) {
  const auto p = static_cast<Eigen::Index>(s.phi_index.size());
  Eigen::VectorXd y;
  Eigen::MatrixXd jp, jm, d[2];
  std::vector<bool> done(static_cast<size_t>(p), false);  // η'd parameters whose differences are in T
  for (size_t m = 0; m < s.eta_free.size(); ++m) {
    const int at = s.eta_free[m], k = s.eta_phi[m];
    const auto mm = static_cast<Eigen::Index>(m);
    const double scale = s.eta_log[m] ? 1e-8 : 1 / std::sqrt(point.omega_inverse(mm, mm));
    for (int level = 0; level < 2; ++level) {
      const double h = kPhiStep * std::max(std::abs(phi(at)), scale) / (1 << level);
      Eigen::VectorXd e = phi;
      e(at) += h;
      if (!Sensitivities(s, e, &y, &jp, why)) return false;
      e(at) = phi(at) - h;
      if (!Sensitivities(s, e, &y, &jm, why)) return false;
      d[level] = (jp - jm) / (2 * h);
    }
    const Eigen::MatrixXd dj = (4 * d[1] - d[0]) / 3;  // ∂J/∂φ_k, n×P
    if (t->empty()) t->assign(static_cast<size_t>(dj.rows()), Eigen::MatrixXd::Zero(p, p));
    for (Eigen::Index j = 0; j < dj.rows(); ++j) {
      for (Eigen::Index l = 0; l < p; ++l) {
        Eigen::MatrixXd& tj = (*t)[static_cast<size_t>(j)];
        // A pair of η'd parameters is seen from both sides: average the two differences.
        const double v = done[static_cast<size_t>(l)] ? 0.5 * (tj(k, l) + dj(j, l)) : dj(j, l);
        tj(k, l) = tj(l, k) = v;
      }
    }
    done[static_cast<size_t>(k)] = true;
  }
  return true;
}

// v(ŷ, σ) and its first derivatives at one sample, with `second` its second derivatives (FOCEI;
// FOCE takes V to first order), and with `third` ∂³v/∂ŷ³ and ∂³v/∂ŷ²∂σ (Laplace's H holds ∂²v/∂ŷ²,
// whose gradient they are).
struct VarianceTaylor {
  double v = 0, vy = 0, vyy = 0, vyyy = 0;
  Eigen::VectorXd vs, vys, vyys;
  Eigen::MatrixXd vss;
};

// ∂³v/∂ŷ³ by the second difference of the exact ∂v/∂ŷ and ∂³v/∂ŷ²∂σ_i by central differences in σ_i of
// ∂²v/∂ŷ² (itself differenced): exact to rounding for libpk's error models, whose v is a polynomial
// of degree 2 in ŷ and in σ; a user's model that is not gets their O(h²) error.
void VarianceThird(const ResidualErrorModel& error, int output, double yhat, const Eigen::VectorXd& sigma,
                   VarianceTaylor* t) {
  const auto ns = sigma.size();
  Eigen::VectorXd vs(ns);
  const auto vy_at = [&](double y, const Eigen::VectorXd& s) {
    double v, vy;
    OutputVariance(error, output, y, s.data(), &v, &vy, vs.data());
    return vy;
  };
  const double h = 1e-3 * std::max(std::abs(yhat), 1e-8);
  t->vyyy = (vy_at(yhat + h, sigma) - 2 * vy_at(yhat, sigma) + vy_at(yhat - h, sigma)) / (h * h);
  const auto vyy_at = [&](const Eigen::VectorXd& s) { return (vy_at(yhat + h, s) - vy_at(yhat - h, s)) / (2 * h); };
  t->vyys.resize(ns);
  for (Eigen::Index i = 0; i < ns; ++i) {
    const double hs = 1e-3 * std::max(std::abs(sigma(i)), 1e-8);
    Eigen::VectorXd sp = sigma, sm = sigma;
    sp(i) += hs;
    sm(i) -= hs;
    t->vyys(i) = (vyy_at(sp) - vyy_at(sm)) / (2 * hs);
  }
}

VarianceTaylor Variance(const ResidualErrorModel& error, int output, double yhat, const Eigen::VectorXd& sigma,
                        bool second, bool third = false) {
  const auto ns = sigma.size();
  VarianceTaylor t;
  auto first = [&](double y, const Eigen::VectorXd& s, double* v, double* vy, Eigen::VectorXd* vs) {
    vs->resize(ns);
    OutputVariance(error, output, y, s.data(), v, vy, vs->data());
  };
  first(yhat, sigma, &t.v, &t.vy, &t.vs);
  if (!second) return t;
  double v1, v2, vy1, vy2;
  Eigen::VectorXd vs1, vs2;
  const double hy = 1e-5 * std::max(std::abs(yhat), 1e-8);
  first(yhat + hy, sigma, &v1, &vy1, &vs1);
  first(yhat - hy, sigma, &v2, &vy2, &vs2);
  t.vyy = (vy1 - vy2) / (2 * hy);
  t.vys = (vs1 - vs2) / (2 * hy);
  t.vss.resize(ns, ns);
  for (Eigen::Index i = 0; i < ns; ++i) {
    const double hs = 1e-5 * std::abs(sigma(i));
    Eigen::VectorXd sp = sigma, sm = sigma;
    sp(i) += hs;
    sm(i) -= hs;
    first(yhat, sp, &v1, &vy1, &vs1);
    first(yhat, sm, &v2, &vy2, &vs2);
    t.vss.col(i) = (vs1 - vs2) / (2 * hs);
  }
  t.vss = 0.5 * (t.vss + t.vss.transpose()).eval();
  if (third) VarianceThird(error, output, yhat, sigma, &t);
  return t;
}

// log det of a symmetric positive definite matrix by Cholesky, and false when it is not.
template <class HD>
bool LogDet(std::vector<std::vector<HD>> a, HD* out) {
  const size_t q = a.size();
  *out = HD(0, a.empty() ? HyperDualShape() : a[0][0].shape());
  for (size_t k = 0; k < q; ++k) {
    for (size_t j = 0; j < k; ++j) a[k][k] -= a[k][j] * a[k][j];
    if (!(a[k][k].value() > 0)) return false;
    a[k][k] = sqrt(a[k][k]);
    *out += 2 * log(a[k][k]);
    for (size_t i = k + 1; i < q; ++i) {
      for (size_t j = 0; j < k; ++j) a[i][k] -= a[i][j] * a[k][j];
      a[i][k] /= a[k][k];
    }
  }
  return true;
}

// The inverse of a lower-triangular matrix.
template <class HD>
std::vector<std::vector<HD>> LowerInverse(const std::vector<std::vector<HD>>& l, HyperDualShape d) {
  using HDMatrix = std::vector<std::vector<HD>>;
  const size_t q = l.size();
  HDMatrix inv(q, std::vector<HD>(q, HD(0, d)));
  for (size_t i = 0; i < q; ++i) {
    inv[i][i] = HD::Reciprocal(l[i][i]);
    for (size_t j = 0; j < i; ++j) {
      HD sum(0, d);
      for (size_t k = j; k < i; ++k) sum += l[i][k] * inv[k][j];
      inv[i][j] = -sum / l[i][i];
    }
  }
  return inv;
}

// U[j](a·q + b, c) = ∂³ŷ_j/∂φ_ka∂φ_kb∂φ_c for the η'd parameters k_a, k_b (η positions a, b) and every
// φ_c, from the third-order sensitivities (Objective::ThirdDerivatives). False with `why` where the
// route has none.
bool ExactThirdOrder(const SubjectModel& s, const Eigen::VectorXd& phi, std::vector<Eigen::MatrixXd>* u,
                     std::string* why) {
  const auto p = static_cast<int>(s.phi_index.size()), q = static_cast<int>(s.eta_phi.size());
  std::map<std::array<int, 3>, int> index;  // each sorted triple once
  std::vector<std::array<int, 3>> triples;
  std::vector<int> slot;  // per (a, b, c): its triple
  for (int a = 0; a < q; ++a) {
    for (int b = 0; b < q; ++b) {
      for (int c = 0; c < p; ++c) {
        std::array<int, 3> t{s.eta_phi[static_cast<size_t>(a)], s.eta_phi[static_cast<size_t>(b)], c};
        std::sort(t.begin(), t.end());
        const auto [it, added] = index.emplace(t, static_cast<int>(triples.size()));
        if (added) triples.push_back(t);
        slot.push_back(it->second);
      }
    }
  }
  std::vector<Eigen::VectorXd> third;
  if (!s.objective->ThirdDerivatives(phi, s.phi_index, triples, &third, why)) return false;
  const Eigen::Index n = third.empty() ? 0 : third.front().size();
  u->assign(static_cast<size_t>(n), Eigen::MatrixXd(q * q, p));
  for (Eigen::Index j = 0; j < n; ++j) {
    Eigen::MatrixXd& uj = (*u)[static_cast<size_t>(j)];
    for (int r = 0, k = 0; r < q * q; ++r) {
      for (int c = 0; c < p; ++c) uj(r, c) = third[static_cast<size_t>(slot[static_cast<size_t>(k++)])](j);
    }
  }
  return true;
}

// The predictions' expansion: J and T at φ̂ = φ(η̂), (FOCE) ŷ and J at η = 0, and (Laplace) U.
struct Expansion {
  Eigen::VectorXd phi0, y0, phi00, y00;
  Eigen::MatrixXd j0, j00;
  std::vector<Eigen::MatrixXd> t, u;
};

// *differenced: why T was differenced (empty when the second-order sensitivities served).
bool Expand(const SubjectModel& s, const PopulationPoint& p, const Eigen::VectorXd& eta, bool foce, Expansion* e,
            std::string* differenced, std::string* why) {
  e->phi0 = IndividualValues(s, p, eta);
  if (!Sensitivities(s, e->phi0, &e->y0, &e->j0, why)) return false;
  differenced->clear();
  const bool laplace = p.method == PopulationMethod::kLaplace;
  if (!ExactSecondOrder(s, e->phi0, &e->t, differenced)) {
    if (differenced->empty()) *differenced = "no second-order sensitivities";
    if (laplace) {  // its H holds ∂²ŷ, exact only from the second-order sensitivities, and its gradient ∂³ŷ
      *why = "Laplace's gradient needs exact second and third derivatives of the predictions (" + *differenced + ")";
      return false;
    }
    if (!SecondOrderByDifferences(s, p, e->phi0, &e->t, why)) return false;
  }
  e->phi00 = IndividualValues(s, p, Eigen::VectorXd::Zero(eta.size()));
  if (foce && e->phi00 == e->phi0) {  // at η = 0 (FO): the same expansion point
    e->y00 = e->y0;
    e->j00 = e->j0;
  } else if (foce && !Sensitivities(s, e->phi00, &e->y00, &e->j00, why)) {
    return false;
  }
  const auto np = static_cast<Eigen::Index>(s.phi_index.size());
  if (e->t.empty()) e->t.assign(static_cast<size_t>(e->y0.size()), Eigen::MatrixXd::Zero(np, np));
  if (laplace) {
    if (!ExactThirdOrder(s, e->phi0, &e->u, why)) return false;
    const auto q = static_cast<Eigen::Index>(eta.size());
    if (e->u.empty()) e->u.assign(static_cast<size_t>(e->y0.size()), Eigen::MatrixXd::Zero(q * q, np));
  }
  return true;
}

// The parameters as functions of z = (η, x), and their offsets from the expansion point.
template <class HD>
struct Variables {
  HyperDualShape d;  // second derivatives in η only (the rows of ∇²l the gradient needs)
  std::vector<HD> eta, theta, sigma, phi, dphi, dphi00, dsigma;
  std::vector<std::vector<HD>> lo;  // Ω's Cholesky factor
};

template <class HD>
Variables<HD> MakeVariables(const SubjectModel& s, const PopulationPoint& p, const Packing& packing,
                            const Eigen::VectorXd& x, const Eigen::VectorXd& eta, const Expansion& e) {
  Variables<HD> v;
  const auto q = static_cast<int>(eta.size()), m = static_cast<int>(x.size());
  const HyperDualShape d{q, q + m};
  v.d = d;
  std::vector<HD> xs;
  for (int i = 0; i < q; ++i) v.eta.push_back(HD::Variable(eta(i), d, i));
  for (int i = 0; i < m; ++i) xs.push_back(HD::Variable(x(i), d, q + i));
  packing.UnpackAs(xs, [d](double c) { return HD(c, d); }, &v.theta, &v.sigma, &v.lo);
  std::vector<int> eta_of(s.phi_index.size(), -1);
  for (int i = 0; i < q; ++i) eta_of[static_cast<size_t>(s.eta_phi[static_cast<size_t>(i)])] = i;
  for (size_t k = 0; k < s.phi_index.size(); ++k) {
    // φ_k = θ_k, θ_k·exp(η) or (a file's η parameter, k past the θ) η; at η = 0: θ_k or 0.
    const bool is_theta = k < s.theta_index.size();
    const HD at_zero = is_theta ? v.theta[k] : HD(0, d);
    const int m = eta_of[k];
    if (m < 0) {
      v.phi.push_back(at_zero);
    } else {
      const HD& eta_m = v.eta[static_cast<size_t>(m)];
      v.phi.push_back(s.eta_log[static_cast<size_t>(m)] ? at_zero * exp(eta_m) : eta_m);
    }
    v.dphi.push_back(v.phi.back() + (-e.phi0(s.phi_index[k])));
    v.dphi00.push_back(at_zero + (-e.phi00(s.phi_index[k])));
  }
  for (size_t i = 0; i < v.sigma.size(); ++i) v.dsigma.push_back(v.sigma[i] + (-p.sigma(static_cast<Eigen::Index>(i))));
  return v;
}

// ηᵀΩ⁻¹η = ‖L⁻¹η‖², log det Ω = 2 Σ log L_kk, and Ω⁻¹ = L⁻ᵀL⁻¹ (H's first term).
template <class HD>
void OmegaTerms(const Variables<HD>& v, HD* quad, HD* log_det_omega, std::vector<std::vector<HD>>* h) {
  const size_t q = v.eta.size();
  const std::vector<std::vector<HD>> linv = LowerInverse<HD>(v.lo, v.d);
  *quad = *log_det_omega = HD(0, v.d);
  for (size_t i = 0; i < q; ++i) {
    *log_det_omega += 2 * log(v.lo[i][i]);
    HD w(0, v.d);
    for (size_t k = 0; k <= i; ++k) w += linv[i][k] * v.eta[k];
    *quad += w * w;
  }
  h->assign(q, std::vector<HD>(q, HD(0, v.d)));
  for (size_t a = 0; a < q; ++a) {
    for (size_t b = 0; b < q; ++b) {
      for (size_t k = std::max(a, b); k < q; ++k) (*h)[a][b] += linv[k][a] * linv[k][b];
    }
  }
}

// Sample j's residual variance V and ∂V/∂ŷ (vy): at φ̂ to second order (FOCEI), or at η = 0 to
// first order (FOCE, where vy stays 0: V does not depend on η).
// With `vyy` (Laplace) also ∂²V/∂ŷ² to first order.
template <class HD>
void ResidualVariance(const SubjectModel& s, const PopulationPoint& p, const Expansion& e, const Variables<HD>& v,
                      Eigen::Index j, const HD& yhat, HD* var, HD* vy, HD* vyy = nullptr) {
  const bool foce = NoInteraction(p.method);
  const VarianceTaylor vt =
      Variance(*p.error, s.outputs(j), foce ? e.y00(j) : e.y0(j), p.sigma, !foce, vyy != nullptr);
  HD dy(0, v.d);
  if (foce) {
    for (size_t k = 0; k < v.dphi00.size(); ++k) dy += e.j00(j, static_cast<Eigen::Index>(k)) * v.dphi00[k];
  } else {
    dy = yhat + (-e.y0(j));
  }
  *var = dy * vt.vy + vt.v;
  *vy = HD(0, v.d);
  for (size_t i = 0; i < v.dsigma.size(); ++i) *var += vt.vs(static_cast<Eigen::Index>(i)) * v.dsigma[i];
  if (foce) return;
  HD second = dy * dy * vt.vyy;
  *vy = dy * vt.vyy + vt.vy;
  for (size_t i = 0; i < v.dsigma.size(); ++i) {
    const auto ii = static_cast<Eigen::Index>(i);
    second += 2 * vt.vys(ii) * dy * v.dsigma[i];
    *vy += vt.vys(ii) * v.dsigma[i];
    for (size_t k = 0; k < v.dsigma.size(); ++k) second += vt.vss(ii, static_cast<Eigen::Index>(k)) * v.dsigma[i] * v.dsigma[k];
  }
  *var += 0.5 * second;
  if (vyy == nullptr) return;
  *vyy = dy * vt.vyyy + vt.vyy;
  for (size_t i = 0; i < v.dsigma.size(); ++i) *vyy += vt.vyys(static_cast<Eigen::Index>(i)) * v.dsigma[i];
}

// ŷ_j as its second-order Taylor model about φ̂ (value, gradient and Hessian exact there).
template <class HD>
HD TaylorPrediction(const Expansion& e, const Variables<HD>& v, Eigen::Index j) {
  const Eigen::MatrixXd& tj = e.t[static_cast<size_t>(j)];
  const auto np = static_cast<int>(v.dphi.size());
  HD yhat(e.y0(j), v.d);
  for (int k = 0; k < np; ++k) {
    HD slope(e.j0(j, k), v.d);
    for (int c = 0; c < np; ++c) slope += 0.5 * tj(k, c) * v.dphi[static_cast<size_t>(c)];
    yhat += slope * v.dphi[static_cast<size_t>(k)];
  }
  return yhat;
}

// A sample's first η-derivatives as functions of z, ∂ŷ/∂φ to first order about φ̂ (from T): of ŷ
// (dy), of f = T(ŷ) (g), of V (dv, from vy = ∂V/∂ŷ), and of the η's φ (slope φ' = ∂φ_k/∂η: φ_k for a
// log-normal η, 1 for a file's η parameter).
template <class HD>
struct EtaFirst {
  std::vector<HD> dy, g, dv, slope;
};

template <class HD>
EtaFirst<HD> FirstEtaDerivatives(const SubjectModel& s, const Expansion& e, const Variables<HD>& v, Eigen::Index j,
                                 const HD& yhat, const HD& vy, bool logs) {
  const Eigen::MatrixXd& tj = e.t[static_cast<size_t>(j)];
  const auto np = static_cast<int>(v.dphi.size()), q = static_cast<int>(v.eta.size());
  EtaFirst<HD> d1;
  for (int a = 0; a < q; ++a) {
    const int k = s.eta_phi[static_cast<size_t>(a)];
    HD slope(e.j0(j, k), v.d);
    for (int c = 0; c < np; ++c) slope += tj(k, c) * v.dphi[static_cast<size_t>(c)];
    d1.slope.push_back(s.eta_log[static_cast<size_t>(a)] ? v.phi[static_cast<size_t>(k)] : HD(1, v.d));
    d1.dy.push_back(slope * d1.slope.back());
    d1.g.push_back(logs ? d1.dy.back() / yhat : d1.dy.back());
    d1.dv.push_back(vy * d1.dy.back());
  }
  return d1;
}

// Sample j's terms of l, (y − f)²/V + log V, and of H, g gᵀ/V + ½ v vᵀ/V² (v = 0 for FOCE), with
// ŷ(z) to second order about φ̂ and ∂ŷ/∂η(z) to first order.
template <class HD>
void AddSample(const SubjectModel& s, const PopulationPoint& p, const Expansion& e, const Variables<HD>& v,
               Eigen::Index j, HD* l, std::vector<std::vector<HD>>* h) {
  const HD yhat = TaylorPrediction(e, v, j);
  const bool logs = s.logs(j);
  HD var, vy;
  ResidualVariance(s, p, e, v, j, yhat, &var, &vy);
  const HD r = (logs ? log(yhat) : yhat) * -1.0 + s.y(j);
  const HD w = HD::Reciprocal(var);
  *l += r * r * w + log(var);
  const EtaFirst<HD> d1 = FirstEtaDerivatives(s, e, v, j, yhat, vy, logs);
  const std::vector<HD>& g = d1.g;
  const std::vector<HD>& dv = d1.dv;
  const bool foce = NoInteraction(p.method);
  for (size_t a = 0; a < g.size(); ++a) {
    for (size_t b = 0; b < g.size(); ++b) {
      (*h)[a][b] += g[a] * g[b] * w;
      if (!foce) (*h)[a][b] += 0.5 * dv[a] * dv[b] * w * w;
    }
  }
}

// log Φ(z) and the inverse Mills ratio m = φ(z)/Φ(z) on HD (Beal's M3): (log Φ)' = m, m' = −m(z + m),
// m'' = −m'(z + m) − m(1 + m').
template <class HD>
void Censored(const HD& z, HD* log_cdf, HD* mills) {
  double lc = 0, m = 0;
  LogNormalCdf(z.value(), &lc, &m);
  const double m1 = -m * (z.value() + m), m2 = -m1 * (z.value() + m) - m * (1 + m1);
  *log_cdf = HD::Apply(z, lc, m, m1);
  *mills = HD::Apply(z, m, m1, m2);
}

// Sample j's l for Laplace (M3's −2 log Φ(z) where censored), and its term of the exact ½∇²_ηη l
// (half_hessian_term.h, as ExactConditionalHessian forms it in doubles) as functions of z = (η, x):
// ∂ŷ/∂φ to first order about φ̂ from T, ∂²ŷ/∂φ∂φ from T and U, V's ŷ-derivatives from
// VarianceTaylor's. Only the terms' gradients are used (log det H's), which these make exact.
template <class HD>
void AddLaplaceSample(const SubjectModel& s, const PopulationPoint& p, const Expansion& e, const Variables<HD>& v,
                      Eigen::Index j, HD* l, std::vector<std::vector<HD>>* h) {
  const Eigen::MatrixXd &tj = e.t[static_cast<size_t>(j)], &uj = e.u[static_cast<size_t>(j)];
  const auto np = static_cast<int>(v.dphi.size()), q = static_cast<int>(v.eta.size());
  const HD yhat = TaylorPrediction(e, v, j);
  const bool logs = s.any_logs && s.logs(j);
  HD var, vy, vyy;
  ResidualVariance(s, p, e, v, j, yhat, &var, &vy, &vyy);
  const HD r = (logs ? log(yhat) : yhat) * -1.0 + s.y(j);
  const HD w = HD::Reciprocal(var);
  SampleScale<HD> scale{r, w, sqrt(w), s.censoring.size() > 0 ? s.censoring(j) : 0.0, HD(0, v.d), HD(0, v.d)};
  if (scale.sign == 0) {
    *l += r * r * w + log(var);
  } else {
    HD log_cdf;
    scale.z = r * scale.root_w * scale.sign;
    Censored(scale.z, &log_cdf, &scale.m);
    *l += -2.0 * log_cdf;
  }
  const EtaFirst<HD> d1 = FirstEtaDerivatives(s, e, v, j, yhat, vy, logs);
  for (int a = 0; a < q; ++a) {
    for (int b = 0; b <= a; ++b) {
      const int ka = s.eta_phi[static_cast<size_t>(a)], kb = s.eta_phi[static_cast<size_t>(b)];
      HD second(tj(ka, kb), v.d);  // ∂²ŷ/∂φ_ka∂φ_kb to first order
      for (int c = 0; c < np; ++c) second += uj(a * q + b, c) * v.dphi[static_cast<size_t>(c)];
      HD yy = second * d1.slope[static_cast<size_t>(a)] * d1.slope[static_cast<size_t>(b)];
      if (a == b && s.eta_log[static_cast<size_t>(a)]) yy += d1.dy[static_cast<size_t>(a)];
      const HD& ga = d1.g[static_cast<size_t>(a)];
      const HD& gb = d1.g[static_cast<size_t>(b)];
      const HD& va = d1.dv[static_cast<size_t>(a)];
      const HD& vb = d1.dv[static_cast<size_t>(b)];
      const HD ff = logs ? yy / yhat - ga * gb : yy;
      const HD vv = vyy * d1.dy[static_cast<size_t>(a)] * d1.dy[static_cast<size_t>(b)] + vy * yy;
      const HD term = HalfHessianTerm(scale, ga, gb, va, vb, ff, vv);
      (*h)[static_cast<size_t>(a)][static_cast<size_t>(b)] += term;
      if (b != a) (*h)[static_cast<size_t>(b)][static_cast<size_t>(a)] += term;
    }
  }
}

// FO: OFV_i = L − ¼ bᵀH⁻¹b at η = 0, which does not move (conditional.cc), with b = ∇_η l. With
// u = H⁻¹b, dOFV_i/dx = ∂L/∂x − ½ (∂b/∂x)ᵀu + ¼ uᵀ(∂H/∂x)u, ∂b/∂x being ∇²_ηx l.
template <class HD>
Eigen::VectorXd FirstOrderGradient(const HD& big_l, const HD& l, const std::vector<std::vector<HD>>& h,
                                   Eigen::Index q, Eigen::Index m) {
  Eigen::MatrixXd hv(q, q);
  for (Eigen::Index a = 0; a < q; ++a) {
    for (Eigen::Index b = 0; b < q; ++b) hv(a, b) = h[static_cast<size_t>(a)][static_cast<size_t>(b)].value();
  }
  const Eigen::VectorXd u = hv.llt().solve(Eigen::VectorXd(l.gradient().head(q)));
  Eigen::VectorXd g = big_l.gradient().tail(m) - 0.5 * l.hessian().topRightCorner(q, m).transpose() * u;
  for (Eigen::Index a = 0; a < q; ++a) {
    for (Eigen::Index b = 0; b < q; ++b) {
      g += 0.25 * u(a) * u(b) * h[static_cast<size_t>(a)][static_cast<size_t>(b)].gradient().tail(m);
    }
  }
  return g;
}

template <class HD>
bool GradientOn(const SubjectModel& s, const PopulationPoint& p, const Packing& packing, const Eigen::VectorXd& x,
                const SubjectMode& mode, Eigen::VectorXd* gradient, std::string* differenced, std::string* why) {
  Expansion e;
  if (!Expand(s, p, mode.eta, NoInteraction(p.method), &e, differenced, why)) return false;
  const Variables<HD> v = MakeVariables<HD>(s, p, packing, x, mode.eta, e);
  HD l, log_det_omega, log_det_h;
  std::vector<std::vector<HD>> h;
  OmegaTerms(v, &l, &log_det_omega, &h);  // l starts as ηᵀΩ⁻¹η
  const bool laplace = p.method == PopulationMethod::kLaplace;
  for (Eigen::Index j = 0; j < e.y0.size(); ++j) {
    if (laplace) {
      AddLaplaceSample(s, p, e, v, j, &l, &h);
    } else {
      AddSample(s, p, e, v, j, &l, &h);
    }
  }
  if (!LogDet<HD>(h, &log_det_h)) {
    *why = "H is not positive definite at the mode";
    return false;
  }
  const HD big_l = l + log_det_omega + log_det_h;
  const auto q = mode.eta.size(), m = x.size();
  if (p.method == PopulationMethod::kFo) {
    *gradient = FirstOrderGradient(big_l, l, h, q, m);
    if (!gradient->allFinite()) *why = "the gradient is not finite";
    return gradient->allFinite();
  }
  // dOFV/dx = ∂L/∂x − (∂L/∂η)ᵀ (∇²_ηη l)⁻¹ ∇²_ηx l
  const Eigen::MatrixXd lee = l.hessian().topLeftCorner(q, q), lex = l.hessian().topRightCorner(q, m);
  Eigen::LLT<Eigen::MatrixXd> llt(lee);
  if (llt.info() != Eigen::Success) {
    *why = "the Hessian of the conditional objective is not positive definite at the mode";
    return false;
  }
  const Eigen::VectorXd deta_weights = llt.solve(Eigen::VectorXd(big_l.gradient().head(q)));
  *gradient = big_l.gradient().tail(m) - lex.transpose() * deta_weights;
  if (!gradient->allFinite()) *why = "the gradient is not finite";
  return gradient->allFinite();
}

}  // namespace

bool SubjectOuterGradient(const SubjectModel& s, const PopulationPoint& p, const Packing& packing,
                          const Eigen::VectorXd& x, const SubjectMode& mode, Eigen::VectorXd* gradient,
                          std::string* differenced, std::string* why) {
  if (p.method == PopulationMethod::kLaplace && !mode.hessian_differenced.empty()) {
    // The OFV's H was differences of ∇l there: the exact gradient would be another objective's.
    *differenced = mode.hessian_differenced;
    *why = "Laplace's H at the mode was differenced (" + mode.hessian_differenced + ")";
    return false;
  }
  // The scalar's derivatives over z = (η, x) live on the stack up to 4 η and 16 variables (2 η and
  // 6 population parameters make 8), on the heap beyond.
  if (mode.eta.size() <= 4 && mode.eta.size() + x.size() <= 16) {
    return GradientOn<HyperDualT<4, 16>>(s, p, packing, x, mode, gradient, differenced, why);
  }
  return GradientOn<HyperDualT<Eigen::Dynamic, Eigen::Dynamic>>(s, p, packing, x, mode, gradient, differenced, why);
}

}  // namespace internal
}  // namespace pk
