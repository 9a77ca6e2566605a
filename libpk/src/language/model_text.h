// A model file as written: declarations and the expression graph, names not yet resolved
// (not installed). The grammar is in docs/model_language.md; parser.cc reads it, analysis.cc checks
// it and binds names.
#ifndef PK_SRC_LANGUAGE_MODEL_TEXT_H_
#define PK_SRC_LANGUAGE_MODEL_TEXT_H_

#include <cmath>
#include <string>
#include <vector>

#include "language/expression.h"

namespace pk {
namespace internal {
namespace lang {

/// Where something was written (1-based).
struct Place {
  int line = 0, column = 0;
};

struct ParameterDecl {
  std::string name;  // upper case
  double initial = NAN;
  double lower = -INFINITY, upper = INFINITY;
  bool has_bounds = false;
  std::string unit;
  Place at;
};

struct CovariateDecl {
  std::string name;
  double reference = NAN;  // a value used when the dataset has no such column (pksim), or NaN
  std::string unit;
  Place at;
};

/// A random effect η ~ N(0, ω²) of the population model; 0 in an individual fit.
struct EtaDecl {
  std::string name;
  double variance = NAN;
  Place at;
};

/// One $OMEGA line: its η (indices into ModelText::etas, consecutive) and Ω's block over them,
/// the lower triangle by rows as NONMEM's BLOCK(n) gives it (one value for a single η).
struct OmegaLine {
  std::vector<int> etas;
  std::vector<double> lower;
  bool fixed = false;
  bool same = false;  ///< `~ SAME`: the line before's block repeated (its values, tied to it)
  Place at;
};

struct CompartmentDecl {
  std::string name;
  bool dose = false;
  bool central = false;
  Place at;
};

/// NAME = expression (a derived quantity; $PK, $ODE or $OUTPUT locals).
struct Definition {
  std::string name;
  int node = -1;
  Place at;
  bool in_pk = false;  // written in $PK (must not read a state)
  std::string initial_of;  // $INIT's line for this compartment (then named X0_<n>)
};

/// d/dt(NAME) = expression.
struct Derivative {
  std::string compartment;
  int node = -1;
  Place at;
};

/// An output, DVID = its position (from 1).
struct OutputDecl {
  std::string name;
  int node = -1;
  Place at;
};

/// NAME ~ model(σ, …) in $ERROR.
struct ErrorDecl {
  std::string output;
  std::string model;  // lower case: additive, proportional, combined, exponential
  std::vector<double> sigma;
  Place at;
};

struct ModelText {
  std::string source;  // the file, for messages
  std::string name, description;
  Place name_at;
  std::vector<ParameterDecl> parameters;
  std::vector<CovariateDecl> covariates;
  std::vector<EtaDecl> etas;
  std::vector<OmegaLine> omega;
  std::vector<CompartmentDecl> compartments;
  std::vector<Definition> definitions;
  std::vector<Derivative> derivatives;
  std::vector<OutputDecl> outputs;
  std::vector<ErrorDecl> errors;
  std::vector<Node> graph;
};

/// Parses model text; throws pk::InputError (source, line, column) on a syntax error.
ModelText Parse(const std::string& text, const std::string& source);

}  // namespace lang
}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_LANGUAGE_MODEL_TEXT_H_
