#include "pk/parameters.h"

#include <limits>

#include "internal_text.h"
#include "pk/error.h"

namespace pk {

ParameterLayout::ParameterLayout(const Model& model)
    : model_(&model), num_model_(model.num_parameters()), n_(model.num_compartments()), names_(model.parameter_names()) {
  const char* prefixes[] = {"F", "ALAG", "R", "D", "X0_"};
  for (const char* prefix : prefixes) {
    for (int c = 1; c <= n_; ++c) names_.push_back(prefix + std::to_string(c));
  }
  defaults_.resize(size());
  defaults_.head(num_model_) = model.default_parameters();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (int c = 0; c < n_; ++c) {
    defaults_(F(c)) = 1.0;
    defaults_(Alag(c)) = 0.0;
    defaults_(Rate(c)) = nan;
    defaults_(Duration(c)) = nan;
    defaults_(InitialState(c)) = 0.0;
  }
  // Modifiers a model file declares start from its values.
  for (const DeclaredParameter& m : model.declarations().modifiers) defaults_(Index(m.name)) = m.initial;
}

int ParameterLayout::Index(const std::string& name) const {
  const std::string upper = internal::ToUpper(name);
  for (size_t i = 0; i < names_.size(); ++i) {
    if (names_[i] == upper) return static_cast<int>(i);
  }
  return -1;
}

Eigen::VectorXd ParameterLayout::Defaults() const { return defaults_; }

Eigen::VectorXd ParameterLayout::Resolve(const ParameterValues& values) const {
  Eigen::VectorXd p = defaults_;
  for (const auto& kv : values) {
    const int i = Index(kv.first);
    if (i < 0) {
      throw InputError(model_->UnknownParameter(kv.first, names_));
    }
    p(i) = kv.second;
  }
  return p;
}

}  // namespace pk
