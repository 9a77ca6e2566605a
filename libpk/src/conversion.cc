#include "pk/conversion.h"

#include <algorithm>
#include <cmath>
#include <functional>

#include <Eigen/Eigenvalues>

#include "pk/initial_estimates.h"

namespace pk {
namespace {

// One reading as a function of the coefficients: names, and values or a failure reason.
using ReadingFunction = std::function<bool(const Eigen::VectorXd&, std::vector<double>*, std::string*)>;

// Poles and residues of B(s)/A(s): rates λ (fastest first) and amplitudes.
bool Exponents(const Eigen::VectorXd& c, Exponentials* e, std::string* why) {
  const int n = static_cast<int>(c.size()) / 2;
  Eigen::MatrixXd companion = Eigen::MatrixXd::Zero(n, n);
  for (int i = 0; i < n; ++i) companion(0, i) = -c(i);
  for (int k = 1; k < n; ++k) companion(k, k - 1) = 1;
  const Eigen::EigenSolver<Eigen::MatrixXd> es(companion, false);
  if (es.info() != Eigen::Success) {
    *why = "the roots of A(s) could not be computed";
    return false;
  }
  std::vector<double> rates;
  for (int i = 0; i < n; ++i) {
    const std::complex<double> root = es.eigenvalues()(i);
    if (std::fabs(root.imag()) > 1e-10 * std::max(1.0, std::abs(root))) {
      *why = "A(s) has complex roots: the response oscillates, no compartment model has it";
      return false;
    }
    if (!(root.real() < 0)) {
      *why = "A(s) has a root s >= 0: a rate is not positive";
      return false;
    }
    rates.push_back(-root.real());
  }
  std::sort(rates.begin(), rates.end(), std::greater<double>());
  e->rate = rates;
  e->amplitude.clear();
  for (int i = 0; i < n; ++i) {
    // Residue at s = −λ_i: B(s)/A'(s), with A'(−λ_i) = Π_{j≠i}(λ_j − λ_i).
    const double s = -rates[i];
    double b = 0, denom = 1;
    for (int k = 0; k < n; ++k) b += c(n + k) * std::pow(s, n - 1 - k);
    for (int j = 0; j < n; ++j) {
      if (j != i) denom *= rates[j] - rates[i];
    }
    if (denom == 0) {
      *why = "A(s) has a repeated root";
      return false;
    }
    e->amplitude.push_back(b / denom);
  }
  return true;
}

void Propagate(const ReadingFunction& f, const std::vector<std::string>& names, const Eigen::VectorXd& c,
               const Eigen::MatrixXd& cov, TransferFunctionReading* out) {
  std::vector<double> values;
  if (!f(c, &values, &out->message)) return;
  out->ok = true;
  const int m = static_cast<int>(values.size()), p = static_cast<int>(c.size());
  Eigen::MatrixXd j = Eigen::MatrixXd::Zero(m, p);
  bool have_j = cov.rows() == p;
  for (int k = 0; k < p && have_j; ++k) {
    const double h = 1e-6 * std::max(std::fabs(c(k)), 1e-12);
    Eigen::VectorXd cp = c, cm = c;
    cp(k) += h;
    cm(k) -= h;
    std::vector<double> vp, vm;
    std::string ignored;
    if (!f(cp, &vp, &ignored) || !f(cm, &vm, &ignored) || vp.size() != values.size() || vm.size() != values.size()) {
      have_j = false;
      break;
    }
    for (int i = 0; i < m; ++i) j(i, k) = (vp[i] - vm[i]) / (2 * h);
  }
  Eigen::MatrixXd derived_cov;
  if (have_j) derived_cov = j * cov * j.transpose();
  for (int i = 0; i < m; ++i) {
    DerivedParameter d;
    d.name = names[i];
    d.value = values[i];
    if (have_j && derived_cov(i, i) >= 0) {
      d.se = std::sqrt(derived_cov(i, i));
      d.rse_pct = 100 * d.se / std::fabs(d.value);
    }
    out->parameters.push_back(d);
  }
}

}  // namespace

std::vector<TransferFunctionReading> ConvertTransferFunction(const Eigen::VectorXd& coefficients,
                                                             const Eigen::MatrixXd& covariance) {
  const int n = static_cast<int>(coefficients.size()) / 2;
  std::vector<TransferFunctionReading> out(3);
  out[0].reading = "exponents";
  out[1].reading = "iv";
  out[2].reading = "oral";

  std::vector<std::string> names;
  for (int i = 1; i <= n; ++i) names.push_back("LAMBDA" + std::to_string(i));
  for (int i = 1; i <= n; ++i) names.push_back("THALF" + std::to_string(i));
  for (int i = 1; i <= n; ++i) names.push_back("AMP" + std::to_string(i));
  Propagate(
      [](const Eigen::VectorXd& c, std::vector<double>* v, std::string* why) {
        Exponentials e;
        if (!Exponents(c, &e, why)) return false;
        v->assign(e.rate.begin(), e.rate.end());
        for (double r : e.rate) v->push_back(std::log(2.0) / r);
        v->insert(v->end(), e.amplitude.begin(), e.amplitude.end());
        return true;
      },
      names, coefficients, covariance, &out[0]);

  static const std::vector<std::vector<std::string>> kMammillary = {
      {"CL", "V"}, {"CL", "V1", "Q", "V2"}, {"CL", "V1", "Q2", "V2", "Q3", "V3"}};
  if (n >= 1 && n <= 3) {
    Propagate(
        [](const Eigen::VectorXd& c, std::vector<double>* v, std::string* why) {
          Exponentials e;
          return Exponents(c, &e, why) && ExponentialsToMammillary(e, v, why);
        },
        kMammillary[n - 1], coefficients, covariance, &out[1]);
  } else {
    out[1].message = "the IV reading covers 1 to 3 compartments";
  }
  if (n >= 2 && n <= 4) {
    std::vector<std::string> oral_names{"KA"};
    for (const std::string& s : kMammillary[n - 2]) oral_names.push_back(s);
    Propagate(
        [](const Eigen::VectorXd& c, std::vector<double>* v, std::string* why) {
          Exponentials e;
          if (!Exponents(c, &e, why)) return false;
          // The fastest rate is KA; the others are disposition, with IV-equivalent amplitudes.
          const double ka = e.rate[0];
          Exponentials disposition;
          for (size_t i = 1; i < e.rate.size(); ++i) {
            disposition.rate.push_back(e.rate[i]);
            disposition.amplitude.push_back(e.amplitude[i] * (ka - e.rate[i]) / ka);
          }
          std::vector<double> p;
          if (!ExponentialsToMammillary(disposition, &p, why)) return false;
          v->assign(1, ka);
          v->insert(v->end(), p.begin(), p.end());
          return true;
        },
        oral_names, coefficients, covariance, &out[2]);
  } else {
    out[2].message = "the oral reading needs tf2 to tf4";
  }
  return out;
}

}  // namespace pk
