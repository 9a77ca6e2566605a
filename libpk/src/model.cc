#include "pk/model.h"

#include <stdexcept>
#include <utility>

#include "internal_text.h"
#include "pk/error.h"

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

void Model::set_initial_structure(InitialStructure s) {
  for (std::string& name : s.names) name = internal::ToUpper(name);
  s.vmax = internal::ToUpper(s.vmax);
  s.km = internal::ToUpper(s.km);
  initial_structure_ = std::move(s);
}

void Model::set_signed_parameters(const std::vector<std::string>& names) {
  signed_.assign(parameter_names_.size(), false);
  for (const std::string& name : names) {
    const int i = ParameterIndex(name);
    if (i < 0) throw std::logic_error("model " + name_ + ": no parameter " + name + " to declare signed");
    signed_[static_cast<size_t>(i)] = true;
  }
}

void Model::set_former_names(std::vector<std::string> names, std::string note) {
  for (std::string& name : names) {
    name = internal::ToUpper(name);
    if (ParameterIndex(name) >= 0) throw std::logic_error("model " + name_ + ": former name " + name + " is in use");
  }
  former_names_ = std::move(names);
  former_names_note_ = std::move(note);
}

bool Model::IsFormerName(const std::string& name) const {
  const std::string upper = internal::ToUpper(name);
  for (const std::string& former : former_names_) {
    if (former == upper) return true;
  }
  return false;
}

std::string Model::UnknownParameter(const std::string& name, const std::vector<std::string>& names) const {
  if (IsFormerName(name)) return "'" + name + "' is no longer a parameter of " + name_ + ": " + former_names_note_;
  const std::string closest = ClosestName(name, names);
  return "unknown parameter '" + name + "'" + (closest.empty() ? "" : " (did you mean " + closest + "?)") +
         "; " + name_ + " has " + internal::Join(names, ", ");
}

int Model::ParameterIndex(const std::string& name) const {
  const std::string upper = internal::ToUpper(name);
  for (size_t i = 0; i < parameter_names_.size(); ++i) {
    if (parameter_names_[i] == upper) return static_cast<int>(i);
  }
  return -1;
}

}  // namespace pk
