// Each output its own error model and σ (MakePerOutputError): NONMEM's $ERROR with
// IF (DVID.EQ.2) Y = … EPS(2), the σ of output k named after it.
#include <utility>

#include "internal_text.h"
#include "pk/error.h"
#include "pk/residual_error.h"

namespace pk {
namespace internal {
namespace {

class PerOutput final : public ResidualErrorModel {
 public:
  PerOutput(std::vector<std::shared_ptr<const ResidualErrorModel>> models, const std::vector<std::string>& outputs)
      : models_(std::move(models)) {
    for (size_t k = 0; k < models_.size(); ++k) {
      first_.push_back(static_cast<int>(names_.size()));
      for (const std::string& sigma : models_[k]->sigma_names()) names_.push_back(sigma + "_" + ToUpper(outputs[k]));
    }
  }

  const char* name() const override { return "per-output"; }
  bool log_transformed() const override {
    for (const auto& m : models_) {
      if (m->log_transformed()) return true;
    }
    return false;
  }
  std::vector<std::string> sigma_names() const override { return names_; }
  int num_sigma() const override { return static_cast<int>(names_.size()); }
  double DefaultSigma(int j, const Eigen::VectorXd& observations) const override {
    const size_t k = OutputOfSigma(j);
    return models_[k]->DefaultSigma(j - first_[k], observations);
  }
  bool sigma_in_dv_units(int j) const override {
    const size_t k = OutputOfSigma(j);
    return models_[k]->sigma_in_dv_units(j - first_[k]);
  }
  // Without an output there is no one model: output 1's, with the other σ's derivatives 0.
  void Variance(double yhat, const double* sigma, double* v, double* dv_dyhat, double* dv_dsigma) const override {
    OutputVariance(*this, 1, yhat, sigma, v, dv_dyhat, dv_dsigma);
  }
  double StandardDeviation(double yhat, const double* sigma) const override {
    return models_[0]->StandardDeviation(yhat, sigma);
  }
  const ResidualErrorModel& ForOutput(int output, int* first_sigma) const override {
    if (output < 1 || output > static_cast<int>(models_.size())) {
      throw InputError("output " + std::to_string(output) + " has no error model (the per-output error models cover "
                       "outputs 1 to " + std::to_string(models_.size()) + ")");
    }
    *first_sigma = first_[static_cast<size_t>(output - 1)];
    return *models_[static_cast<size_t>(output - 1)];
  }
  int num_outputs() const override { return static_cast<int>(models_.size()); }

 private:
  size_t OutputOfSigma(int j) const {
    size_t k = 0;
    while (k + 1 < first_.size() && first_[k + 1] <= j) ++k;
    return k;
  }

  std::vector<std::shared_ptr<const ResidualErrorModel>> models_;
  std::vector<int> first_;
  std::vector<std::string> names_;
};

}  // namespace
}  // namespace internal

std::shared_ptr<const ResidualErrorModel> MakePerOutputError(
    std::vector<std::shared_ptr<const ResidualErrorModel>> models, std::vector<std::string> output_names) {
  if (models.empty() || models.size() != output_names.size()) {
    throw InputError("per-output error models: " + std::to_string(models.size()) + " models for " +
                     std::to_string(output_names.size()) + " outputs");
  }
  for (size_t k = 0; k < models.size(); ++k) {
    if (!models[k] || !models[k]->is_likelihood()) {
      throw InputError("per-output error models: output " + output_names[k] +
                       " needs a likelihood (additive, proportional, combined or exponential), not least squares");
    }
  }
  return std::make_shared<internal::PerOutput>(std::move(models), output_names);
}

}  // namespace pk
