// The gradient of OFV_i with respect to the packed population parameters x, for FOCE and FOCEI,
// by the implicit function theorem on the conditional mode (Almquist, Leander & Jirstrand,
// J Pharmacokinet Pharmacodyn 2015;42:191-209; docs/population.md):
//
//   OFV_i(x) = L(η̂(x), x),   L(η, x) = l(η, x) + log det Ω + log det H(η, x),   ∇_η l(η̂, x) = 0
//   dOFV_i/dx = ∂L/∂x + (∂L/∂η)ᵀ dη̂/dx,    dη̂/dx = −(∇²_ηη l)⁻¹ ∇²_ηx l.
//
// H contains ∂f/∂η, so these need second derivatives of the predictions ŷ(φ). The subject's ŷ is
// replaced by its second-order Taylor model about φ̂ = φ(η̂), which has the same value, gradient
// and Hessian there, and l and L are evaluated on HyperDual in z = (η, x): ∇²l and ∇L are then
// exact given ŷ's first and second derivatives. The first derivatives J = ∂ŷ/∂φ are the exact
// forward sensitivities; the second, T = ∂J/∂φ_k for each η'd φ_k, are central differences of J,
// Richardson-extrapolated (error ~1e-10 relative on the exact propagator): the one place a finite
// difference of the predictions remains (and the variance's second derivatives, below).
// The residual variance v(ŷ, σ) enters by its own second-order Taylor model, its second
// derivatives differences of its exact first ones.
#include "population/outer_gradient.h"

#include <cmath>

#include <Eigen/Cholesky>

#include "population/hyper_dual.h"

namespace pk {
namespace internal {
namespace {

constexpr double kPhiStep = 1e-3;  // relative step in φ for T (Richardson with h and h/2)

// ŷ and J = ∂ŷ/∂φ over every θ at φ.
bool Sensitivities(const SubjectModel& s, const Eigen::VectorXd& phi, Eigen::VectorXd* yhat, Eigen::MatrixXd* j,
                   std::string* why) {
  const Objective::Evaluation ev =
      s.objective->Evaluate(phi, s.theta_index, Objective::Need::kJacobian, GradientRoute::kForward);
  if (!ev.ok) {
    *why = ev.message;
    return false;
  }
  *yhat = ev.predictions;
  *j = -ev.jacobian.topRows(ev.predictions.size());
  return true;
}

// T[j](k, l) = ∂²ŷ_j/∂φ_k∂φ_l for k or l η'd (others 0).
bool SecondOrder(const SubjectModel& s, const Eigen::VectorXd& phi, std::vector<Eigen::MatrixXd>* t,
                 std::string* why) {
  const auto p = static_cast<Eigen::Index>(s.theta_index.size());
  Eigen::VectorXd y;
  Eigen::MatrixXd jp, jm, d[2];
  for (size_t m = 0; m < s.eta_free.size(); ++m) {
    const int at = s.eta_free[m], k = s.eta_theta[m];
    for (int level = 0; level < 2; ++level) {
      const double h = kPhiStep * std::abs(phi(at)) / (1 << level);
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
        const bool both = tj(k, l) != 0 || tj(l, k) != 0;
        const double v = both ? 0.5 * (tj(k, l) + dj(j, l)) : dj(j, l);
        tj(k, l) = tj(l, k) = v;
      }
    }
  }
  return true;
}

// v(ŷ, σ) and its derivatives to second order at one sample.
struct VarianceTaylor {
  double v = 0, vy = 0, vyy = 0;
  Eigen::VectorXd vs, vys;
  Eigen::MatrixXd vss;
};

VarianceTaylor Variance(const ResidualErrorModel& error, double yhat, const Eigen::VectorXd& sigma) {
  const auto ns = sigma.size();
  VarianceTaylor t;
  t.vs.resize(ns);
  auto first = [&](double y, const Eigen::VectorXd& s, double* v, double* vy, Eigen::VectorXd* vs) {
    vs->resize(ns);
    error.Variance(y, s.data(), v, vy, vs->data());
  };
  first(yhat, sigma, &t.v, &t.vy, &t.vs);
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
  return t;
}

// log det of a symmetric positive definite matrix by Cholesky, and false when it is not.
template <class HD>
bool LogDet(std::vector<std::vector<HD>> a, HD* out) {
  const size_t q = a.size();
  *out = HD(0, static_cast<int>(a.empty() ? 0 : a[0][0].gradient().size()));
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
std::vector<std::vector<HD>> LowerInverse(const std::vector<std::vector<HD>>& l, int d) {
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

template <class HD>
bool GradientOn(const SubjectModel& s, const PopulationPoint& p, const Packing& packing, const Eigen::VectorXd& x,
                const SubjectMode& mode, Eigen::VectorXd* gradient, std::string* why) {
  using HDMatrix = std::vector<std::vector<HD>>;
  const bool foce = p.method == PopulationMethod::kFoce, logs = p.error->log_transformed();
  const auto q = static_cast<int>(mode.eta.size()), m = static_cast<int>(x.size()), d = q + m;
  const auto np = static_cast<int>(s.theta_index.size());
  const Eigen::VectorXd phi0 = IndividualValues(s, p, mode.eta);
  Eigen::VectorXd y0, y00;
  Eigen::MatrixXd j0, j00;
  std::vector<Eigen::MatrixXd> t;
  if (!Sensitivities(s, phi0, &y0, &j0, why) || !SecondOrder(s, phi0, &t, why)) return false;
  const Eigen::VectorXd phi00 = IndividualValues(s, p, Eigen::VectorXd::Zero(q));
  if (foce && !Sensitivities(s, phi00, &y00, &j00, why)) return false;
  const Eigen::Index n = y0.size();
  if (t.empty()) t.assign(static_cast<size_t>(n), Eigen::MatrixXd::Zero(np, np));

  // z = (η, x): the parameters as functions of z.
  std::vector<HD> eta, xs, theta, sigma;
  for (int i = 0; i < q; ++i) eta.push_back(HD::Variable(mode.eta(i), d, i));
  for (int i = 0; i < m; ++i) xs.push_back(HD::Variable(x(i), d, q + i));
  HDMatrix lo;
  packing.UnpackAs(xs, [d](double v) { return HD(v, d); }, &theta, &sigma, &lo);
  std::vector<HD> dphi, dphi00;
  std::vector<int> eta_of(static_cast<size_t>(np), -1);
  for (int i = 0; i < q; ++i) eta_of[static_cast<size_t>(s.eta_theta[static_cast<size_t>(i)])] = i;
  std::vector<HD> phi;
  for (int k = 0; k < np; ++k) {
    const auto u = static_cast<size_t>(k);
    phi.push_back(eta_of[u] >= 0 ? theta[u] * exp(eta[static_cast<size_t>(eta_of[u])]) : theta[u]);
    dphi.push_back(phi.back() + (-phi0(s.theta_index[u])));
    dphi00.push_back(theta[u] + (-phi00(s.theta_index[u])));
  }
  std::vector<HD> dsigma;
  for (size_t i = 0; i < sigma.size(); ++i) dsigma.push_back(sigma[i] + (-p.sigma(static_cast<Eigen::Index>(i))));

  // Ω⁻¹ = L⁻ᵀL⁻¹, log det Ω = 2 Σ log L_kk, ηᵀΩ⁻¹η = ‖L⁻¹η‖².
  const HDMatrix linv = LowerInverse<HD>(lo, d);
  HD log_det_omega(0, d), quad(0, d);
  for (int i = 0; i < q; ++i) {
    log_det_omega += 2 * log(lo[static_cast<size_t>(i)][static_cast<size_t>(i)]);
    HD w(0, d);
    for (int k = 0; k <= i; ++k) w += linv[static_cast<size_t>(i)][static_cast<size_t>(k)] * eta[static_cast<size_t>(k)];
    quad += w * w;
  }
  HDMatrix h(static_cast<size_t>(q), std::vector<HD>(static_cast<size_t>(q), HD(0, d)));
  for (int a = 0; a < q; ++a) {
    for (int b = 0; b < q; ++b) {
      for (int k = std::max(a, b); k < q; ++k) {
        h[static_cast<size_t>(a)][static_cast<size_t>(b)] +=
            linv[static_cast<size_t>(k)][static_cast<size_t>(a)] * linv[static_cast<size_t>(k)][static_cast<size_t>(b)];
      }
    }
  }
  HD l = quad;
  for (Eigen::Index j = 0; j < n; ++j) {
    const Eigen::MatrixXd& tj = t[static_cast<size_t>(j)];
    // ŷ(z) to second order about φ̂, and ∂ŷ/∂η_i(z) to first order.
    HD yhat(y0(j), d);
    for (int k = 0; k < np; ++k) {
      const auto u = static_cast<size_t>(k);
      HD slope(j0(j, k), d);
      for (int c = 0; c < np; ++c) slope += 0.5 * tj(k, c) * dphi[static_cast<size_t>(c)];
      yhat += slope * dphi[u];
    }
    std::vector<HD> dy_deta;
    for (int i = 0; i < q; ++i) {
      const int k = s.eta_theta[static_cast<size_t>(i)];
      HD slope(j0(j, k), d);
      for (int c = 0; c < np; ++c) slope += tj(k, c) * dphi[static_cast<size_t>(c)];
      dy_deta.push_back(slope * phi[static_cast<size_t>(k)]);
    }
    const HD f = logs ? log(yhat) : yhat;
    // The residual variance: at φ̂ (FOCEI), or at η = 0 to first order (FOCE).
    HD v(0, d), vy(0, d);
    if (foce) {
      const VarianceTaylor vt = Variance(*p.error, y00(j), p.sigma);
      HD dy(0, d);
      for (int k = 0; k < np; ++k) dy += j00(j, k) * dphi00[static_cast<size_t>(k)];
      v = dy * vt.vy + vt.v;
      for (size_t i = 0; i < dsigma.size(); ++i) v += vt.vs(static_cast<Eigen::Index>(i)) * dsigma[i];
    } else {
      const VarianceTaylor vt = Variance(*p.error, y0(j), p.sigma);
      const HD dy = yhat + (-y0(j));
      HD second = dy * dy * vt.vyy;
      vy = dy * vt.vyy + vt.vy;
      for (size_t i = 0; i < dsigma.size(); ++i) {
        const auto ii = static_cast<Eigen::Index>(i);
        second += 2 * vt.vys(ii) * dy * dsigma[i];
        vy += vt.vys(ii) * dsigma[i];
        for (size_t k = 0; k < dsigma.size(); ++k) second += vt.vss(ii, static_cast<Eigen::Index>(k)) * dsigma[i] * dsigma[k];
      }
      v = dy * vt.vy + vt.v + 0.5 * second;
      for (size_t i = 0; i < dsigma.size(); ++i) v += vt.vs(static_cast<Eigen::Index>(i)) * dsigma[i];
    }
    const HD r = f * -1.0 + s.y(j);
    const HD w = HD::Reciprocal(v);
    l += r * r * w + log(v);
    std::vector<HD> g, dv;
    for (int i = 0; i < q; ++i) {
      g.push_back(logs ? dy_deta[static_cast<size_t>(i)] / yhat : dy_deta[static_cast<size_t>(i)]);
      dv.push_back(vy * dy_deta[static_cast<size_t>(i)]);
    }
    for (int a = 0; a < q; ++a) {
      for (int b = 0; b < q; ++b) {
        HD& e = h[static_cast<size_t>(a)][static_cast<size_t>(b)];
        e += g[static_cast<size_t>(a)] * g[static_cast<size_t>(b)] * w;
        if (!foce) e += 0.5 * dv[static_cast<size_t>(a)] * dv[static_cast<size_t>(b)] * w * w;
      }
    }
  }
  HD log_det_h;
  if (!LogDet<HD>(h, &log_det_h)) {
    *why = "H is not positive definite at the mode";
    return false;
  }
  const HD big_l = l + log_det_omega + log_det_h;
  // dOFV/dx = ∂L/∂x − (∂L/∂η)ᵀ (∇²_ηη l)⁻¹ ∇²_ηx l
  const Eigen::MatrixXd lee = l.hessian().topLeftCorner(q, q), lex = l.hessian().topRightCorner(q, m);
  Eigen::LLT<Eigen::MatrixXd> llt(lee);
  if (llt.info() != Eigen::Success) {
    *why = "the Hessian of the conditional objective is not positive definite at the mode";
    return false;
  }
  const Eigen::VectorXd deta_weights = llt.solve(Eigen::VectorXd(big_l.gradient().head(q)));
  *gradient = big_l.gradient().tail(m) - lex.transpose() * deta_weights;
  return gradient->allFinite();
}

}  // namespace

bool SubjectOuterGradient(const SubjectModel& s, const PopulationPoint& p, const Packing& packing,
                          const Eigen::VectorXd& x, const SubjectMode& mode, Eigen::VectorXd* gradient,
                          std::string* why) {
  // The scalar's derivatives over z = (η, x) live on the stack up to 16 variables (2 η and 6
  // population parameters make 8), on the heap beyond.
  if (mode.eta.size() + x.size() <= 16) return GradientOn<HyperDualT<16>>(s, p, packing, x, mode, gradient, why);
  return GradientOn<HyperDualT<Eigen::Dynamic>>(s, p, packing, x, mode, gradient, why);
}

}  // namespace internal
}  // namespace pk
