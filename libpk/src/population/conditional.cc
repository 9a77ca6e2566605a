// One subject's conditional problem: l(η), the mode η̂ and OFV_i (conditional.h).
#include "population/conditional.h"

#include <algorithm>
#include <cmath>
#include <exception>
#include <thread>

#include <Eigen/Cholesky>

#include "censoring.h"
#include "population/half_hessian_term.h"
#include "pk/error.h"

namespace pk {
namespace internal {
namespace {

constexpr double kNewtonFrom = 1e-4;       // scoring hands over to Newton below this step,
constexpr int kScoringIterations = 20;     // or after this many iterations (scoring can zig-zag slowly)
constexpr double kHessianStep = 1e-3;      // central-difference step in η for ½∇²l
constexpr int kMaxIterations = 200;
constexpr double kMaxStep = 1;          // the largest change of one η in one iteration
constexpr int kBlindSteps = 3;          // full steps below l's resolution, at most, per mode search
// A predicted decrease of l below this many times its noise cannot be resolved by the line search: the
// decrease along a step is about half the predicted one at best, and l is off by up to its noise at
// both ends. (CVODES at rtol 1e-9 on effect_linear_pop: a scoring step predicting 1.1 times the noise
// failed every halving, and a subject's search stopped "without progress".)
constexpr double kResolvable = 4;

bool LogDet(const Eigen::MatrixXd& m, double* out) {
  Eigen::LLT<Eigen::MatrixXd> llt(m);
  if (llt.info() != Eigen::Success) return false;
  *out = 2 * llt.matrixLLT().diagonal().array().log().sum();
  return std::isfinite(*out);
}

// The residual variances at the predictions, and ∂V/∂ŷ.
bool Variances(const SubjectModel& s, const PopulationPoint& p, const Eigen::VectorXd& yhat, Eigen::VectorXd* v,
               Eigen::VectorXd* dv_dyhat, std::string* why) {
  const Eigen::Index n = yhat.size();
  v->resize(n);
  dv_dyhat->resize(n);
  thread_local std::vector<double> dsigma;
  dsigma.resize(static_cast<size_t>(std::max<Eigen::Index>(p.sigma.size(), 1)));
  for (Eigen::Index j = 0; j < n; ++j) {
    OutputVariance(*p.error, s.outputs(j), yhat(j), p.sigma.data(), &(*v)(j), &(*dv_dyhat)(j), dsigma.data());
    if (!((*v)(j) > 0) || !std::isfinite((*v)(j))) {
      *why = "the residual variance of sample " + std::to_string(j + 1) + " is not positive (prediction " +
             std::to_string(yhat(j)) + ")";
      return false;
    }
  }
  return true;
}

// EvaluateConditional's working vectors, kept per thread: it runs thousands of times a fit on a
// few samples each, where allocating them would cost more than the arithmetic.
struct ConditionalScratch {
  Eigen::VectorXd phi, dv_dyhat;
  Eigen::ArrayXd r, w, keep, weight;
  Eigen::MatrixXd scaled;  // rows of ∂f/∂η or ∂V/∂η times a sample's √weight
};

ConditionalScratch& Scratch() {
  thread_local ConditionalScratch scratch;
  return scratch;
}

// M3's terms in ∇l and in the scoring matrix. With z = s(y − f)/√V and the inverse Mills ratio
// m = φ(z)/Φ(z): ∂z/∂η = −s g/√V − z v/(2V), ∇(−2 log Φ(z)) = −2m ∂z/∂η, and since
// d²(−2 log Φ)/dz² = 2(m² + zm) > 0, ½ of its Gauss–Newton part is (m² + zm) ∂z ∂zᵀ.
void AddCensoredDerivatives(const SubjectModel& s, const Eigen::ArrayXd& r, const Eigen::ArrayXd& w, Conditional* c) {
  for (Eigen::Index j = 0; j < r.size(); ++j) {
    if (s.censoring(j) == 0) continue;
    const double sign = s.censoring(j), root_w = std::sqrt(w(j)), z = sign * r(j) * root_w;
    double log_cdf = 0, mills = 0;
    LogNormalCdf(z, &log_cdf, &mills);
    const Eigen::VectorXd dz = -sign * root_w * c->g.row(j).transpose() - 0.5 * z * w(j) * c->dv.row(j).transpose();
    c->gradient -= 2 * mills * dz;
    c->h += (mills * mills + z * mills) * dz * dz.transpose();
  }
}

}  // namespace

PopulationPoint PopulationPoint::Make(const PopulationParameters& pp, const ResidualErrorModel& error,
                                      PopulationMethod m) {
  PopulationPoint p;
  p.theta = pp.theta;
  p.sigma = pp.sigma;
  p.error = &error;
  p.method = m;
  const Eigen::Index q = pp.omega.rows();
  Eigen::LLT<Eigen::MatrixXd> llt(pp.omega);
  if (llt.info() != Eigen::Success) throw InputError("Ω is not positive definite");
  p.omega_inverse = llt.solve(Eigen::MatrixXd::Identity(q, q));
  p.log_det_omega = 2 * llt.matrixLLT().diagonal().array().log().sum();
  return p;
}

Eigen::VectorXd IndividualValues(const SubjectModel& s, const PopulationPoint& p, const Eigen::VectorXd& eta) {
  Eigen::VectorXd v;
  IndividualValues(s, p, eta, &v);
  return v;
}

void IndividualValues(const SubjectModel& s, const PopulationPoint& p, const Eigen::VectorXd& eta,
                      Eigen::VectorXd* out) {
  Eigen::VectorXd& v = *out;
  v = s.base;
  for (size_t k = 0; k < s.theta_index.size(); ++k) v(s.theta_index[k]) = p.theta(static_cast<Eigen::Index>(k));
  for (size_t m = 0; m < s.eta_free.size(); ++m) {
    const double e = eta(static_cast<Eigen::Index>(m));
    v(s.eta_free[m]) = s.eta_log[m] ? v(s.eta_free[m]) * std::exp(e) : e;
  }
}

void DescribeIndividual(const SubjectModel& s, const PopulationPoint& p, const Eigen::VectorXd& eta,
                        PopulationSubject* out) {
  const Eigen::VectorXd phi = IndividualValues(s, p, eta);
  out->parameters.resize(static_cast<Eigen::Index>(s.theta_index.size()));
  for (size_t k = 0; k < s.theta_index.size(); ++k) out->parameters(static_cast<Eigen::Index>(k)) = phi(s.theta_index[k]);
  const ModelDeclarations& declared = s.objective->model().declarations();
  out->definitions.resize(0);
  if (declared.pk_values) out->definitions = declared.pk_values(s.objective->RecordParameters(phi, 0));
}

bool EvaluateConditional(const SubjectModel& s, const PopulationPoint& p, const Eigen::VectorXd& eta,
                         const Eigen::VectorXd* fixed_variance, bool derivatives, Conditional* c, std::string* why) {
  ConditionalScratch& sc = Scratch();
  IndividualValues(s, p, eta, &sc.phi);
  // ∂ŷ/∂φ of the η'd parameters, into c->g (scaled to ∂f/∂η below).
  if (!s.objective->Sensitivities(sc.phi, s.eta_free, &c->yhat, derivatives ? &c->g : nullptr, why)) return false;
  const Eigen::Index n = s.y.size(), q = eta.size();
  // The exponential error (of every output, or of some) compares log ŷ.
  if (s.any_logs && (s.logs && c->yhat.array() <= 0).any()) {
    *why = "a prediction is not positive, and the exponential error takes its logarithm";
    return false;
  }
  if (s.any_logs) {
    c->f = s.logs.select(c->yhat.array().log(), c->yhat.array()).matrix();
  } else {
    c->f = c->yhat;
  }
  if (fixed_variance) {
    c->variance = *fixed_variance;
    sc.dv_dyhat.setZero(n);
  } else if (!Variances(s, p, c->yhat, &c->variance, &sc.dv_dyhat, why)) {
    return false;
  }
  sc.r = (s.y - c->f).array();
  sc.w = c->variance.array().inverse();
  // A censored sample's term is M3's −2 log Φ(z), z = CENS·(y − f)/√V, not the normal one.
  const bool censored = s.censoring.size() == n && (s.censoring.array() != 0).any();
  if (censored) {
    sc.keep = (s.censoring.array() == 0).cast<double>();
  } else {
    sc.keep.setOnes(n);
  }
  const Eigen::ArrayXd &r = sc.r, &w = sc.w, &keep = sc.keep;
  c->l = (keep * (r * r * w + c->variance.array().log())).sum() + eta.dot(p.omega_inverse * eta);
  for (Eigen::Index j = 0; censored && j < n; ++j) {
    if (s.censoring(j) == 0) continue;
    double log_cdf = 0, mills = 0;
    LogNormalCdf(s.censoring(j) * r(j) * std::sqrt(w(j)), &log_cdf, &mills);
    c->l -= 2 * log_cdf;
  }
  if (!std::isfinite(c->l)) {
    *why = "the conditional objective is not finite";
    return false;
  }
  if (!derivatives) return true;
  // ∂ŷ/∂η_m = ∂ŷ/∂φ_m · φ_m for φ_m = θ·e^η, ∂ŷ/∂φ_m for φ_m = η.
  for (Eigen::Index m = 0; m < q; ++m) {
    const auto mm = static_cast<size_t>(m);
    if (s.eta_log[mm]) c->g.col(m) *= sc.phi(s.eta_free[mm]);
  }
  c->dv.noalias() = sc.dv_dyhat.asDiagonal() * c->g;  // from ∂ŷ/∂η
  if (s.any_logs) c->g = s.logs.select(c->yhat.array().inverse(), 1.0).matrix().asDiagonal() * c->g;
  c->gradient.noalias() = 2 * p.omega_inverse * eta;
  sc.weight = keep * r * w;
  c->gradient.noalias() -= 2 * c->g.transpose() * sc.weight.matrix();
  sc.weight = keep * (w - r * r * w * w);
  c->gradient.noalias() += c->dv.transpose() * sc.weight.matrix();
  // H = Ω⁻¹ + Gᵀ diag(w) G + ½ Vᵀ diag(w²) V, each as a product of the scaled rows with themselves.
  c->h = p.omega_inverse;
  sc.weight = (keep * w).sqrt();
  sc.scaled = sc.weight.matrix().asDiagonal() * c->g;
  c->h.noalias() += sc.scaled.transpose() * sc.scaled;
  sc.weight = (0.5 * keep).sqrt() * w;
  sc.scaled = sc.weight.matrix().asDiagonal() * c->dv;
  c->h.noalias() += sc.scaled.transpose() * sc.scaled;
  if (censored) AddCensoredDerivatives(s, r, w, c);
  return true;
}

bool ConditionalHessian(const SubjectModel& s, const PopulationPoint& p, const Eigen::VectorXd& eta,
                        const Eigen::VectorXd* fixed_variance, bool extrapolate, Eigen::MatrixXd* half_hessian,
                        std::string* why) {
  // Central differences of the exact gradient at steps h and h/2, combined by Richardson's
  // extrapolation (4D(h/2) − D(h))/3, whose error is O(h⁴); or at h alone (error O(h²)).
  const Eigen::Index q = eta.size();
  half_hessian->resize(q, q);
  Conditional plus, minus;
  Eigen::VectorXd d[2];
  const int levels = extrapolate ? 2 : 1;
  for (Eigen::Index k = 0; k < q; ++k) {
    for (int level = 0; level < levels; ++level) {
      const double h = kHessianStep / (1 << level);
      Eigen::VectorXd e = eta;
      e(k) += h;
      if (!EvaluateConditional(s, p, e, fixed_variance, true, &plus, why)) return false;
      e(k) = eta(k) - h;
      if (!EvaluateConditional(s, p, e, fixed_variance, true, &minus, why)) return false;
      d[level] = (plus.gradient - minus.gradient) / (4 * h);
    }
    half_hessian->col(k) = extrapolate ? Eigen::VectorXd((4 * d[1] - d[0]) / 3) : d[0];
  }
  *half_hessian = 0.5 * (*half_hessian + half_hessian->transpose()).eval();
  return true;
}

namespace {

// ∂²ŷ_j/∂φ_a∂φ_b for the η'd parameters (positions in s.eta_free), a ≤ b, one vector per pair.
bool EtaSecondDerivatives(const SubjectModel& s, const Eigen::VectorXd& phi, std::vector<Eigen::VectorXd>* second,
                          std::string* why) {
  const auto q = static_cast<int>(s.eta_free.size());
  std::vector<std::pair<int, int>> pairs;
  for (int a = 0; a < q; ++a) {
    for (int b = a; b < q; ++b) pairs.emplace_back(a, b);
  }
  return s.objective->SecondDerivatives(phi, s.eta_free, pairs, second, why);
}

// One sample's derivatives in η: of the prediction (dy, yy), of f = T(ŷ) (g, ff) and of the
// residual variance V (dv, vv; zero when V is held at its η = 0 value, FOCE).
// Kept per thread and reused from sample to sample: the Hessian is formed at every mode of every
// outer evaluation, on a few samples each, where allocating would cost more than the arithmetic.
struct SampleDerivatives {
  Eigen::VectorXd slope;  // φ'_a = ∂φ_a/∂η_a: φ_a for a log-normal η, 1 for a file's η parameter
  Eigen::VectorXd dy, g, dv;
  Eigen::MatrixXd yy, ff, vv;
};

// ∂²ŷ/∂η_a∂η_b = T_ab φ'_a φ'_b + δ_ab ∂ŷ/∂η_a for a log-normal η (φ = θe^η: φ' = φ'' = φ), with
// T from `second` (EtaSecondDerivatives' order); then the chain rule into f and V.
void SampleEtaDerivatives(const SubjectModel& s, const PopulationPoint& p, const std::vector<Eigen::VectorXd>& second,
                          const Conditional& c, bool fixed_variance, Eigen::Index j, SampleDerivatives* d) {
  const auto q = static_cast<Eigen::Index>(s.eta_free.size());
  const double yhat = c.yhat(j);
  const bool logs = s.any_logs && s.logs(j);
  d->g.resize(q);
  d->dy.resize(q);
  d->yy.resize(q, q);
  d->ff.resize(q, q);
  for (Eigen::Index a = 0; a < q; ++a) {
    d->g(a) = c.g(j, a);
    d->dy(a) = logs ? d->g(a) * yhat : d->g(a);
  }
  size_t pair = 0;
  for (Eigen::Index a = 0; a < q; ++a) {
    for (Eigen::Index b = a; b < q; ++b) d->yy(a, b) = d->yy(b, a) = second[pair++](j) * d->slope(a) * d->slope(b);
    if (s.eta_log[static_cast<size_t>(a)]) d->yy(a, a) += d->dy(a);
  }
  for (Eigen::Index a = 0; a < q; ++a) {
    for (Eigen::Index b = 0; b < q; ++b) d->ff(a, b) = logs ? d->yy(a, b) / yhat - d->g(a) * d->g(b) : d->yy(a, b);
  }
  d->dv.setZero(q);
  d->vv.setZero(q, q);
  if (fixed_variance) return;
  // v(ŷ, σ)'s second derivative in ŷ by central differences of its exact first (quadratic in ŷ for
  // libpk's error models, so the difference is exact to rounding; a user's ResidualErrorModel that
  // is not quadratic gets its O(h²) error).
  const auto ns = std::max<Eigen::Index>(p.sigma.size(), 1);
  thread_local Eigen::VectorXd dsigma;
  dsigma.resize(ns);
  double v, vy, vy_plus, vy_minus;
  const double h = 1e-5 * std::max(std::abs(yhat), 1e-8);
  OutputVariance(*p.error, s.outputs(j), yhat, p.sigma.data(), &v, &vy, dsigma.data());
  OutputVariance(*p.error, s.outputs(j), yhat + h, p.sigma.data(), &v, &vy_plus, dsigma.data());
  OutputVariance(*p.error, s.outputs(j), yhat - h, p.sigma.data(), &v, &vy_minus, dsigma.data());
  const double vyy = (vy_plus - vy_minus) / (2 * h);
  for (Eigen::Index a = 0; a < q; ++a) {
    d->dv(a) = vy * d->dy(a);
    for (Eigen::Index b = 0; b < q; ++b) d->vv(a, b) = vyy * d->dy(a) * d->dy(b) + vy * d->yy(a, b);
  }
}

}  // namespace

bool ExactConditionalHessian(const SubjectModel& s, const PopulationPoint& p, const Eigen::VectorXd& eta,
                             const Eigen::VectorXd* fixed_variance, const Conditional& c,
                             Eigen::MatrixXd* half_hessian, std::string* why) {
  const Eigen::VectorXd phi = IndividualValues(s, p, eta);
  std::vector<Eigen::VectorXd> second;
  if (!EtaSecondDerivatives(s, phi, &second, why)) return false;
  const Eigen::Index q = eta.size();
  thread_local SampleDerivatives d;
  d.slope.resize(q);
  for (Eigen::Index a = 0; a < q; ++a) {
    const auto k = static_cast<size_t>(a);
    d.slope(a) = s.eta_log[k] ? phi(s.eta_free[k]) : 1;
  }
  *half_hessian = p.omega_inverse;
  Eigen::MatrixXd& h = *half_hessian;
  for (Eigen::Index j = 0; j < c.yhat.size(); ++j) {
    SampleEtaDerivatives(s, p, second, c, fixed_variance != nullptr, j, &d);
    SampleScale<double> k{s.y(j) - c.f(j), 1 / c.variance(j), 1 / std::sqrt(c.variance(j)), 0.0, 0.0, 0.0};
    if (s.censoring.size() > 0 && s.censoring(j) != 0) {
      k.sign = s.censoring(j);
      k.z = k.sign * k.r * k.root_w;
      double log_cdf = 0;
      LogNormalCdf(k.z, &log_cdf, &k.m);
    }
    for (Eigen::Index a = 0; a < q; ++a) {
      for (Eigen::Index b = 0; b <= a; ++b) {
        const double t = HalfHessianTerm(k, d.g(a), d.g(b), d.dv(a), d.dv(b), d.ff(a, b), d.vv(a, b));
        h(a, b) += t;
        if (b != a) h(b, a) += t;
      }
    }
  }
  if (!h.allFinite()) {
    *why = "the Hessian of the conditional objective is not finite";
    return false;
  }
  return true;
}

namespace {

// Newton's (or scoring's) step from c, with `half_hessian` standing for ½∇²l.
bool Step(const Conditional& c, const Eigen::MatrixXd& half_hessian, Eigen::VectorXd* step) {
  Eigen::LLT<Eigen::MatrixXd> llt(half_hessian);
  if (llt.info() != Eigen::Success) return false;
  *step = -llt.solve(0.5 * c.gradient);
  // Far from the mode (starting values off by orders of magnitude) the quadratic model's step can
  // be enormous; no η moves by more than kMaxStep per iteration.
  const double longest = step->lpNorm<Eigen::Infinity>();
  if (longest > kMaxStep) *step *= kMaxStep / longest;
  return step->allFinite();
}

// Moves η along `step`, halving until l decreases enough (Armijo); false when it never does.
bool LineSearch(const SubjectModel& s, const PopulationPoint& p, const Eigen::VectorXd* fv, const Eigen::VectorXd& step,
                Eigen::VectorXd* eta, Conditional* c) {
  const double slope = c->gradient.dot(step);
  Conditional trial;
  std::string ignored;
  for (double t = 1; t > 1e-10; t *= 0.5) {
    const Eigen::VectorXd e = *eta + t * step;
    if (e == *eta) return false;  // the step is below η's rounding: no move is possible
    if (!EvaluateConditional(s, p, e, fv, true, &trial, &ignored)) continue;
    // Armijo, or a full step whose change of l is rounding (at the mode l cannot resolve the
    // decrease). Fractions of a step are not accepted on rounding: they would creep without end.
    if (trial.l <= c->l + 1e-4 * t * slope || (t == 1 && trial.l <= c->l + 1e-13 * std::abs(c->l))) {
      *eta = e;
      *c = std::move(trial);
      return true;
    }
  }
  return false;
}

// FO: no mode. At η = 0 with V held there, l, ∇l and H = Ω⁻¹ + GᵀV⁻¹G are FOCE's, and by the
// determinant lemma and Woodbury's identity (C = GΩGᵀ + V, r = y − f₀, ∇l = −2GᵀV⁻¹r)
//   log det C + rᵀC⁻¹r = l + log det Ω + log det H − ¼ ∇lᵀH⁻¹∇l.
SubjectMode FirstOrderSubject(const SubjectModel& s, const PopulationPoint& p, Eigen::Index q) {
  SubjectMode mode;
  mode.eta = Eigen::VectorXd::Zero(q);
  Conditional c;
  if (!EvaluateConditional(s, p, mode.eta, nullptr, true, &c, &mode.message)) return mode;
  // V held at its η = 0 value, where it is evaluated: ∇l and H without the interaction's terms (FO
  // refuses censored samples, as FOCE).
  mode.fixed_variance = c.variance;
  const Eigen::ArrayXd w = c.variance.array().inverse();
  c.gradient.noalias() = -2 * c.g.transpose() * (w * (s.y - c.f).array()).matrix();
  c.h = p.omega_inverse;
  c.h.noalias() += c.g.transpose() * w.matrix().asDiagonal() * c.g;
  c.dv.setZero(c.g.rows(), c.g.cols());
  double log_det_h = 0;
  if (!LogDet(c.h, &log_det_h)) {
    mode.message = "the Hessian of the linearised objective is not positive definite";
    return mode;
  }
  mode.ofv = c.l + p.log_det_omega + log_det_h - 0.25 * c.gradient.dot(c.h.llt().solve(c.gradient));
  mode.hessian = c.h;
  mode.at_mode = std::move(c);
  mode.ok = std::isfinite(mode.ofv);
  if (!mode.ok) mode.message = "OFV_i is not finite";
  return mode;
}

}  // namespace

SubjectMode SolveSubject(const SubjectModel& s, const PopulationPoint& p, const Eigen::VectorXd& start) {
  if (p.method == PopulationMethod::kFo) return FirstOrderSubject(s, p, start.size());
  SubjectMode mode;
  const Eigen::Index q = start.size();
  Conditional c;
  if (p.method == PopulationMethod::kFoce) {
    if (!EvaluateConditional(s, p, Eigen::VectorXd::Zero(q), nullptr, false, &c, &mode.message)) return mode;
    mode.fixed_variance = c.variance;
  }
  const Eigen::VectorXd* fv = mode.fixed_variance.size() ? &mode.fixed_variance : nullptr;
  mode.eta = start;
  if (!EvaluateConditional(s, p, mode.eta, fv, true, &c, &mode.message)) {
    mode.eta.setZero();
    if (!start.any() || !EvaluateConditional(s, p, mode.eta, fv, true, &c, &mode.message)) return mode;
  }
  bool newton = false, converged = false;
  // ½∇²l: exact where the route gives second derivatives (tried at every use: a numerical failure
  // at one η says nothing of the next); `exact_here` says half_hessian holds it at the current η.
  const bool exact = p.exact_hessian;
  bool exact_here = false;
  std::string no_exact = exact ? "" : "differences asked for";
  int blind_steps = 0;  // full steps taken where l cannot resolve the decrease (below)
  const Eigen::VectorXd scale = p.omega_inverse.diagonal().cwiseSqrt();
  double previous = 0;  // the last step's length
  Eigen::MatrixXd half_hessian;
  Eigen::VectorXd step;
  for (mode.iterations = 0; mode.iterations < kMaxIterations; ++mode.iterations) {
    if (newton) {
      exact_here = false;
      if (exact && s.newton_exact_hessian) exact_here = ExactConditionalHessian(s, p, mode.eta, fv, c, &half_hessian, &no_exact);
      if (!exact_here && !ConditionalHessian(s, p, mode.eta, fv, false, &half_hessian, &mode.message)) return mode;
    }
    if (!newton || !Step(c, half_hessian, &step)) {
      newton = false;
      if (!Step(c, c.h, &step)) {
        mode.message = "the approximate Hessian of the conditional objective is not positive definite";
        return mode;
      }
    }
    // Measured in η's own scale, 1/√(Ω⁻¹)_mm: a model file's additive η may be far from 1.
    const double length = step.cwiseProduct(scale).lpNorm<Eigen::Infinity>();
    if (length < s.step_tolerance) {
      converged = true;
      break;
    }
    if (!LineSearch(s, p, fv, step, &mode.eta, &c)) {
      const double predicted = -c.gradient.dot(step), noise = s.relative_noise * (double(s.y.size()) + std::abs(c.l));
      const bool unresolvable = predicted < kResolvable * noise;
      if (unresolvable && blind_steps < kBlindSteps) {
        // l cannot resolve a decrease this small, but ∇l, exact, still points to the mode: take the
        // full step when l stays within its noise. Stopping here would leave η̂ off by about
        // √(noise/H), and OFV_i (whose log det H is not stationary at the mode) off by as much.
        ++blind_steps;
        const Eigen::VectorXd next = mode.eta + step;
        Conditional trial;
        std::string ignored;
        if (next != mode.eta && EvaluateConditional(s, p, next, fv, true, &trial, &ignored) &&
            trial.l <= c.l + noise) {
          mode.eta = next;
          exact_here = false;
          c = std::move(trial);
          continue;
        }
      }
      if ((length < std::max(1e-7, 10 * s.step_tolerance) && newton) || unresolvable) {
        converged = true;  // rounding or the solver's error: l cannot decrease further
        break;
      }
      mode.message = "the search for the conditional mode made no progress";
      return mode;
    }
    exact_here = false;  // the line search moved η
    // Scoring contracts fast near the mode when the residuals are small; Newton (5 sensitivity
    // passes an iteration to scoring's 1) takes over where it does not.
    const bool slow = previous > 0 && length > 0.2 * previous;
    if ((length < kNewtonFrom && slow) || mode.iterations + 1 >= kScoringIterations) newton = true;
    previous = length;
  }
  if (!converged) {
    mode.message = "the conditional mode was not found in " + std::to_string(kMaxIterations) + " iterations";
    return mode;
  }
  // Laplace's H enters the OFV: at the mode, exact, or else differences extrapolated.
  if (p.method == PopulationMethod::kLaplace && !exact_here) {
    if (!(exact && ExactConditionalHessian(s, p, mode.eta, fv, c, &half_hessian, &no_exact))) {
      mode.hessian_differenced = no_exact;
      if (!ConditionalHessian(s, p, mode.eta, fv, true, &half_hessian, &mode.message)) return mode;
    }
  }
  double log_det_h = 0;
  const Eigen::MatrixXd& h = p.method == PopulationMethod::kLaplace ? half_hessian : c.h;
  if (!LogDet(h, &log_det_h)) {
    mode.message = "the Hessian at the conditional mode is not positive definite";
    return mode;
  }
  mode.ofv = c.l + p.log_det_omega + log_det_h;
  mode.hessian = h;
  mode.at_mode = std::move(c);
  mode.ok = std::isfinite(mode.ofv);
  if (!mode.ok) mode.message = "OFV_i is not finite";
  return mode;
}

Eigen::MatrixXd EtaCovariance(const SubjectMode& mode) {
  if (!mode.ok || mode.hessian.size() == 0) return Eigen::MatrixXd();
  const Eigen::Index q = mode.hessian.rows();
  return mode.hessian.llt().solve(Eigen::MatrixXd::Identity(q, q));
}

void ParallelFor(int n, int threads, const std::function<void(int)>& work) {
  threads = std::max(1, std::min(threads, n));
  if (threads == 1) {
    for (int i = 0; i < n; ++i) work(i);
    return;
  }
  std::vector<std::exception_ptr> errors(static_cast<size_t>(threads));
  std::vector<std::thread> pool;
  for (int t = 0; t < threads; ++t) {
    pool.emplace_back([&, t] {
      try {
        for (int i = t; i < n; i += threads) work(i);
      } catch (...) {
        errors[static_cast<size_t>(t)] = std::current_exception();
      }
    });
  }
  for (auto& th : pool) th.join();
  for (auto& e : errors) {
    if (e) std::rethrow_exception(e);
  }
}

}  // namespace internal
}  // namespace pk
