// Checks a parsed model file and binds its names (not installed).
#ifndef PK_SRC_LANGUAGE_ANALYSIS_H_
#define PK_SRC_LANGUAGE_ANALYSIS_H_

#include <string>
#include <vector>

#include <Eigen/Core>

#include "language/expression.h"
#include "language/model_text.h"
#include "pk/linear_model.h"
#include "pk/model.h"

namespace pk {
namespace internal {
namespace lang {

/// A model file, checked and bound: every name is a state, a model parameter (the declared
/// parameters, then the covariates, then with `bind_etas` the random effects) or a definition
/// inlined into the graph. Without `bind_etas` random effects are 0 (an individual model).
struct CompiledModel {
  ModelText text;
  std::vector<Node> graph;  // resolved (no kSymbol) and constant-folded
  std::vector<std::string> compartments;
  int central = 1, default_dose = 1;  // 1-based
  std::vector<std::string> parameters;
  Eigen::VectorXd defaults;
  std::vector<std::string> signed_parameters;
  ModelDeclarations declarations;
  std::vector<int> rhs;      // root of d/dt of each compartment
  std::vector<std::string> output_names;
  std::vector<int> outputs;  // root of each output (DVID 1, 2, …)
  std::vector<std::string> pk_names;  // the $PK definitions, in file order
  std::vector<int> pk_roots;          // and their roots (they read no state)
  /// Dose modifiers computed in $PK (F1 = …): names, roots (amount-free) and the model parameters each reads.
  std::vector<std::string> modifier_names;
  std::vector<int> modifier_roots;
  std::vector<std::vector<int>> modifier_reads;
  /// When dx/dt = A(θ)x (+ zero-order inputs) and every output is y_k = c_k(θ)x + d_k(θ): the terms
  /// for LinearModel::FromTerms (c_terms[k − 1] are output k's, d_terms[k − 1] its offset's, empty
  /// for none; d_terms is empty when no output has one).
  /// An entry c·θ_a/θ_b is a term of its own; any other (−CL/V with CL = TVCL·WT·exp(η), say) reads
  /// a derived coefficient: term index m + k stands for the node derived_roots[k], which reads the
  /// parameters derived_reads[k] and no amount (pk::DerivedCoefficients). Otherwise `linear` is
  /// false and declarations.why_not_linear says why (the model runs on an ODE propagator).
  bool linear = false;
  std::vector<LinearTerm> a_terms;
  std::vector<std::vector<LinearTerm>> c_terms;
  std::vector<std::vector<LinearTerm>> d_terms;
  std::vector<int> derived_roots;
  std::vector<std::vector<int>> derived_reads;
};

/// Checks `text` and binds its names; `bind_etas` makes each η a model parameter
/// (pk::RandomEffects::kParameters). Throws pk::InputError (file, line, column) naming what is
/// wrong and what was expected.
CompiledModel Analyse(ModelText text, bool bind_etas = false);

}  // namespace lang
}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_LANGUAGE_ANALYSIS_H_
