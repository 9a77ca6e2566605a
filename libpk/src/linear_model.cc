#include "pk/linear_model.h"

#include <stdexcept>
#include <utility>

#include "internal_text.h"

namespace pk {

LinearModel::LinearModel(std::string name, std::string description, std::vector<std::string> compartments,
                         std::vector<std::string> parameters, Eigen::VectorXd defaults, int central,
                         int default_dose, std::vector<LinearFlow> flows, std::vector<int> volumes)
    : Model(std::move(name), std::move(description), std::move(compartments), std::move(parameters),
            std::move(defaults), central, default_dose),
      flows_(std::move(flows)),
      volumes_(std::move(volumes)) {}

double LinearModel::Output(int cmt, const Eigen::VectorXd& x, const Eigen::VectorXd& theta) const {
  const int i = cmt - 1;
  return volumes_[i] >= 0 ? x(i) / theta(volumes_[i]) : x(i);
}

LinearModelBuilder::LinearModelBuilder(std::string name, std::string description)
    : name_(std::move(name)), description_(std::move(description)) {}

int LinearModelBuilder::Parameter(const std::string& name, double default_value) {
  parameters_.push_back(internal::ToUpper(name));
  defaults_.push_back(default_value);
  return static_cast<int>(parameters_.size()) - 1;
}

int LinearModelBuilder::Compartment(const std::string& name, int volume_parameter) {
  compartments_.push_back(name);
  volumes_.push_back(volume_parameter);
  return static_cast<int>(compartments_.size()) - 1;
}

void LinearModelBuilder::RateFlow(int from, int to, int k) { flows_.push_back({from, to, k, false}); }

void LinearModelBuilder::ClearanceFlow(int from, int to, int cl) { flows_.push_back({from, to, cl, true}); }

void LinearModelBuilder::SetCentral(int compartment) { central_ = compartment; }

void LinearModelBuilder::SetDefaultDose(int compartment) { default_dose_ = compartment; }

std::shared_ptr<const LinearModel> LinearModelBuilder::Build() const {
  const int n = static_cast<int>(compartments_.size());
  const int m = static_cast<int>(parameters_.size());
  auto bad = [&](const std::string& what) { throw std::logic_error("model " + name_ + ": " + what); };
  if (n == 0) bad("no compartments");
  if (central_ < 0 || central_ >= n) bad("no central compartment");
  if (volumes_[central_] < 0) bad("the central compartment needs a volume");
  if (default_dose_ < 0 || default_dose_ >= n) bad("no default dose compartment");
  for (int v : volumes_) {
    if (v >= m) bad("volume parameter out of range");
  }
  for (const LinearFlow& f : flows_) {
    if (f.from < 0 || f.from >= n || f.to < -1 || f.to >= n || f.to == f.from) bad("flow between invalid compartments");
    if (f.parameter < 0 || f.parameter >= m) bad("flow parameter out of range");
    if (f.clearance && volumes_[f.from] < 0) bad("a clearance flow leaves a compartment without a volume");
  }
  Eigen::VectorXd defaults(m);
  for (int i = 0; i < m; ++i) defaults(i) = defaults_[i];
  return std::shared_ptr<const LinearModel>(new LinearModel(name_, description_, compartments_, parameters_,
                                                            defaults, central_ + 1, default_dose_ + 1, flows_,
                                                            volumes_));
}

}  // namespace pk
