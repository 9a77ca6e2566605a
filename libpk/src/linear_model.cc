#include "pk/linear_model.h"

#include <stdexcept>
#include <utility>

#include "internal_text.h"

namespace pk {

LinearModel::LinearModel(std::string name, std::string description, std::vector<std::string> compartments,
                         std::vector<std::string> parameters, Eigen::VectorXd defaults, int central,
                         int default_dose, std::vector<LinearTerm> a_terms, std::vector<std::vector<LinearTerm>> c_terms,
                         int tf_order)
    : Model(std::move(name), std::move(description), std::move(compartments), std::move(parameters),
            std::move(defaults), central, default_dose),
      a_terms_(std::move(a_terms)),
      c_terms_(std::move(c_terms)),
      tf_order_(tf_order) {}

std::shared_ptr<const LinearModel> LinearModel::FromTerms(std::string name, std::string description,
                                                          std::vector<std::string> compartments,
                                                          std::vector<std::string> parameters,
                                                          Eigen::VectorXd defaults, int central, int default_dose,
                                                          std::vector<LinearTerm> system_terms,
                                                          std::vector<std::vector<LinearTerm>> output_terms,
                                                          int transfer_function_order,
                                                          InitialStructure initial_structure,
                                                          ModelDeclarations declarations,
                                                          std::vector<std::string> signed_parameters,
                                                          DerivedCoefficients derived,
                                                          std::vector<std::string> outputs,
                                                          std::vector<std::vector<LinearTerm>> output_offsets) {
  const int n = static_cast<int>(compartments.size()), m = static_cast<int>(parameters.size());
  const int indexed = m + derived.count;  // a term indexes [θ; ψ]
  auto bad = [&](const std::string& what) { throw std::logic_error("model " + name + ": " + what); };
  if (output_terms.size() != compartments.size() + outputs.size()) {
    bad("one output row per compartment and per named output is needed");
  }
  if (defaults.size() != m) bad("one default per parameter is needed");
  if (central < 1 || central > n || default_dose < 1 || default_dose > n) bad("central or dose compartment out of range");
  auto check = [&](const LinearTerm& t) {
    if (t.row < 0 || t.row >= n || t.col < 0 || t.col >= n) bad("term outside the state");
    if (t.numerator >= indexed || t.denominator >= indexed || t.numerator < -1 || t.denominator < -1) {
      bad("term parameter out of range");
    }
  };
  if (derived.count < 0 || (derived.count > 0 && (!derived.evaluate || !derived.evaluate_second ||
                                                   static_cast<int>(derived.reads.size()) != derived.count))) {
    bad("derived coefficients need a function and the parameters each reads");
  }
  for (const auto& reads : derived.reads) {
    for (int j : reads) {
      if (j < 0 || j >= m) bad("a derived coefficient reads a parameter out of range");
    }
  }
  for (const LinearTerm& t : system_terms) check(t);
  for (const auto& row : output_terms) {
    for (const LinearTerm& t : row) check(t);
  }
  bool any_offset = false;
  for (const auto& row : output_offsets) {
    for (const LinearTerm& t : row) {
      LinearTerm at = t;
      at.row = at.col = 0;  // an offset has no place in the state
      check(at);
    }
    any_offset = any_offset || !row.empty();
  }
  if (!output_offsets.empty() && output_offsets.size() != output_terms.size()) {
    bad("output offsets, when given, need one row per output row");
  }
  if (any_offset && transfer_function_order > 0) bad("a transfer-function model's output has no offset");
  for (std::string& p : parameters) p = internal::ToUpper(p);
  std::shared_ptr<LinearModel> model(new LinearModel(std::move(name), std::move(description), std::move(compartments),
                                                     std::move(parameters), std::move(defaults), central,
                                                     default_dose, std::move(system_terms), std::move(output_terms),
                                                     transfer_function_order));
  model->set_initial_structure(std::move(initial_structure));
  // A transfer function's coefficients take either sign; a compartment model's parameters are positive.
  if (transfer_function_order > 0) model->set_signed_parameters(model->parameter_names());
  if (!signed_parameters.empty()) model->set_signed_parameters(signed_parameters);
  model->set_declarations(std::move(declarations));
  model->set_output_names(std::move(outputs));
  model->derived_ = std::move(derived);
  if (any_offset) model->d_terms_ = std::move(output_offsets);
  return model;
}

double LinearModel::Output(int cmt, const Eigen::VectorXd& x, const Eigen::VectorXd& theta) const {
  return OutputRow<double>(cmt, theta) * x + OutputOffset<double>(cmt, theta);
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
  // Each flow k(θ) (a rate constant, or CL/V of its source) adds +k at (to, from) and −k at (from, from).
  std::vector<LinearTerm> a_terms;
  for (const LinearFlow& f : flows_) {
    const int den = f.clearance ? volumes_[f.from] : -1;
    a_terms.push_back({f.from, f.from, -1.0, f.parameter, den});
    if (f.to >= 0) a_terms.push_back({f.to, f.from, 1.0, f.parameter, den});
  }
  // Observing compartment c gives its concentration (amount / volume), or its amount.
  std::vector<std::vector<LinearTerm>> c_terms(n);
  for (int c = 0; c < n; ++c) c_terms[c].push_back({0, c, 1.0, -1, volumes_[c]});
  std::shared_ptr<LinearModel> model(new LinearModel(name_, description_, compartments_, parameters_, defaults,
                                                     central_ + 1, default_dose_ + 1, std::move(a_terms),
                                                     std::move(c_terms), 0));
  model->set_initial_structure(initial_structure_);
  model->set_former_names(former_names_, former_names_note_);
  return model;
}

}  // namespace pk
