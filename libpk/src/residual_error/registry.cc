// The residual-error models by name: adding one is a file in this folder and a line here.
#include "residual_error/registry.h"

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
  return names.count(name) > 0;
}

}  // namespace pk
