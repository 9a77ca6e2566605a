#include "objective/sample_loss.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "censoring.h"
#include "pk/objective.h"
#include "pk/output.h"

namespace pk {
namespace internal {
namespace {

constexpr double kInfinity = std::numeric_limits<double>::infinity();

bool Fail(std::string* why, const std::string& text) {
  *why = text;
  return false;
}

std::string At(const SampleSet& samples, int k) { return FormatNumber((*samples.times)[static_cast<size_t>(k)]); }

// Beal's M3 for censored sample k: the probability that its value lies beyond its limit DV,
// ℓ_k = −log Φ(z), z = s(T(DV) − μ)/√v. With h = φ(z)/Φ(z): ∂ℓ/∂ŷ = −h ∂z/∂ŷ,
// ∂z/∂ŷ = −(s/√v) ∂μ/∂ŷ − z/(2v) ∂v/∂ŷ, and ∂ℓ/∂v = h z/(2v).
bool CensoredTerm(const SampleSet& samples, int k, int s, double y, double mu, bool log_scale, double yhat,
                  SampleLoss* out, Eigen::VectorXd* dl_dy, std::string* why) {
  const double v = out->v(k);
  const double beyond = s * (y - mu);
  if (log_scale && !(yhat > 0)) {  // CENS=1 with log ŷ = −∞: certainly below
    out->z(k) = kInfinity;
    out->dmu_dy(k) = 0;
    (*dl_dy)(k) = 0;
    out->dl_dv(k) = 0;
    return true;
  }
  if (!(v > 0)) {
    if (beyond > 0) {  // certainly beyond: probability 1, no information
      out->z(k) = kInfinity;
      (*dl_dy)(k) = 0;
      out->dl_dv(k) = 0;
      return true;
    }
    return Fail(why, "the censored sample at TIME " + At(samples, k) + " (CENS=" + std::to_string(s) +
                         ") has probability 0: its prediction " + FormatNumber(yhat) + " is not beyond its limit " +
                         FormatNumber((*samples.y)(k)) + " and its σ is 0");
  }
  const double z = beyond / std::sqrt(v);
  out->z(k) = z;
  double log_cdf, h;
  LogNormalCdf(z, &log_cdf, &h);
  out->value -= log_cdf;
  (*dl_dy)(k) = h == 0 ? 0.0 : -h * (-s / std::sqrt(v) * out->dmu_dy(k) - z / (2 * v) * out->dv_dy(k));
  out->dl_dv(k) = h == 0 ? 0.0 : h * z / (2 * v);
  return true;
}

// A prediction at or below kZeroPredictionLevel of the subject's largest is zero to rounding: the
// modal form gives about 1e-15 for a compartment the drug has not reached yet (a sample at the time
// of an oral dose). When the variance vanishes with the prediction (a proportional error alone), its
// log-variance term would be rounding noise of about −70 that optimisers chase, so such a sample is
// refused. Returns the level, or -1 when the variance does not vanish at ŷ = 0.
double ZeroLevel(const ResidualErrorModel& error, const double* sigma, double largest, bool* relative) {
  const size_t ns = error.sigma_names().size();
  std::vector<double> dv_dsigma(ns);
  double v0, dv0;
  error.Variance(0.0, sigma, &v0, &dv0, dv_dsigma.data());
  bool vanishes = v0 == 0;
  for (double d : dv_dsigma) vanishes = vanishes && d == 0;
  *relative = false;
  for (size_t j = 0; vanishes && j < ns; ++j) *relative = *relative || sigma[j] > 0;
  return vanishes ? kZeroPredictionLevel * largest : -1.0;
}

// Each output's error model (one for all, or each its own: ResidualErrorModel::ForOutput), with
// where its σ start and its zero level over the output's own predictions.
struct OutputError {
  const ResidualErrorModel* model = nullptr;
  int first = 0;
  double zero_level = -1;
  bool relative = false;
};

std::vector<OutputError> OutputErrors(const ResidualErrorModel& error, const SampleSet& samples, const double* sigma,
                                      const Eigen::VectorXd& yhat) {
  const auto output = [&](Eigen::Index k) { return samples.outputs ? (*samples.outputs)(k) : 1; };
  int outputs = 1;
  for (Eigen::Index k = 0; k < yhat.size(); ++k) outputs = std::max(outputs, output(k));
  std::vector<double> largest(static_cast<size_t>(outputs), 0.0);
  for (Eigen::Index k = 0; k < yhat.size(); ++k) {
    double& l = largest[static_cast<size_t>(output(k) - 1)];
    l = std::max(l, std::fabs(yhat(k)));
  }
  std::vector<OutputError> out(static_cast<size_t>(outputs));
  for (int o = 1; o <= outputs; ++o) {
    OutputError& e = out[static_cast<size_t>(o - 1)];
    e.model = &error.ForOutput(o, &e.first);
    e.zero_level = ZeroLevel(*e.model, sigma + e.first, largest[static_cast<size_t>(o - 1)], &e.relative);
  }
  return out;
}

bool Likelihood(const ResidualErrorModel& error, const SampleSet& samples, const double* sigma,
                const Eigen::VectorXd& yhat, SampleLoss* out, Eigen::VectorXd* dl_dy, std::string* why) {
  const Eigen::Index n = yhat.size();
  const int ns = error.num_sigma();
  const Eigen::VectorXd& obs = *samples.y;
  const Eigen::VectorXi& cens = *samples.cens;
  out->r = obs - yhat;
  out->v.resize(n);
  out->dv_dy.resize(n);
  out->dv_dsigma.setZero(n, ns);
  out->dl_dv.resize(n);
  out->dmu_dy.setOnes(n);
  out->z.setZero(n);
  const std::vector<OutputError> errors = OutputErrors(error, samples, sigma, yhat);
  std::vector<double> dv_dsigma(static_cast<size_t>(ns));
  for (Eigen::Index k = 0; k < n; ++k) {
    const OutputError& e = errors[static_cast<size_t>(samples.outputs ? (*samples.outputs)(k) - 1 : 0)];
    const bool log_scale = e.model->log_transformed();
    double v, dv;
    e.model->Variance(yhat(k), sigma + e.first, &v, &dv, dv_dsigma.data());
    out->v(k) = v;
    out->dv_dy(k) = dv;
    for (int q = 0; q < e.model->num_sigma(); ++q) {
      out->dv_dsigma(k, e.first + q) = dv_dsigma[static_cast<size_t>(q)];
    }
    // The compared quantities: y and μ = ŷ, or log y and μ = log ŷ.
    double y = obs(k), mu = yhat(k);
    if (log_scale) {
      y = std::log(obs(k));
      mu = std::log(yhat(k));
      out->dmu_dy(k) = 1 / yhat(k);
      if (!(yhat(k) > 0) && !(cens(k) == 1)) {  // a sample censored below its limit is certain there
        return Fail(why, "the prediction of the sample at TIME " + At(samples, static_cast<int>(k)) + " is " +
                             FormatNumber(yhat(k)) + ": the " + e.model->name() +
                             " error model needs a positive prediction (give the sample MDV=1, or CENS=1 if it "
                             "lies below a limit)");
      }
    }
    if (const int s = cens(k)) {
      if (!CensoredTerm(samples, static_cast<int>(k), s, y, mu, log_scale, yhat(k), out, dl_dy, why)) return false;
      continue;
    }
    if (!(v > 0) || std::fabs(yhat(k)) <= e.zero_level) {
      std::ostringstream os;
      os << "the residual variance of the sample at TIME " << At(samples, static_cast<int>(k)) << " is zero: "
         << (e.relative ? "its prediction is 0 and the " + std::string(e.model->name()) +
                              " error's variance vanishes with it (give it MDV=1, or use a combined error with "
                              "SIGMA_ADD fixed)"
                        : std::string("a σ of 0"));
      return Fail(why, os.str());
    }
    // The exponential error's density of y is that of log y over y: the log y term keeps V
    // comparable with the other error models' (it does not depend on θ).
    double& r = out->r(k);
    if (log_scale) {
      r = y - mu;
      out->value += y;
    }
    out->value += 0.5 * (std::log(2 * M_PI * v) + r * r / v);
    out->dl_dv(k) = 0.5 * (1 / v - r * r / (v * v));
    (*dl_dy)(k) = -r / v * out->dmu_dy(k) + out->dl_dv(k) * dv;
  }
  return true;
}

}  // namespace

bool ComputeSampleLoss(const ResidualErrorModel& error, const SampleSet& samples, const double* sigma,
                       const Eigen::VectorXd& yhat, bool keep_residuals, SampleLoss* out, Eigen::VectorXd* dl_dy,
                       std::string* why) {
  out->value = 0;
  dl_dy->resize(yhat.size());
  if (error.is_likelihood()) return Likelihood(error, samples, sigma, yhat, out, dl_dy, why);
  const Eigen::VectorXd& y = *samples.y;
  const Eigen::VectorXd& w = *samples.w;
  if (keep_residuals) out->r = y - yhat;
  out->value = 0.5 * (w.array() * (y - yhat).array().square()).sum();
  *dl_dy = -(w.array() * (y - yhat).array()).matrix();
  return true;
}

Eigen::MatrixXd SampleInformation(const SampleLoss& loss, const Eigen::VectorXi& cens, const Eigen::MatrixXd& jy,
                                  const std::vector<int>& sigma_of) {
  const Eigen::Index n = jy.rows(), p = jy.cols();
  Eigen::MatrixXd info = Eigen::MatrixXd::Zero(p, p);
  for (Eigen::Index k = 0; k < n; ++k) {
    // ∇v = ∂v/∂ŷ ∇ŷ + its σ terms; ∂v/∂ŷ = 0 on log scale, where jy holds ∇μ = ∇ŷ/ŷ.
    const double v = loss.v(k);
    Eigen::VectorXd gs = loss.dv_dy(k) * jy.row(k).transpose();
    for (Eigen::Index j = 0; j < p; ++j) {
      if (sigma_of[static_cast<size_t>(j)] >= 0) gs(j) += loss.dv_dsigma(k, sigma_of[static_cast<size_t>(j)]);
    }
    if (cens(k) == 0) {
      info += jy.row(k).transpose() * jy.row(k) / v + gs * gs.transpose() / (2 * v * v);
    } else if (v > 0) {
      // The Tobit model's information in (μ, σ) = (μ, √v), ∇σ = ∇v/(2σ) (internal::CensoredInformation).
      double i_mm, i_ms, i_ss;
      CensoredInformation(loss.z(k), cens(k), &i_mm, &i_ms, &i_ss);
      const Eigen::VectorXd gm_k = jy.row(k).transpose();
      const Eigen::VectorXd gsd = gs / (2 * std::sqrt(v));
      info += (i_mm * gm_k * gm_k.transpose() + i_ms * (gm_k * gsd.transpose() + gsd * gm_k.transpose()) +
               i_ss * gsd * gsd.transpose()) /
              v;
    }
  }
  return info;
}

}  // namespace internal
}  // namespace pk
