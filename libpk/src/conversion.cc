#include "pk/conversion.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>

#include <Eigen/Eigenvalues>
#include <Eigen/LU>

#include "pk/linear_model.h"

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

// {CL, V1[, Q2, V2[, Q3, V3]]} -> append k10[, k12, k21[, k13, k31]].
void AppendMicroConstants(std::vector<double>* p) {
  const std::vector<double> q = *p;
  p->push_back(q[0] / q[1]);
  for (size_t i = 2; i + 1 < q.size(); i += 2) {
    p->push_back(q[i] / q[1]);
    p->push_back(q[i] / q[i + 1]);
  }
}

// Rates within 1e-3 of each other (relative) make amplitudes of opposite sign that nearly cancel: the response
// is close to t·e^{−λt} there, and the pair is not determined apart. Says so in the message of an exponents
// reading whose first n parameters are LAMBDA1..n.
void NoteCoincidence(int n, TransferFunctionReading* r) {
  if (!r->ok) return;
  for (int i = 0; i + 1 < n; ++i) {
    const double a = r->parameters[i].value, b = r->parameters[i + 1].value;
    const double gap = std::fabs(a - b) / std::max(std::fabs(a), std::fabs(b));
    if (gap <= 1e-3) {
      char buf[200];
      std::snprintf(buf, sizeof buf,
                    "%s and %s nearly coincide (%.1e apart, relative): their amplitudes cancel, and the "
                    "response there is close to t·e^{-λt}",
                    r->parameters[i].name.c_str(), r->parameters[i + 1].name.c_str(), gap);
      r->message = buf;
      return;
    }
  }
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

bool ModelToExponentials(const Model& model, const Eigen::VectorXd& theta, Exponentials* e, std::string* why) {
  const auto* linear = dynamic_cast<const LinearModel*>(&model);
  if (linear == nullptr) {
    *why = "only linear models have a sum-of-exponentials response";
    return false;
  }
  if (!linear->output_offset_terms(model.central_compartment()).empty()) {
    *why = "the central output has a baseline (an offset), which a sum of exponentials does not have";
    return false;
  }
  const Eigen::MatrixXd a = linear->SystemMatrix<double>(theta);
  const Eigen::RowVectorXd c = linear->OutputRow<double>(model.central_compartment(), theta);
  const Eigen::EigenSolver<Eigen::MatrixXd> es(a);
  if (es.info() != Eigen::Success || es.eigenvalues().imag().cwiseAbs().maxCoeff() > 1e-10 * a.norm()) {
    *why = "A(θ) has complex eigenvalues";
    return false;
  }
  const Eigen::MatrixXd v = es.eigenvectors().real();
  const Eigen::FullPivLU<Eigen::MatrixXd> lu(v);
  // Nearly parallel eigenvectors (rates that coincide to about 1e-10, e.g. KA = CL/V) give amplitudes of
  // opposite sign that cancel to nothing but rounding: the response is t·e^{−λt} there, not a sum of exponentials.
  if (!lu.isInvertible() || lu.rcond() < 1e-10) {
    *why = "A(θ) is defective (coincident rates)";
    return false;
  }
  const Eigen::VectorXd w_dose = lu.inverse().col(model.default_dose_compartment() - 1);
  const Eigen::RowVectorXd cv = c * v;
  e->rate.clear();
  e->amplitude.clear();
  // c e^{At} e_dose = Σ_i (cV)_i (V⁻¹ e_dose)_i e^{λ_i t}; modes the output never sees are dropped.
  std::vector<std::pair<double, double>> modes;
  for (int i = 0; i < a.rows(); ++i) {
    const double amp = cv(i) * w_dose(i);
    if (std::fabs(amp) > 1e-14 * std::max(1.0, cv.cwiseAbs().maxCoeff() * w_dose.cwiseAbs().maxCoeff())) {
      modes.emplace_back(-es.eigenvalues()(i).real(), amp);
    }
  }
  std::sort(modes.begin(), modes.end(), [](const auto& x, const auto& y) { return x.first > y.first; });
  for (const auto& m : modes) {
    e->rate.push_back(m.first);
    e->amplitude.push_back(m.second);
  }
  return true;
}

namespace {

// The exponents' names: LAMBDA1, LAMBDA2, ... fastest first; behind a depot, the absorption rate (the
// exponent closest to the depot's exit rate) is LAMBDA_ABS and the disposition rates are numbered without it.
std::vector<std::string> ExponentNames(const Model& model, const Eigen::VectorXd& theta, const Exponentials& e) {
  const int n = static_cast<int>(e.rate.size());
  int absorption = -1;
  // Behind a depot (the dose compartment, not the central one, with nothing flowing into it) the
  // absorption rate is the depot's exit rate −A(d, d): KA in the catalogue, whatever a model file
  // calls it.
  double rate = NAN;
  const auto* linear = dynamic_cast<const LinearModel*>(&model);
  const int d = model.default_dose_compartment() - 1;
  if (linear != nullptr && d != model.central_compartment() - 1) {
    const Eigen::MatrixXd a = linear->SystemMatrix<double>(theta.head(model.num_parameters()));
    bool inflow = false;
    for (int j = 0; j < a.cols(); ++j) inflow = inflow || (j != d && a(d, j) != 0);
    if (!inflow && a(d, d) < 0) rate = -a(d, d);
  }
  if (!std::isnan(rate)) {
    double best = INFINITY;
    for (int i = 0; i < n; ++i) {
      const double gap = std::fabs(e.rate[i] - rate);
      if (gap < best) {
        best = gap;
        absorption = i;
      }
    }
  }
  std::vector<std::string> names;
  for (const char* prefix : {"LAMBDA", "THALF", "AMP"}) {
    for (int i = 0, k = 1; i < n; ++i) {
      names.push_back(std::string(prefix) + (i == absorption ? "_ABS" : std::to_string(k++)));
    }
  }
  return names;
}

}  // namespace

TransferFunctionReading ModelExponents(const Model& model, const Eigen::VectorXd& theta,
                                       const Eigen::MatrixXd& covariance) {
  TransferFunctionReading out;
  out.reading = "exponents";
  Exponentials e;
  if (!ModelToExponentials(model, theta, &e, &out.message)) return out;
  const int n = static_cast<int>(e.rate.size());
  Propagate(
      [&model](const Eigen::VectorXd& t, std::vector<double>* v, std::string* why) {
        Exponentials x;
        if (!ModelToExponentials(model, t, &x, why)) return false;
        v->assign(x.rate.begin(), x.rate.end());
        for (double r : x.rate) v->push_back(std::log(2.0) / r);
        v->insert(v->end(), x.amplitude.begin(), x.amplitude.end());
        return true;
      },
      ExponentNames(model, theta, e), theta, covariance, &out);
  NoteCoincidence(n, &out);
  return out;
}

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
  NoteCoincidence(n, &out[0]);

  // Clearances and volumes, then the micro-constants they imply.
  static const std::vector<std::vector<std::string>> kMammillary = {
      {"CL", "V", "K10"},
      {"CL", "V1", "Q", "V2", "K10", "K12", "K21"},
      {"CL", "V1", "Q2", "V2", "Q3", "V3", "K10", "K12", "K21", "K13", "K31"}};
  // Behind a depot (compartment 1) NONMEM's TRANS4 numbers the disposition compartments from 2.
  static const std::vector<std::vector<std::string>> kOralMammillary = {
      {"KA", "CL", "V", "K20"},
      {"KA", "CL", "V2", "Q", "V3", "K20", "K23", "K32"},
      {"KA", "CL", "V2", "Q3", "V3", "Q4", "V4", "K20", "K23", "K32", "K24", "K42"}};
  if (n >= 1 && n <= 3) {
    Propagate(
        [](const Eigen::VectorXd& c, std::vector<double>* v, std::string* why) {
          Exponentials e;
          if (!Exponents(c, &e, why) || !ExponentialsToMammillary(e, v, why)) return false;
          AppendMicroConstants(v);
          return true;
        },
        kMammillary[n - 1], coefficients, covariance, &out[1]);
  } else {
    out[1].message = "the IV reading covers 1 to 3 compartments";
  }
  if (n >= 2 && n <= 4) {
    const std::vector<std::string>& oral_names = kOralMammillary[n - 2];
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
          AppendMicroConstants(&p);
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

bool ExponentialsToMammillary(const Exponentials& e, std::vector<double>* p, std::string* why) {
  const int m = static_cast<int>(e.rate.size());
  auto fail = [&](const std::string& w) {
    if (why) *why = w;
    return false;
  };
  double b0 = 0;
  for (double a : e.amplitude) b0 += a;
  if (!(b0 > 0)) return fail("the amplitudes do not sum to a positive concentration");
  const double v1 = 1 / b0;
  p->clear();
  if (m == 1) {
    *p = {e.rate[0] * v1, v1};
    return true;
  }
  if (m == 2) {
    const double a1 = e.amplitude[0], a2 = e.amplitude[1], l1 = e.rate[0], l2 = e.rate[1];
    const double k21 = (a1 * l2 + a2 * l1) / (a1 + a2);
    const double k10 = l1 * l2 / k21;
    const double k12 = l1 + l2 - k21 - k10;
    if (!(k21 > 0 && k10 > 0 && k12 > 0)) return fail("the exponentials give a negative micro-constant");
    *p = {k10 * v1, v1, k12 * v1, k12 * v1 / k21};
    return true;
  }
  if (m == 3) {
    // A(s) = Π(s + λ_i) = s³ + a1 s² + a2 s + a3; B(s) = Σ a_i Π_{j≠i}(s + λ_j) = b0 s² + b1 s + b2.
    const double l1 = e.rate[0], l2 = e.rate[1], l3 = e.rate[2];
    const double a1 = l1 + l2 + l3, a2 = l1 * l2 + l1 * l3 + l2 * l3, a3 = l1 * l2 * l3;
    double b1 = 0, b2 = 0;
    for (int i = 0; i < 3; ++i) {
      const double lj = e.rate[(i + 1) % 3], lk = e.rate[(i + 2) % 3];
      b1 += e.amplitude[i] * (lj + lk);
      b2 += e.amplitude[i] * lj * lk;
    }
    // B(s)/b0 = (s + k21)(s + k31).
    const double sum = b1 / b0, prod = b2 / b0, disc = sum * sum - 4 * prod;
    if (!(disc >= 0) || !(prod > 0)) return fail("the peripheral rates are complex (no mammillary model fits)");
    const double k21 = (sum + std::sqrt(disc)) / 2, k31 = (sum - std::sqrt(disc)) / 2;
    if (!(k31 > 0)) return fail("a peripheral rate is not positive");
    const double k10 = a3 / (k21 * k31);
    const double s1 = a1 - k10 - k21 - k31;
    const double s2 = a2 - k10 * (k21 + k31) - k21 * k31;
    if (std::fabs(k21 - k31) < 1e-12 * k21) return fail("the peripheral rates coincide: the labelling is not identifiable");
    // k12 k31 + k13 k21 = s2, k12 + k13 = s1.
    const double k12 = (s2 - s1 * k21) / (k31 - k21), k13 = s1 - k12;
    if (!(k10 > 0 && k12 > 0 && k13 > 0)) return fail("the exponentials give a negative micro-constant");
    *p = {k10 * v1, v1, k12 * v1, k12 * v1 / k21, k13 * v1, k13 * v1 / k31};
    return true;
  }
  return fail("only 1, 2 or 3 exponentials are supported");
}

void ExponentialsToTransferFunction(const Exponentials& e, std::vector<double>* coefficients) {
  const int n = static_cast<int>(e.rate.size());
  // Polynomial products, highest power first: {1} · (s + λ).
  auto product = [&](int skip) {
    std::vector<double> p{1.0};
    for (int i = 0; i < n; ++i) {
      if (i == skip) continue;
      std::vector<double> q(p.size() + 1, 0.0);
      for (size_t k = 0; k < p.size(); ++k) {
        q[k] += p[k];
        q[k + 1] += p[k] * e.rate[i];
      }
      p = q;
    }
    return p;
  };
  const std::vector<double> a = product(-1);  // size n+1, a[0] = 1
  std::vector<double> b(n, 0.0);
  for (int i = 0; i < n; ++i) {
    const std::vector<double> p = product(i);  // size n
    for (int k = 0; k < n; ++k) b[k] += e.amplitude[i] * p[k];
  }
  coefficients->assign(a.begin() + 1, a.end());
  coefficients->insert(coefficients->end(), b.begin(), b.end());
}

}  // namespace pk
