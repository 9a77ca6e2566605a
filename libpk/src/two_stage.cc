// Stage two of the two-stage population methods (pk/two_stage.h; derivation
// in docs/fitting.md, "Population estimates in two stages").
#include "pk/two_stage.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>

#include "estimation/nlopt.h"
#include "internal_text.h"
#include "pk/error.h"
#include "pk/objective.h"
#include "pk/output.h"

namespace pk {

namespace {

using internal::Cell;
using internal::Num;

using internal::kNaN;
constexpr double kLog2Pi = 1.8378770664093454836;

// μ and Ω as one point of the EM map.
struct Point {
  Eigen::VectorXd mu;
  Eigen::MatrixXd omega;
};

class Gts {
 public:
  Gts(std::vector<Eigen::VectorXd> phi, std::vector<Eigen::MatrixXd> c, bool diagonal)
      : phi_(std::move(phi)), c_(std::move(c)), diagonal_(diagonal), p_(static_cast<int>(phi_[0].size())) {}

  int p() const { return p_; }
  int n() const { return static_cast<int>(phi_.size()); }

  // ℓ(μ, Ω) of pk/two_stage.h; −∞ when some Ω + C_i is not positive definite.
  // With g_mu and g also its gradient: ∂ℓ/∂μ = Σ_i Σ_i⁻¹r_i and
  // G = ∂ℓ/∂Ω = ½ Σ_i (Σ_i⁻¹r_i r_iᵀΣ_i⁻¹ − Σ_i⁻¹), Σ_i = Ω + C_i, r_i = φ̂_i − μ.
  double LogLikelihood(const Point& x, Eigen::VectorXd* g_mu = nullptr, Eigen::MatrixXd* g = nullptr) const {
    if (g_mu) *g_mu = Eigen::VectorXd::Zero(p_);
    if (g) *g = Eigen::MatrixXd::Zero(p_, p_);
    double l = 0;
    for (int i = 0; i < n(); ++i) {
      const Eigen::LLT<Eigen::MatrixXd> llt(x.omega + c_[i]);
      if (llt.info() != Eigen::Success) return -std::numeric_limits<double>::infinity();
      const Eigen::VectorXd r = phi_[i] - x.mu;
      const Eigen::VectorXd sr = llt.solve(r);
      l -= 0.5 * (2 * llt.matrixLLT().diagonal().array().log().sum() + r.dot(sr) + p_ * kLog2Pi);
      if (g_mu) *g_mu += sr;
      if (g) *g += 0.5 * (sr * sr.transpose() - llt.solve(Eigen::MatrixXd::Identity(p_, p_)));
    }
    return l;
  }

  // The E-step: the shrunken estimates φ*_i = μ + K_i(φ̂_i − μ) with
  // K_i = Ω(Ω + C_i)⁻¹, and Σ_i P_i with P_i = (I − K_i)Ω their covariances.
  // False when some Ω + C_i is not positive definite.
  bool Shrink(const Point& x, std::vector<Eigen::VectorXd>* star, Eigen::MatrixXd* sum_p) const {
    star->resize(n());
    *sum_p = Eigen::MatrixXd::Zero(p_, p_);
    for (int i = 0; i < n(); ++i) {
      const Eigen::LLT<Eigen::MatrixXd> llt(x.omega + c_[i]);
      if (llt.info() != Eigen::Success) return false;
      const Eigen::MatrixXd k = llt.solve(x.omega).transpose();  // ((Ω + C_i)⁻¹Ω)ᵀ
      (*star)[i] = x.mu + k * (phi_[i] - x.mu);
      *sum_p += x.omega - k * x.omega;
    }
    return true;
  }

  // One EM step: the E-step, then the M-step's μ = mean φ*_i and
  // Ω = mean [P_i + (φ*_i − μ)(φ*_i − μ)ᵀ] (its diagonal for a diagonal Ω).
  bool Step(const Point& x, Point* next) const {
    std::vector<Eigen::VectorXd> star;
    Eigen::MatrixXd s;
    if (!Shrink(x, &star, &s)) return false;
    next->mu = Eigen::VectorXd::Zero(p_);
    for (const Eigen::VectorXd& e : star) next->mu += e / n();
    for (const Eigen::VectorXd& e : star) s += (e - next->mu) * (e - next->mu).transpose();
    s /= n();
    next->omega = 0.5 * (s + s.transpose());
    if (diagonal_) next->omega = Eigen::MatrixXd(next->omega.diagonal().asDiagonal());
    return true;
  }

  // The free entries of Ω (its lower triangle, or its diagonal), which are
  // also those of its Cholesky factor L.
  std::vector<std::pair<int, int>> OmegaEntries() const {
    std::vector<std::pair<int, int>> e;
    for (int j = 0; j < p_; ++j) {
      for (int k = diagonal_ ? j : 0; k <= j; ++k) e.emplace_back(j, k);
    }
    return e;
  }

  // L from v = (μ, the free entries of L).
  Eigen::MatrixXd Factor(const double* v) const {
    const auto entries = OmegaEntries();
    Eigen::MatrixXd l = Eigen::MatrixXd::Zero(p_, p_);
    for (size_t a = 0; a < entries.size(); ++a) l(entries[a].first, entries[a].second) = v[p_ + a];
    return l;
  }

  // v = (μ, the free entries of L) ↦ (μ, Ω = LLᵀ).
  Point FromFactor(const double* v) const {
    const Eigen::MatrixXd l = Factor(v);
    return Point{Eigen::Map<const Eigen::VectorXd>(v, p_), l * l.transpose()};
  }

  // ℓ at v = (μ, L), and its gradient there: ∂ℓ/∂μ, and ∂ℓ/∂L = 2GL.
  double FactorLogLikelihood(const double* v, double* gradient) const {
    if (!gradient) return LogLikelihood(FromFactor(v));
    Eigen::VectorXd g_mu;
    Eigen::MatrixXd g;
    const double value = LogLikelihood(FromFactor(v), &g_mu, &g);
    Eigen::Map<Eigen::VectorXd>(gradient, p_) = g_mu;
    const Eigen::MatrixXd gl = 2 * g * Factor(v);
    const auto entries = OmegaEntries();
    for (size_t a = 0; a < entries.size(); ++a) gradient[p_ + a] = gl(entries[a].first, entries[a].second);
    return value;
  }

  // The expected information about μ, Σ_i Σ_i⁻¹, and about Ω's free entries ω_a,
  // I_ab = ½ Σ_i tr(Σ_i⁻¹ E_a Σ_i⁻¹ E_b) with E_a = ∂Ω/∂ω_a (pk/two_stage.h).
  void Information(const Point& x, Eigen::MatrixXd* info_mu, Eigen::MatrixXd* info_omega) const {
    const auto entries = OmegaEntries();
    const int q = static_cast<int>(entries.size());
    *info_mu = Eigen::MatrixXd::Zero(p_, p_);
    *info_omega = Eigen::MatrixXd::Zero(q, q);
    std::vector<Eigen::MatrixXd> a(q);
    for (int i = 0; i < n(); ++i) {
      const Eigen::MatrixXd s = (x.omega + c_[i]).llt().solve(Eigen::MatrixXd::Identity(p_, p_));
      *info_mu += s;
      for (int e = 0; e < q; ++e) {  // Σ⁻¹E_a: E_a has ones at (j,k) and (k,j)
        const int j = entries[e].first, k = entries[e].second;
        a[e] = Eigen::MatrixXd::Zero(p_, p_);
        a[e].col(k) += s.col(j);
        if (j != k) a[e].col(j) += s.col(k);
      }
      for (int e = 0; e < q; ++e) {
        for (int f = 0; f <= e; ++f) {
          const double t = 0.5 * (a[e].array() * a[f].transpose().array()).sum();
          (*info_omega)(e, f) += t;
          if (f != e) (*info_omega)(f, e) += t;
        }
      }
    }
  }

 private:
  std::vector<Eigen::VectorXd> phi_;
  std::vector<Eigen::MatrixXd> c_;
  bool diagonal_;
  int p_;
};

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

DescriptiveStatistics Describe(const std::string& name, const std::vector<double>& v) {
  DescriptiveStatistics d;
  d.name = name;
  d.n = static_cast<int>(v.size());
  if (v.empty()) return d;
  const bool positive = std::all_of(v.begin(), v.end(), [](double x) { return x > 0; });
  std::vector<double> logs;
  if (positive) {
    for (double x : v) logs.push_back(std::log(x));
  }
  // Mean and SD (divisor n − 1; NaN for one value).
  auto moments = [](const std::vector<double>& x, double* mean, double* sd) {
    double sum = 0, ss = 0;
    for (double e : x) sum += e;
    *mean = sum / x.size();
    for (double e : x) ss += (e - *mean) * (e - *mean);
    *sd = x.size() > 1 ? std::sqrt(ss / (x.size() - 1)) : kNaN;
  };
  moments(v, &d.mean, &d.sd);
  d.cv_pct = d.mean != 0 ? 100 * d.sd / std::fabs(d.mean) : kNaN;
  d.median = Median(v);
  d.min = *std::min_element(v.begin(), v.end());
  d.max = *std::max_element(v.begin(), v.end());
  if (positive) {
    double mean_log = 0, sd_log = 0;
    moments(logs, &mean_log, &sd_log);
    d.geometric_mean = std::exp(mean_log);
    d.geometric_cv_pct = 100 * std::sqrt(std::expm1(sd_log * sd_log));
  }
  return d;
}

bool AllFinite(const Eigen::MatrixXd& m) { return m.size() > 0 && m.allFinite(); }


// EM for a start (kEmSteps iterations: it never decreases ℓ and keeps Ω
// positive definite), then L-BFGS over μ and Ω's Cholesky factor L, in which
// a singular Ω (a variance or a correlation at its bound) is an ordinary
// point, where EM would creep towards it.
constexpr int kEmSteps = 50;
constexpr int kLbfgsRounds = 5;
// |∂ℓ/∂v_k|·scale_k: a move of one scale changes ℓ by less than this.
constexpr double kGradientTolerance = 1e-6;

void Maximise(const Gts& gts, const Eigen::VectorXd& scale, const TwoStageOptions& options, Point* x,
              TwoStageSummary* out) {
  const int p = gts.p();
  int em = 0;
  for (; em < std::min(kEmSteps, options.max_iterations); ++em) {
    Point next;
    if (!gts.Step(*x, &next)) break;
    *x = next;
  }
  const auto entries = gts.OmegaEntries();
  const int dim = p + static_cast<int>(entries.size());
  std::vector<double> v(dim);
  for (int j = 0; j < p; ++j) v[j] = x->mu(j);
  const Eigen::MatrixXd l = x->omega.llt().matrixL();
  for (size_t a = 0; a < entries.size(); ++a) v[p + a] = l(entries[a].first, entries[a].second);
  // NLopt's L-BFGS may stop with a generic failure when its line search can
  // no longer improve ℓ near the optimum; so convergence is judged by the
  // gradient, with each entry in units of the parameter's scale (s_j for μ_j
  // and L_jk), and L-BFGS restarted from its best point while that is large.
  auto scaled_gradient = [&](const std::vector<double>& at) {
    std::vector<double> g(dim);
    gts.FactorLogLikelihood(at.data(), g.data());
    double m = 0;
    for (int j = 0; j < p; ++j) m = std::max(m, std::fabs(g[j]) * scale(j));
    for (size_t a = 0; a < entries.size(); ++a) m = std::max(m, std::fabs(g[p + a]) * scale(entries[a].first));
    return m;
  };
  int evaluations = 0;
  const internal::NloptFunction minus_l = [&](const double* at, double* gradient) {
    ++evaluations;
    const double l = gts.FactorLogLikelihood(at, gradient);
    if (gradient) {
      for (int k = 0; k < dim; ++k) gradient[k] = -gradient[k];
    }
    return std::isfinite(l) ? -l : std::numeric_limits<double>::max();
  };
  std::string result = "FAILURE";
  double best = gts.FactorLogLikelihood(v.data(), nullptr);
  for (int round = 0; round < kLbfgsRounds && em + evaluations < options.max_iterations; ++round) {
    internal::Nlopt opt("LD_LBFGS", dim);
    opt.SetRelativeTolerances(0, options.tolerance);
    opt.SetMaxEvaluations(std::max(1, options.max_iterations - em - evaluations));
    std::vector<double> trial = v;
    result = opt.Minimize(minus_l, &trial).result;
    const double l_trial = gts.FactorLogLikelihood(trial.data(), nullptr);
    if (std::isfinite(l_trial) && l_trial >= best) {
      best = l_trial;
      v = trial;
    }
    out->gts_converged = scaled_gradient(v) <= kGradientTolerance;
    if (out->gts_converged) break;
  }
  out->gts_iterations = em + evaluations;
  if (!out->gts_converged) {
    out->gts_message = std::string("the maximisation stopped short of a stationary point after ") +
                       std::to_string(out->gts_iterations) + " iterations (L-BFGS: " + result + ")";
  }
  *x = gts.FromFactor(v.data());
}

void RunGts(const std::vector<Eigen::VectorXd>& phi, const std::vector<Eigen::MatrixXd>& c,
            const TwoStageOptions& options, TwoStageSummary* out) {
  const bool log_normal = options.distribution == BetweenSubjectModel::kLogNormal;
  const Gts gts(phi, c, options.diagonal_omega);
  const int p = gts.p(), n = gts.n();
  // Start from the STS mean and the estimates' covariance (divisor n) less the
  // mean C_i: its positive part, plus a tenth of mean C_i's diagonal.
  Point x{Eigen::VectorXd::Zero(p), Eigen::MatrixXd::Zero(p, p)};
  Eigen::MatrixXd mean_c = Eigen::MatrixXd::Zero(p, p);
  for (int i = 0; i < n; ++i) {
    x.mu += phi[i] / n;
    mean_c += c[i] / n;
  }
  Eigen::MatrixXd s = Eigen::MatrixXd::Zero(p, p);
  for (int i = 0; i < n; ++i) s += (phi[i] - x.mu) * (phi[i] - x.mu).transpose() / n;
  const Eigen::VectorXd scale = (s.diagonal() + mean_c.diagonal()).cwiseSqrt().cwiseMax(1e-300);
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(s - mean_c);
  x.omega = eig.eigenvectors() * eig.eigenvalues().cwiseMax(0).asDiagonal() * eig.eigenvectors().transpose();
  x.omega.diagonal() += 0.1 * mean_c.diagonal();
  if (options.diagonal_omega) x.omega = Eigen::MatrixXd(x.omega.diagonal().asDiagonal());

  Maximise(gts, scale, options, &x, out);

  out->mu = x.mu;
  out->omega = x.omega;
  out->minus2ll = -2 * gts.LogLikelihood(x);
  Eigen::MatrixXd info_mu, info_omega;
  gts.Information(x, &info_mu, &info_omega);
  out->mu_covariance = info_mu.llt().solve(Eigen::MatrixXd::Identity(p, p));
  out->omega_se = Eigen::MatrixXd::Constant(p, p, kNaN);
  const auto entries = gts.OmegaEntries();
  Eigen::FullPivLU<Eigen::MatrixXd> lu(info_omega);
  if (lu.isInvertible()) {
    const Eigen::MatrixXd cov = lu.inverse();
    for (size_t a = 0; a < entries.size(); ++a) {
      const double v = cov(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(a));
      out->omega_se(entries[a].first, entries[a].second) = out->omega_se(entries[a].second, entries[a].first) =
          v > 0 ? std::sqrt(v) : kNaN;
    }
  }
  out->omega_correlation = Eigen::MatrixXd::Identity(p, p);
  for (int j = 0; j < p; ++j) {
    for (int k = 0; k < j; ++k) {
      const double d = std::sqrt(x.omega(j, j) * x.omega(k, k));
      out->omega_correlation(j, k) = out->omega_correlation(k, j) = d > 0 ? x.omega(j, k) / d : kNaN;
    }
  }
  std::vector<std::string> at_zero;
  for (int j = 0; j < p; ++j) {
    PopulationParameter q;
    q.name = out->parameters[j];
    const double se_mu = std::sqrt(out->mu_covariance(j, j));
    q.typical = log_normal ? std::exp(x.mu(j)) : x.mu(j);
    q.typical_se = log_normal ? q.typical * se_mu : se_mu;
    q.typical_rse_pct = 100 * q.typical_se / std::fabs(q.typical);
    q.omega2 = x.omega(j, j);
    q.omega2_se = out->omega_se(j, j);
    q.omega2_rse_pct = 100 * q.omega2_se / q.omega2;
    q.bsv_cv_pct = log_normal ? 100 * std::sqrt(std::expm1(q.omega2)) : 100 * std::sqrt(q.omega2) / std::fabs(x.mu(j));
    if (q.omega2 < 1e-6 * scale(j) * scale(j)) {  // at its bound: a relative SE means nothing
      at_zero.push_back(q.name);
      q.omega2_rse_pct = kNaN;
      q.omega2_at_bound = true;
    }
    out->population.push_back(q);
  }
  auto note = [&](const std::string& text) {
    if (!out->gts_message.empty()) out->gts_message += "; ";
    out->gts_message += text;
  };
  if (!at_zero.empty()) {
    note("the between-subject variance of " + internal::Join(at_zero, ", ") +
         " is at its bound of 0: the estimates vary no more than their standard errors explain");
  } else if (!options.diagonal_omega && p > 1) {
    const Eigen::VectorXd r = Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(out->omega_correlation).eigenvalues();
    if (r.minCoeff() < 1e-6) {
      note("Ω is singular (the smallest eigenvalue of its correlation matrix is " + Num(std::max(0.0, r.minCoeff()), "%.2g") +
           "): some random effects are perfectly correlated; consider a diagonal Ω");
    }
  }
  std::vector<Eigen::VectorXd> star;
  Eigen::MatrixXd unused;
  gts.Shrink(x, &star, &unused);
  out->shrunken.resize(n, p);
  for (int i = 0; i < n; ++i) {
    out->shrunken.row(i) = log_normal ? Eigen::VectorXd(star[i].array().exp()).transpose() : star[i].transpose();
  }
  out->gts_ok = true;
}

}  // namespace

const char* ToString(BetweenSubjectModel m) {
  return m == BetweenSubjectModel::kLogNormal ? "log-normal" : "normal";
}

BetweenSubjectModel ParseBetweenSubjectModel(const std::string& text) {
  if (text == "lognormal" || text == "log-normal") return BetweenSubjectModel::kLogNormal;
  if (text == "normal") return BetweenSubjectModel::kNormal;
  throw InputError("expected lognormal or normal, got '" + text + "'");
}

bool TwoStageOptions::IsValid(std::string* error) const {
  std::string why;
  if (max_iterations < 1) why = "max_iterations must be at least 1";
  if (!(tolerance > 0) || !std::isfinite(tolerance)) why = "tolerance must be positive and finite";
  if (error) *error = why;
  return why.empty();
}

TwoStageSummary EstimateTwoStage(const std::vector<std::string>& names, const std::vector<double>& ids,
                                 const std::vector<Eigen::VectorXd>& estimates,
                                 const std::vector<Eigen::MatrixXd>& covariances, const TwoStageOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw InputError("two-stage options: " + why);
  const int p = static_cast<int>(names.size());
  if (ids.size() != estimates.size() || ids.size() != covariances.size()) {
    throw InputError("two-stage: IDs, estimates and covariances differ in number");
  }
  TwoStageSummary out;
  out.distribution = options.distribution;
  out.diagonal_omega = options.diagonal_omega;
  out.parameters = names;
  const bool log_normal = options.distribution == BetweenSubjectModel::kLogNormal;
  std::vector<std::vector<double>> columns(p);
  std::vector<Eigen::VectorXd> phi;
  std::vector<Eigen::MatrixXd> c;
  for (size_t i = 0; i < ids.size(); ++i) {
    const Eigen::VectorXd& theta = estimates[i];
    const Eigen::MatrixXd& cov = covariances[i];
    if (theta.size() != p || (cov.size() > 0 && (cov.rows() != p || cov.cols() != p))) {
      throw InputError("two-stage: subject " + FormatNumber(ids[i]) + " has estimates of another size");
    }
    if (!theta.allFinite()) {
      out.excluded.emplace_back(ids[i], "an estimate is not finite");
      continue;
    }
    out.sts_ids.push_back(ids[i]);
    for (int j = 0; j < p; ++j) columns[j].push_back(theta(j));
    if (log_normal && (theta.array() <= 0).any()) {
      int j = 0;
      while (theta(j) > 0) ++j;
      out.excluded.emplace_back(ids[i], "GTS: " + names[j] + " = " + Num(theta(j)) + " is not positive (log-normal model)");
      continue;
    }
    if (!AllFinite(cov)) {
      out.excluded.emplace_back(ids[i], "GTS: no covariance of the estimates");
      continue;
    }
    // C_i on the scale of φ: D⁻¹ Cov D⁻¹ for φ = log θ.
    const Eigen::VectorXd d = log_normal ? Eigen::VectorXd(theta.cwiseInverse()) : Eigen::VectorXd::Ones(p);
    Eigen::MatrixXd ci = d.asDiagonal() * cov * d.asDiagonal();
    ci = 0.5 * (ci + ci.transpose());
    if (ci.llt().info() != Eigen::Success) {
      out.excluded.emplace_back(ids[i], "GTS: the covariance of the estimates is not positive definite");
      continue;
    }
    out.gts_ids.push_back(ids[i]);
    phi.push_back(log_normal ? Eigen::VectorXd(theta.array().log()) : theta);
    c.push_back(ci);
  }
  for (int j = 0; j < p; ++j) out.descriptive.push_back(Describe(names[j], columns[j]));
  if (phi.size() < 2) {
    out.gts_message = "GTS needs at least two subjects with covariances; there " +
                      std::string(phi.size() == 1 ? "is 1" : "are 0");
  } else if (p == 0) {
    out.gts_message = "no structural parameter was estimated";
  } else {
    RunGts(phi, c, options, &out);
  }
  return out;
}

TwoStageSummary EstimateTwoStage(const std::vector<SubjectFit>& fits, const TwoStageOptions& options) {
  std::vector<std::string> names;
  bool have_names = false;
  std::vector<double> ids;
  std::vector<Eigen::VectorXd> estimates;
  std::vector<Eigen::MatrixXd> covariances;
  std::vector<std::pair<double, std::string>> excluded;
  for (const SubjectFit& f : fits) {
    if (!f.ok) {
      excluded.emplace_back(f.id, "not fitted: " + f.error);
      continue;
    }
    std::vector<int> index;  // into summary.estimated
    std::vector<std::string> mine;
    for (size_t k = 0; k < f.summary.estimated.size(); ++k) {
      if (IsResidualErrorName(f.summary.estimated[k])) continue;
      index.push_back(static_cast<int>(k));
      mine.push_back(f.summary.estimated[k]);
    }
    // The parameters are named by the first fit that ran, converged or not,
    // so that a summary over no converged fit still lists them (with N = 0).
    if (!have_names) {
      names = mine;
      have_names = true;
    }
    if (!f.summary.converged()) {
      excluded.emplace_back(f.id, "the fit did not converge (" + f.summary.message + ")");
      continue;
    }
    if (!f.summary.identifiable) {
      excluded.emplace_back(f.id, "not identifiable (" + f.summary.covariance_message + ")");
      continue;
    }
    if (mine != names) {
      excluded.emplace_back(f.id, "estimates other parameters (" + internal::Join(mine, ", ") + ")");
      continue;
    }
    const int p = static_cast<int>(index.size());
    Eigen::VectorXd theta(p);
    for (int j = 0; j < p; ++j) {
      const auto it = std::find_if(f.summary.estimates.begin(), f.summary.estimates.end(),
                                   [&](const ParameterEstimate& e) { return e.name == mine[j]; });
      theta(j) = it != f.summary.estimates.end() ? it->estimate : kNaN;
    }
    Eigen::MatrixXd cov;
    const Eigen::MatrixXd& full = f.summary.covariance;
    if (full.rows() == static_cast<Eigen::Index>(f.summary.estimated.size()) && full.cols() == full.rows()) {
      cov.resize(p, p);
      for (int j = 0; j < p; ++j) {
        for (int k = 0; k < p; ++k) cov(j, k) = full(index[j], index[k]);
      }
    }
    ids.push_back(f.id);
    estimates.push_back(theta);
    covariances.push_back(cov);
  }
  TwoStageSummary out = EstimateTwoStage(names, ids, estimates, covariances, options);
  out.excluded.insert(out.excluded.begin(), excluded.begin(), excluded.end());
  return out;
}

std::string TwoStageSummary::BriefReport() const {
  std::ostringstream out;
  out << "two-stage population estimates (" << ToString(distribution) << "): STS over " << sts_ids.size()
      << " subjects";
  if (gts_ok) {
    out << "; GTS over " << gts_ids.size() << " subjects, " << (diagonal_omega ? "diagonal" : "full") << " Ω, "
        << (gts_converged ? "converged" : "not converged") << " after " << gts_iterations << " iterations, -2LL "
        << Num(minus2ll);
  } else {
    out << "; no GTS";
  }
  if (!gts_message.empty()) out << " (" << gts_message << ")";
  return out.str();
}

std::string TwoStageSummary::FullReport() const {
  std::ostringstream out;
  out << BriefReport() << "\n\n";
  char line[512];
  std::snprintf(line, sizeof line, "  %-10s %4s %11s %11s %7s %11s %8s %11s %11s %11s\n", "STS", "N", "mean", "SD",
                "CV%", "geo. mean", "geo. CV%", "median", "min", "max");
  out << line;
  for (const DescriptiveStatistics& d : descriptive) {
    std::snprintf(line, sizeof line, "  %-10s %4d %s %s %s %s %s %s %s %s\n", d.name.c_str(), d.n,
                  Cell(d.mean, "%.4g", 11).c_str(), Cell(d.sd, "%.3g", 11).c_str(), Cell(d.cv_pct, "%.3g", 7).c_str(),
                  Cell(d.geometric_mean, "%.4g", 11).c_str(), Cell(d.geometric_cv_pct, "%.3g", 8).c_str(),
                  Cell(d.median, "%.4g", 11).c_str(), Cell(d.min, "%.4g", 11).c_str(), Cell(d.max, "%.4g", 11).c_str());
    out << line;
  }
  if (gts_ok) {
    std::snprintf(line, sizeof line, "\n  %-10s %11s %11s %7s %11s %11s %7s %8s\n", "GTS", "typical", "SE", "RSE%",
                  "omega^2", "SE", "RSE%", "BSV CV%");
    out << line;
    // Estimates to 4 significant digits, SE and RSE% to 3; a variance at its bound is 0 (bound).
    for (const PopulationParameter& q : population) {
      char omega2[16] = "  0 (bound)", se[16] = "          –", cv[16] = "       0";
      if (!q.omega2_at_bound) {
        std::snprintf(omega2, sizeof omega2, "%s", Cell(q.omega2, "%.4g", 11).c_str());
        std::snprintf(se, sizeof se, "%s", Cell(q.omega2_se, "%.3g", 11).c_str());
        std::snprintf(cv, sizeof cv, "%s", Cell(q.bsv_cv_pct, "%.3g", 8).c_str());
      }
      std::snprintf(line, sizeof line, "  %-10s %s %s %s %s %s %s %s\n", q.name.c_str(), Cell(q.typical, "%.4g", 11).c_str(),
                    Cell(q.typical_se, "%.3g", 11).c_str(), Cell(q.typical_rse_pct, "%.3g", 7).c_str(), omega2, se,
                    Cell(q.omega2_rse_pct, "%.3g", 7).c_str(), cv);
      out << line;
    }
    if (!diagonal_omega && parameters.size() > 1) {
      out << "\n  correlation of the random effects\n" << internal::LowerTriangle(parameters, omega_correlation, 10);
    }
  }
  for (const auto& e : excluded) out << "  left out: ID " << FormatNumber(e.first) << ": " << e.second << "\n";
  return out.str();
}

}  // namespace pk
