#include "pk/parameters.h"

#include <algorithm>
#include <limits>

#include "internal_text.h"
#include "pk/error.h"

namespace pk {

ParameterLayout::ParameterLayout(const Model& model)
    : model_(&model), num_model_(model.num_parameters()), n_(model.num_compartments()), names_(model.parameter_names()) {
  const char* prefixes[] = {"F", "ALAG", "R", "D", "X0_", "K0_"};
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
    defaults_(ConstantInput(c)) = 0.0;
  }
  // Modifiers a model file declares start from its values.
  for (const DeclaredParameter& m : model.declarations().modifiers) defaults_(Index(m.name)) = m.initial;
  const ComputedModifiers& computed = model.declarations().computed_modifiers;
  computed_flag_.assign(names_.size(), 0);
  for (size_t k = 0; k < computed.names.size(); ++k) {
    const int i = Index(computed.names[k]);
    if (i < num_model_) throw InputError("model " + model.name() + " computes " + computed.names[k] + ", which is not a dose modifier");
    computed_.push_back(i);
    computed_flag_[static_cast<size_t>(i)] = 1;
    computed_reads_.insert(computed_reads_.end(), computed.reads[k].begin(), computed.reads[k].end());
  }
  std::sort(computed_reads_.begin(), computed_reads_.end());
  computed_reads_.erase(std::unique(computed_reads_.begin(), computed_reads_.end()), computed_reads_.end());
  ComputeModifiers(&defaults_);
}

namespace {

// The computed modifiers' values from p's model parameters, written into p (one scratch per thread
// and scalar type: a record's set is computed without allocating once warm).
template <typename T, typename Evaluate>
void Compute(const std::vector<int>& slots, const Evaluate& evaluate, Eigen::Matrix<T, Eigen::Dynamic, 1>* p) {
  if (slots.empty()) return;
  thread_local std::vector<T> values;
  values.resize(slots.size());
  evaluate(p->data(), values.data());
  for (size_t k = 0; k < slots.size(); ++k) (*p)(slots[k]) = values[k];
}

}  // namespace

void ParameterLayout::ComputeModifiers(Eigen::VectorXd* p) const {
  Compute<double>(computed_, model_->declarations().computed_modifiers.evaluate, p);
}

void ParameterLayout::ComputeModifiers(Eigen::Matrix<Dual, Eigen::Dynamic, 1>* p) const {
  Compute<Dual>(computed_, model_->declarations().computed_modifiers.evaluate_dual, p);
}

bool ParameterLayout::ComputeModifiers(Eigen::Matrix<HyperDual3, Eigen::Dynamic, 1>* p) const {
  const auto& evaluate = model_->declarations().computed_modifiers.evaluate_third;
  if (computed_.empty()) return true;
  if (!evaluate) return false;
  Compute<HyperDual3>(computed_, evaluate, p);
  return true;
}

void ParameterLayout::CheckNotComputed(const std::string& name, const std::string& what) const {
  const int i = Index(name);
  if (!is_computed(i)) return;
  const std::string& source = model_->declarations().source;
  throw InputError(names_[static_cast<size_t>(i)] + " is computed in $PK of model " + model_->name() +
                   (source.empty() ? "" : " (" + source + ")") + ", so " + what +
                   " cannot set it: a computed dose modifier is never given, fixed or estimated");
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
    CheckNotComputed(kv.first, "a value given for it");
    p(i) = kv.second;
  }
  ComputeModifiers(&p);
  return p;
}

}  // namespace pk
