#include "pk/model.h"

#include <utility>

#include "internal_text.h"
#include "pk/ode_model.h"

namespace pk {

Model::Model(std::string name, std::string description, std::vector<std::string> compartment_names,
             std::vector<std::string> parameter_names, Eigen::VectorXd default_parameters, int central,
             int default_dose)
    : name_(std::move(name)),
      description_(std::move(description)),
      compartment_names_(std::move(compartment_names)),
      parameter_names_(std::move(parameter_names)),
      default_parameters_(std::move(default_parameters)),
      central_(central),
      default_dose_(default_dose) {}

int Model::ParameterIndex(const std::string& name) const {
  const std::string upper = internal::ToUpper(name);
  for (size_t i = 0; i < parameter_names_.size(); ++i) {
    if (parameter_names_[i] == upper) return static_cast<int>(i);
  }
  return -1;
}

namespace {

std::vector<std::string> Names(const OdeModelSpec& spec) {
  std::vector<std::string> names;
  for (const auto& p : spec.parameters) names.push_back(internal::ToUpper(p.first));
  return names;
}

Eigen::VectorXd Defaults(const OdeModelSpec& spec) {
  Eigen::VectorXd v(spec.parameters.size());
  for (size_t i = 0; i < spec.parameters.size(); ++i) v(static_cast<Eigen::Index>(i)) = spec.parameters[i].second;
  return v;
}

}  // namespace

OdeModel::OdeModel(const OdeModelSpec& spec)
    : Model(spec.name, spec.description, spec.compartments, Names(spec), Defaults(spec), spec.central,
            spec.default_dose),
      outputs_(spec.outputs) {}

double OdeModel::Output(int cmt, const Eigen::VectorXd& x, const Eigen::VectorXd& theta) const {
  return cmt == central_compartment() ? OutputValue(1, x, theta) : x(cmt - 1);
}

}  // namespace pk
