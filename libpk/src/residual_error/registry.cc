// The residual-error models by name: adding one is a file in this folder and a line here.
#include "residual_error/registry.h"

#include <algorithm>
#include <cmath>
#include <set>
#include <utility>

#include "internal_text.h"
#include "pk/error.h"

namespace pk {
namespace internal {

// One line each here and in Registry(), for the model in its own file of this folder.
std::shared_ptr<const ResidualErrorModel> MakeLeastSquares();
std::shared_ptr<const ResidualErrorModel> MakeAdditiveError();
std::shared_ptr<const ResidualErrorModel> MakeProportionalError();
std::shared_ptr<const ResidualErrorModel> MakeCombinedError();
std::shared_ptr<const ResidualErrorModel> MakeExponentialError();

namespace {

using Factory = std::shared_ptr<const ResidualErrorModel> (*)();

const std::vector<std::pair<const char*, Factory>>& Registry() {
  static const std::vector<std::pair<const char*, Factory>> registry = {
      {"least-squares", MakeLeastSquares},
      {"additive", MakeAdditiveError},
      {"proportional", MakeProportionalError},
      {"combined", MakeCombinedError},
      {"exponential", MakeExponentialError},
  };
  return registry;
}

}  // namespace

double AdditiveStart(const Eigen::VectorXd& dv) {
  double sum_abs = 0;
  for (Eigen::Index k = 0; k < dv.size(); ++k) sum_abs += std::fabs(dv(k));  // in sample order
  return dv.size() == 0 || sum_abs == 0 ? 1.0 : 0.1 * sum_abs / static_cast<double>(dv.size());
}

}  // namespace internal

double ResidualErrorModel::DefaultSigma(int, const Eigen::VectorXd&) const { return 0.1; }
bool ResidualErrorModel::sigma_in_dv_units(int) const { return false; }
void ResidualErrorModel::Variance(double, const double*, double* v, double* dv_dyhat, double*) const {
  *v = 1;
  *dv_dyhat = 0;
}

const ResidualErrorModel& ResidualErrorModel::ForOutput(int, int* first_sigma) const {
  *first_sigma = 0;
  return *this;
}

void OutputVariance(const ResidualErrorModel& error, int output, double yhat, const double* sigma, double* v,
                    double* dv_dyhat, double* dv_dsigma) {
  int first = 0;
  const ResidualErrorModel& e = error.ForOutput(output, &first);
  if (&e == &error) {
    error.Variance(yhat, sigma, v, dv_dyhat, dv_dsigma);
    return;
  }
  std::fill(dv_dsigma, dv_dsigma + error.num_sigma(), 0.0);
  e.Variance(yhat, sigma + first, v, dv_dyhat, dv_dsigma + first);
}

double OutputStandardDeviation(const ResidualErrorModel& error, int output, double yhat, const double* sigma) {
  int first = 0;
  const ResidualErrorModel& e = error.ForOutput(output, &first);
  return e.StandardDeviation(yhat, sigma + first);
}

std::string DescribeErrorModel(const ResidualErrorModel& error) {
  if (error.num_outputs() == 0) return error.name();
  std::string out;
  for (int k = 1; k <= error.num_outputs(); ++k) {
    int first = 0;
    const ResidualErrorModel& e = error.ForOutput(k, &first);
    std::string sigmas;
    for (size_t j = 0; j < e.sigma_names().size(); ++j) {
      sigmas += (j ? ", " : "") + error.sigma_names()[static_cast<size_t>(first) + j];
    }
    out += (k > 1 ? "; " : "") + std::string(e.name()) + " (" + sigmas + ")";
  }
  return out;
}

std::vector<double> DefaultSigmas(const ResidualErrorModel& error, const Eigen::VectorXd& observations,
                                  const Eigen::VectorXi& outputs) {
  std::vector<double> out(error.sigma_names().size());
  if (error.num_outputs() == 0) {
    for (size_t j = 0; j < out.size(); ++j) out[j] = error.DefaultSigma(static_cast<int>(j), observations);
    return out;
  }
  for (int k = 1; k <= error.num_outputs(); ++k) {
    std::vector<double> own;
    for (Eigen::Index i = 0; i < observations.size(); ++i) {
      if ((outputs.size() ? outputs(i) : 1) == k) own.push_back(observations(i));
    }
    const Eigen::Map<const Eigen::VectorXd> obs(own.data(), static_cast<Eigen::Index>(own.size()));
    int first = 0;
    const ResidualErrorModel& e = error.ForOutput(k, &first);
    for (size_t j = 0; j < e.sigma_names().size(); ++j) out[first + j] = e.DefaultSigma(static_cast<int>(j), obs);
  }
  return out;
}

double ResidualErrorModel::StandardDeviation(double yhat, const double* sigma) const {
  std::vector<double> dv_dsigma(sigma_names().size());
  double v, dv_dyhat;
  Variance(yhat, sigma, &v, &dv_dyhat, dv_dsigma.data());
  return std::sqrt(v);
}

std::shared_ptr<const ResidualErrorModel> MakeResidualError(const std::string& name) {
  std::string key = internal::ToLower(name);
  if (key == "ls" || key == "none") key = "least-squares";
  for (const auto& entry : internal::Registry()) {
    if (key == entry.first) return entry.second();
  }
  throw InputError("expected " + internal::Join(ResidualErrorNames(), ", ") + ", got '" + name + "'");
}

std::vector<std::string> ResidualErrorNames() {
  std::vector<std::string> names;
  for (const auto& entry : internal::Registry()) names.push_back(entry.first);
  return names;
}

std::shared_ptr<const ResidualErrorModel> LeastSquares() {
  static const std::shared_ptr<const ResidualErrorModel> ls = internal::MakeLeastSquares();
  return ls;
}

bool IsResidualErrorName(const std::string& name) {
  static const std::set<std::string> names = [] {
    std::set<std::string> all;
    for (const auto& entry : internal::Registry()) {
      for (const std::string& sigma : entry.second()->sigma_names()) all.insert(sigma);
    }
    return all;
  }();
  if (names.count(name) > 0) return true;
  // A per-output model's σ: a registered σ, then _ and the output's name.
  for (const std::string& sigma : names) {
    if (name.size() > sigma.size() + 1 && name.compare(0, sigma.size() + 1, sigma + "_") == 0) return true;
  }
  return false;
}

}  // namespace pk
