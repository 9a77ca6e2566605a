// Name binding, the checks of a model file, and the detection of linear structure.
#include "language/analysis.h"

#include <algorithm>
#include <cctype>
#include <map>
#include <utility>

#include <Eigen/Cholesky>

#include "internal_text.h"
#include "pk/error.h"
#include "pk/output.h"
#include "pk/residual_error.h"

namespace pk {
namespace internal {
namespace lang {
namespace {

enum class SymbolKind { kState, kParameter, kCovariate, kEta, kDefinition, kModifier, kOutput };

struct Symbol {
  SymbolKind kind;
  int index;  // state, model parameter, eta or definition index
  Place at;
};

const char* KindName(SymbolKind k) {
  switch (k) {
    case SymbolKind::kState: return "a compartment";
    case SymbolKind::kParameter: return "a parameter";
    case SymbolKind::kCovariate: return "a covariate";
    case SymbolKind::kEta: return "a random effect";
    case SymbolKind::kDefinition: return "a definition";
    case SymbolKind::kModifier: return "a dose modifier";
    case SymbolKind::kOutput: return "an output";
  }
  return "";
}

// "F1" → ("F", 1); "X0_2" → ("X0_", 2); "K0_1" → ("K0_", 1); else ("", 0).
std::pair<std::string, int> ModifierName(const std::string& name) {
  for (const char* prefix : {"ALAG", "X0_", "K0_", "F", "R", "D"}) {
    const std::string p(prefix);
    if (name.size() <= p.size() || name.compare(0, p.size(), p) != 0) continue;
    const std::string digits = name.substr(p.size());
    if (!std::all_of(digits.begin(), digits.end(), [](char c) { return std::isdigit(static_cast<unsigned char>(c)); }) ||
        digits[0] == '0' || digits.size() > 3) {
      continue;
    }
    return {p, std::stoi(digits)};
  }
  return {"", 0};
}

// A monomial c · x_state · Π θ_k^power (state -1: none), for the linear-structure test.
struct Monomial {
  double c = 1;
  int state = -1;
  std::map<int, int> powers;
};
using Polynomial = std::vector<Monomial>;

class Analyser {
 public:
  Analyser(ModelText text, bool bind_etas) : bind_etas_(bind_etas) {
    out_.text = std::move(text);
    out_.declarations.source = out_.text.source;
  }

  CompiledModel Run() {
    const ModelText& t = out_.text;
    if (t.name.empty()) Fail(Place{1, 1}, "the model file has no $PROBLEM line with the model's name");
    if (t.compartments.empty()) Fail(Place{1, 1}, "the model declares no compartments ($CMT)");
    if (t.outputs.empty()) Fail(Place{1, 1}, "the model declares no outputs ($OUTPUT, for example CP = CENTRAL / V)");
    DeclareSymbols();
    BindDerivatives();
    BindOutputs();
    CheckDefinitions();
    CheckUnused();
    ChooseCompartments();
    BindErrors();
    DetectLinear();
    out_.graph = std::move(g_);
    return std::move(out_);
  }

 private:
  [[noreturn]] void Fail(const Place& at, const std::string& message) const {
    throw InputError(out_.text.source, at.line, at.column, message);
  }
  [[noreturn]] void Fail(const Node& n, const std::string& message) const { Fail(Place{n.line, n.column}, message); }

  // --- declarations -------------------------------------------------------------------------
  void Declare(const std::string& name, SymbolKind kind, int index, const Place& at) {
    if (name == "TIME" || name == "T") {
      Fail(at, name + " is reserved: a model's right-hand side must not depend on time (doses and records carry it)");
    }
    if (IsResidualErrorName(name)) Fail(at, name + " is the name of a residual-error σ; choose another name");
    const auto it = symbols_.find(name);
    if (it != symbols_.end()) {
      Fail(at, name + " is declared twice: as " + KindName(kind) + " here and as " + KindName(it->second.kind) +
                   " on line " + std::to_string(it->second.at.line));
    }
    symbols_[name] = {kind, index, at};
  }

  void DeclareSymbols() {
    const ModelText& t = out_.text;
    const int n = static_cast<int>(t.compartments.size());
    for (int i = 0; i < n; ++i) {
      Declare(t.compartments[i].name, SymbolKind::kState, i, t.compartments[i].at);
      out_.compartments.push_back(t.compartments[i].name);
    }
    for (const ParameterDecl& p : t.parameters) DeclareParameter(p, n);
    for (const CovariateDecl& c : t.covariates) {
      Declare(c.name, SymbolKind::kCovariate, static_cast<int>(out_.parameters.size()), c.at);
      out_.parameters.push_back(c.name);
      defaults_.push_back(c.reference);
      out_.signed_parameters.push_back(c.name);
      DeclaredParameter d;
      d.name = c.name;
      d.initial = c.reference;
      d.unit = c.unit;
      d.covariate = true;
      out_.declarations.parameters.push_back(d);
    }
    for (size_t i = 0; i < t.etas.size(); ++i) {
      const EtaDecl& e = t.etas[i];
      if (!(e.variance > 0) || !std::isfinite(e.variance)) {
        Fail(e.at, "the variance ω² of " + e.name + " must be positive, not " + FormatNumber(e.variance));
      }
      Declare(e.name, SymbolKind::kEta, static_cast<int>(i), e.at);
      if (bind_etas_) DeclareEtaParameter(e);
    }
    for (const OmegaLine& line : t.omega) DeclareOmegaBlock(line);
    for (size_t i = 0; i < t.definitions.size(); ++i) {
      const Definition& d = t.definitions[i];
      const auto mod = ModifierName(d.name);
      if (!mod.first.empty()) DeclareComputedModifier(d, mod.second, static_cast<int>(i));
      Declare(d.name, SymbolKind::kDefinition, static_cast<int>(i), d.at);
    }
    for (size_t i = 0; i < t.outputs.size(); ++i) {
      Declare(t.outputs[i].name, SymbolKind::kOutput, static_cast<int>(i), t.outputs[i].at);
    }
    out_.defaults = Eigen::Map<Eigen::VectorXd>(defaults_.data(), static_cast<Eigen::Index>(defaults_.size()));
    resolved_def_.assign(t.definitions.size(), -1);
    def_state_.assign(t.definitions.size(), 0);
    used_.assign(out_.parameters.size(), false);
    eta_used_.assign(t.etas.size(), false);
  }

  // F1 = …, ALAG2 = …: a dose modifier computed in $PK from individual parameters (it may not read
  // an amount, and it modifies a compartment that exists). Expressions may read it as a definition.
  void DeclareComputedModifier(const Definition& d, int cmt, int index) {
    if (!d.in_pk) {
      Fail(d.at, d.name + " is a dose modifier: compute it in $PK, where individual parameters are defined (the "
                          "event engine applies it to doses, before any amount exists)");
    }
    if (cmt > n()) {
      Fail(d.at, d.name + " modifies compartment " + std::to_string(cmt) + ", but the model has " +
                     std::to_string(n()) + " compartment" + (n() > 1 ? "s" : ""));
    }
    modifier_definitions_.push_back(index);
  }

  // Ω's block over one $OMEGA line's η: symmetric from its lower triangle, positive definite.
  void DeclareOmegaBlock(const OmegaLine& line) {
    const ModelText& t = out_.text;
    const auto n = static_cast<Eigen::Index>(line.etas.size());
    OmegaBlockDeclaration block;
    block.omega.resize(n, n);
    size_t k = 0;
    for (Eigen::Index i = 0; i < n; ++i) {
      block.etas.push_back(t.etas[static_cast<size_t>(line.etas[static_cast<size_t>(i)])].name);
      for (Eigen::Index j = 0; j <= i; ++j) block.omega(i, j) = block.omega(j, i) = line.lower[k++];
    }
    block.fixed = line.fixed;
    block.same = line.same;
    if (!block.omega.allFinite() || block.omega.llt().info() != Eigen::Success) {
      std::string names;
      for (const std::string& e : block.etas) names += (names.empty() ? "" : ", ") + e;
      Fail(line.at, "the block of " + names + " is not positive definite: a covariance is larger than the "
                    "variances allow (|ω_ij| < √(ω²_i ω²_j) at least)");
    }
    out_.declarations.omega_blocks.push_back(std::move(block));
  }

  // A population model's η: a parameter of either sign, 0 unless the population fit binds it.
  void DeclareEtaParameter(const EtaDecl& e) {
    eta_input_.push_back(static_cast<int>(out_.parameters.size()));
    out_.parameters.push_back(e.name);
    defaults_.push_back(0.0);
    out_.signed_parameters.push_back(e.name);
    DeclaredParameter d;
    d.name = e.name;
    d.initial = 0;
    d.eta = true;
    d.variance = e.variance;
    out_.declarations.parameters.push_back(d);
  }

  void DeclareParameter(const ParameterDecl& p, int n) {
    if (p.has_bounds && !(p.lower < p.upper)) {
      Fail(p.at, p.name + ": the lower bound " + FormatNumber(p.lower) + " is not below the upper bound " +
                     FormatNumber(p.upper));
    }
    if (!std::isfinite(p.initial)) Fail(p.at, p.name + ": the initial value must be finite");
    if (p.has_bounds && !(p.initial > p.lower && p.initial < p.upper)) {
      Fail(p.at, p.name + ": the initial value " + FormatNumber(p.initial) + " must lie strictly within its bounds (" +
                     FormatNumber(p.lower) + ", " + FormatNumber(p.upper) + ")");
    }
    const bool is_signed = p.has_bounds && p.lower < 0;
    if (!is_signed && !(p.initial > 0)) {
      Fail(p.at, p.name + " must be positive (give bounds with a negative lower bound, such as (-inf, inf), for a "
                          "parameter of either sign), not " + FormatNumber(p.initial));
    }
    DeclaredParameter d;
    d.name = p.name;
    d.initial = p.initial;
    d.lower = p.has_bounds ? p.lower : -HUGE_VAL;
    d.upper = p.has_bounds ? p.upper : HUGE_VAL;
    d.unit = p.unit;
    const auto mod = ModifierName(p.name);
    if (!mod.first.empty()) {
      if (mod.second > n) {
        Fail(p.at, p.name + " modifies compartment " + std::to_string(mod.second) + ", but the model has " +
                       std::to_string(n) + " compartment" + (n > 1 ? "s" : ""));
      }
      Declare(p.name, SymbolKind::kModifier, -1, p.at);
      out_.declarations.modifiers.push_back(d);
      return;
    }
    Declare(p.name, SymbolKind::kParameter, static_cast<int>(out_.parameters.size()), p.at);
    out_.parameters.push_back(p.name);
    defaults_.push_back(p.initial);
    if (is_signed) out_.signed_parameters.push_back(p.name);
    out_.declarations.parameters.push_back(d);
  }

  // --- resolution ---------------------------------------------------------------------------
  int NewNode(Node n) {
    g_.push_back(std::move(n));
    return static_cast<int>(g_.size()) - 1;
  }
  int Constant(double v, const Node& at) {
    Node n;
    n.op = Op::kConstant;
    n.value = v;
    n.line = at.line;
    n.column = at.column;
    return NewNode(n);
  }
  int Input(int input, const Node& at) {
    const auto it = input_node_.find(input);
    if (it != input_node_.end()) return it->second;
    Node n;
    n.op = Op::kInput;
    n.input = input;
    n.line = at.line;
    n.column = at.column;
    return input_node_[input] = NewNode(n);
  }
  int n() const { return static_cast<int>(out_.compartments.size()); }

  // The resolved node of parsed node `i`; `context` names what is being bound, for messages.
  int Resolve(int i, const std::string& context) {
    const Node& src = out_.text.graph[static_cast<size_t>(i)];
    if (src.op == Op::kSymbol) return ResolveSymbol(src, context);
    if (src.op == Op::kConstant) return Constant(src.value, src);
    Node r = src;
    r.a = src.a >= 0 ? Resolve(src.a, context) : -1;
    r.b = src.b >= 0 ? Resolve(src.b, context) : -1;
    r.c = src.c >= 0 ? Resolve(src.c, context) : -1;
    return Fold(r);
  }

  int ResolveSymbol(const Node& src, const std::string& context) {
    const auto it = symbols_.find(src.name);
    if (it == symbols_.end() && (src.name == "TIME" || src.name == "T")) {
      Fail(src, src.name + " is reserved: a model's right-hand side must not depend on time (doses and records "
                           "carry it)");
    }
    if (it == symbols_.end()) {
      std::vector<std::string> names;
      for (const auto& kv : symbols_) names.push_back(kv.first);
      const std::string closest = ClosestName(src.name, names);
      Fail(src, context + " reads " + src.name + ", which is not defined" +
                    (closest.empty() ? "" : " (did you mean " + closest + "?)") +
                    "; declare it in $PARAM or $COVARIATE, or define it in $PK");
    }
    const Symbol& s = it->second;
    switch (s.kind) {
      case SymbolKind::kState: return Input(s.index, src);
      case SymbolKind::kParameter:
      case SymbolKind::kCovariate:
        return Input(n() + s.index, src);
      case SymbolKind::kEta:
        eta_used_[static_cast<size_t>(s.index)] = true;
        if (bind_etas_) return Input(n() + eta_input_[static_cast<size_t>(s.index)], src);
        return Constant(0.0, src);  // an individual model: η = 0
      case SymbolKind::kDefinition: {
        const auto modifier = ModifierName(src.name);
        if (modifier.first == "K0_" && context.compare(0, 5, "d/dt(") == 0) {
          Fail(src, context + " reads " + src.name + ", the zero-order input the event engine adds to compartment " +
                        std::to_string(modifier.second) + " at all times: it would count twice; write the input in "
                        "d/dt or compute " + src.name + " in $PK, not both");
        }
        return ResolveDefinition(s.index, src);
      }
      case SymbolKind::kModifier:
        Fail(src, src.name + " is a dose modifier, which the event engine applies to doses; an expression cannot "
                             "read it");
      case SymbolKind::kOutput:
        Fail(src, context + " reads the output " + src.name + "; outputs are not names: define the shared part in "
                                                            "$PK or $ODE");
    }
    return -1;
  }

  int ResolveDefinition(int d, const Node& at) {
    if (def_state_[static_cast<size_t>(d)] == 2) return resolved_def_[static_cast<size_t>(d)];
    const Definition& def = out_.text.definitions[static_cast<size_t>(d)];
    if (def_state_[static_cast<size_t>(d)] == 1) {
      std::string path;
      for (size_t k = std::find(stack_.begin(), stack_.end(), d) - stack_.begin(); k < stack_.size(); ++k) {
        path += out_.text.definitions[static_cast<size_t>(stack_[k])].name + " → ";
      }
      Fail(at, "cyclic definition: " + path + def.name);
    }
    def_state_[static_cast<size_t>(d)] = 1;
    stack_.push_back(d);
    const int r = Resolve(def.node, def.name);
    stack_.pop_back();
    def_state_[static_cast<size_t>(d)] = 2;
    return resolved_def_[static_cast<size_t>(d)] = r;
  }

  // Folds an operation on constants into a constant; refuses operations that always fail.
  int Fold(const Node& r) {
    const auto constant = [&](int k, double* v) {
      if (k < 0 || g_[static_cast<size_t>(k)].op != Op::kConstant) return false;
      *v = g_[static_cast<size_t>(k)].value;
      return true;
    };
    double b = 0, a = 0;
    if (r.op == Op::kDiv && ((constant(r.b, &b) && b == 0) || IdenticallyZero(r.b))) {
      Fail(r, "division by zero: the denominator is always 0");
    }
    if ((r.op == Op::kLog || r.op == Op::kLog10) && constant(r.a, &a) && !(a > 0)) {
      Fail(r, "log of " + FormatNumber(a) + ": the argument is never positive");
    }
    if (r.op == Op::kSqrt && constant(r.a, &a) && a < 0) Fail(r, "sqrt of " + FormatNumber(a) + ", a negative constant");
    const int arity = Arity(r.op);
    double v[3] = {0, 0, 0};
    bool all = true;
    const int ops[3] = {r.a, r.b, r.c};
    for (int k = 0; k < arity; ++k) all = all && constant(ops[k], &v[k]);
    if (!all) {
      Node copy = r;
      // A constant exponent: pow(x, c) differentiates without log x (x may be 0).
      if (copy.op == Op::kPow && constant(copy.b, &b)) {
        copy.value = b;
        copy.b = -1;
      }
      return NewNode(copy);
    }
    if (r.op == Op::kSelect) return Constant(v[0] != 0 ? v[1] : v[2], r);
    std::vector<Node> tiny(static_cast<size_t>(arity) + 1);
    for (int k = 0; k < arity; ++k) {
      tiny[static_cast<size_t>(k)].op = Op::kConstant;
      tiny[static_cast<size_t>(k)].value = v[k];
    }
    Node op = r;
    op.a = 0;
    op.b = arity > 1 ? 1 : -1;
    op.c = arity > 2 ? 2 : -1;
    tiny[static_cast<size_t>(arity)] = op;
    const Program p(tiny, {arity}, 0);
    double value = 0;
    std::vector<double> slots;
    p.Run<double>(nullptr, nullptr, &value, &slots);
    if (!std::isfinite(value)) Fail(r, "this expression of constants is not finite (" + FormatNumber(value) + ")");
    return Constant(value, r);
  }

  // A state the node reads, or -1 (memoised: definitions make the graph a DAG, and a node shared by
  // both operands of each of a chain of nodes would otherwise be visited 2^depth times).
  int StateRead(int k) {
    if (state_read_.size() < g_.size()) state_read_.resize(g_.size(), -2);
    int& memo = state_read_[static_cast<size_t>(k)];
    if (memo != -2) return memo;
    const Node& node = g_[static_cast<size_t>(k)];
    int s = node.op == Op::kInput && node.input < n() ? node.input : -1;
    for (int o : {node.a, node.b, node.c}) {
      if (s < 0 && o >= 0) s = StateRead(o);
    }
    return state_read_[static_cast<size_t>(k)] = s;
  }

  // --- the model's parts --------------------------------------------------------------------
  void BindDerivatives() {
    const ModelText& t = out_.text;
    out_.rhs.assign(static_cast<size_t>(n()), -1);
    std::vector<const Derivative*> seen(static_cast<size_t>(n()), nullptr);
    for (const Derivative& d : t.derivatives) {
      const auto it = symbols_.find(d.compartment);
      if (it == symbols_.end() || it->second.kind != SymbolKind::kState) {
        const std::string closest = ClosestName(d.compartment, out_.compartments);
        Fail(d.at, "d/dt(" + d.compartment + "): " + d.compartment + " is not a compartment" +
                       (closest.empty() ? "" : " (did you mean " + closest + "?)") + "; the compartments are " +
                       Join(out_.compartments, ", "));
      }
      const int c = it->second.index;
      if (seen[static_cast<size_t>(c)] != nullptr) {
        Fail(d.at, "d/dt(" + d.compartment + ") is given twice (first on line " +
                       std::to_string(seen[static_cast<size_t>(c)]->at.line) + ")");
      }
      seen[static_cast<size_t>(c)] = &d;
      out_.rhs[static_cast<size_t>(c)] = Resolve(d.node, "d/dt(" + d.compartment + ")");
    }
    for (int c = 0; c < n(); ++c) {
      if (out_.rhs[static_cast<size_t>(c)] < 0) {
        Fail(t.compartments[static_cast<size_t>(c)].at,
             "compartment " + out_.compartments[static_cast<size_t>(c)] +
                 " has no equation: add d/dt(" + out_.compartments[static_cast<size_t>(c)] +
                 ") = … in $ODE, or remove the compartment");
      }
    }
  }

  void BindOutputs() {
    for (const OutputDecl& o : out_.text.outputs) {
      out_.output_names.push_back(o.name);
      out_.outputs.push_back(Resolve(o.node, "output " + o.name));
    }
  }

  // Every definition is bound, used or not (a typo in one is still an error); $PK computes
  // individual parameters before any state exists.
  void CheckDefinitions() {
    const ModelText& t = out_.text;
    for (size_t d = 0; d < t.definitions.size(); ++d) {
      Node at;
      at.line = t.definitions[d].at.line;
      at.column = t.definitions[d].at.column;
      const int r = ResolveDefinition(static_cast<int>(d), at);
      const int s = t.definitions[d].in_pk ? StateRead(r) : -1;
      if (s >= 0 && !t.definitions[d].initial_of.empty()) {
        Fail(t.definitions[d].at, "the initial amount of " + t.definitions[d].initial_of + " reads the amount in " +
                                      out_.compartments[static_cast<size_t>(s)] +
                                      ": it is set before any amount exists (write it from parameters and $PK)");
      }
      if (s >= 0) {
        Fail(t.definitions[d].at, t.definitions[d].name + " in $PK reads the amount in " +
                                      out_.compartments[static_cast<size_t>(s)] +
                                      ": $PK computes individual parameters, which cannot depend on the state; "
                                      "define it in $ODE");
      }
      const std::string& name = t.definitions[d].name;
      if (std::find(modifier_definitions_.begin(), modifier_definitions_.end(), static_cast<int>(d)) !=
          modifier_definitions_.end()) {
        out_.modifier_names.push_back(name);
        out_.modifier_roots.push_back(r);
        out_.modifier_reads.push_back(ParametersRead(r));
      }
      if (t.definitions[d].in_pk && std::find(out_.pk_names.begin(), out_.pk_names.end(), name) == out_.pk_names.end()) {
        out_.pk_names.push_back(name);
        out_.pk_roots.push_back(r);
      }
    }
  }

  // The model parameters the equations and outputs read.
  void MarkUsed(int k, std::vector<char>* seen) {
    if ((*seen)[static_cast<size_t>(k)]) return;
    (*seen)[static_cast<size_t>(k)] = 1;
    const Node& node = g_[static_cast<size_t>(k)];
    if (node.op == Op::kInput && node.input >= n()) used_[static_cast<size_t>(node.input - n())] = true;
    for (int o : {node.a, node.b, node.c}) {
      if (o >= 0) MarkUsed(o, seen);
    }
  }

  void CheckUnused() {
    const ModelText& t = out_.text;
    std::vector<char> seen(g_.size(), 0);
    for (int r : out_.rhs) MarkUsed(r, &seen);
    for (int r : out_.outputs) MarkUsed(r, &seen);
    for (int r : out_.modifier_roots) MarkUsed(r, &seen);
    for (const ParameterDecl& p : t.parameters) {
      const Symbol& s = symbols_.at(p.name);
      if (s.kind == SymbolKind::kParameter && !used_[static_cast<size_t>(s.index)]) {
        Fail(p.at, "parameter " + p.name + " is never used: no equation or output reads it, so no data can "
                                           "estimate it or change a prediction");
      }
    }
    for (const CovariateDecl& c : t.covariates) {
      if (!used_[static_cast<size_t>(symbols_.at(c.name).index)]) {
        Fail(c.at, "covariate " + c.name + " is never used");
      }
    }
    for (size_t i = 0; i < t.etas.size(); ++i) {
      if (!eta_used_[i]) Fail(t.etas[i].at, "random effect " + t.etas[i].name + " is never used");
    }
  }

  void ChooseCompartments() {
    const ModelText& t = out_.text;
    int dose = -1, central = -1;
    for (int c = 0; c < n(); ++c) {
      const CompartmentDecl& d = t.compartments[static_cast<size_t>(c)];
      for (auto attr : {std::make_pair(d.dose, &dose), std::make_pair(d.central, &central)}) {
        if (!attr.first) continue;
        if (*attr.second >= 0) {
          Fail(d.at, std::string("only one compartment can be the ") + (attr.second == &dose ? "dose" : "central") +
                         " compartment (" + out_.compartments[static_cast<size_t>(*attr.second)] + " is already)");
        }
        *attr.second = c;
      }
    }
    // The central compartment defaults to the one output 1 reads; doses default to the first compartment.
    if (central < 0) central = std::max(0, StateRead(out_.outputs[0]));
    out_.central = central + 1;
    out_.default_dose = (dose < 0 ? 0 : dose) + 1;
  }

  void BindErrors() {
    const ModelText& t = out_.text;
    std::map<std::string, const ErrorDecl*> seen;
    for (const ErrorDecl& e : t.errors) {
      const auto it = symbols_.find(e.output);
      if (it == symbols_.end() || it->second.kind != SymbolKind::kOutput) {
        Fail(e.at, "$ERROR: " + e.output + " is not an output; the outputs are " + Join(out_.output_names, ", "));
      }
      if (seen.count(e.output)) {
        Fail(e.at, "$ERROR: " + e.output + " has two error models (first on line " +
                       std::to_string(seen[e.output]->at.line) + ")");
      }
      seen[e.output] = &e;
      std::vector<std::string> names = ResidualErrorNames();
      names.erase(names.begin());  // least squares is no error model
      if (std::find(names.begin(), names.end(), e.model) == names.end()) {
        const std::string closest = ClosestName(e.model, names);
        Fail(e.at, "$ERROR: unknown error model '" + e.model + "'" +
                       (closest.empty() ? "" : " (did you mean " + closest + "?)") + "; the error models are " +
                       Join(names, ", "));
      }
      const std::shared_ptr<const ResidualErrorModel> model = MakeResidualError(e.model);
      if (!e.sigma.empty() && e.sigma.size() != model->sigma_names().size()) {
        Fail(e.at, "$ERROR: " + e.model + " takes " + std::to_string(model->sigma_names().size()) + " σ (" +
                       Join(model->sigma_names(), ", ") + "), not " + std::to_string(e.sigma.size()));
      }
      for (double s : e.sigma) {
        if (!(s > 0)) Fail(e.at, "$ERROR: an initial σ must be positive, not " + FormatNumber(s));
      }
      out_.declarations.error_model = model->name();
      if (!e.sigma.empty()) out_.declarations.sigma = e.sigma;
    }
    if (seen.size() > 1) PerOutputErrors(seen);
  }

  // A line per output: each output its own model and σ, and then every output needs one.
  void PerOutputErrors(const std::map<std::string, const ErrorDecl*>& seen) {
    ModelDeclarations& d = out_.declarations;
    bool all_sigma = true;
    for (const std::string& output : out_.output_names) {
      const auto it = seen.find(output);
      if (it == seen.end()) {
        Fail(out_.text.errors.front().at, "$ERROR gives outputs their own error models, but not " + output +
                                              ": give every output a line (" + output + " ~ additive, …)");
      }
      d.output_error_models.push_back(it->second->model);
      d.output_sigma.push_back(it->second->sigma);
      all_sigma = all_sigma && !it->second->sigma.empty();
    }
    d.error_model = "per-output";
    d.sigma.clear();
    for (const auto& sigma : d.output_sigma) {
      if (all_sigma) d.sigma.insert(d.sigma.end(), sigma.begin(), sigma.end());
    }
  }

  // --- linear structure ---------------------------------------------------------------------
  // False when node k is not a sum of monomials with at most one state each (memoised, as StateRead).
  bool Expand(int k, Polynomial* p) {
    const auto memo = expanded_.find(k);
    if (memo != expanded_.end()) {
      *p = memo->second.second;
      return memo->second.first;
    }
    const bool ok = ExpandNode(k, p);
    expanded_[k] = {ok, *p};
    return ok;
  }
  bool ExpandNode(int k, Polynomial* p) {
    const Node& node = g_[static_cast<size_t>(k)];
    Polynomial a, b;
    switch (node.op) {
      case Op::kConstant: *p = {Monomial{node.value, -1, {}}}; return true;
      case Op::kInput:
        if (node.input < n()) {
          *p = {Monomial{1, node.input, {}}};
        } else {
          *p = {Monomial{1, -1, {{node.input - n(), 1}}}};
        }
        return true;
      case Op::kNeg:
        if (!Expand(node.a, p)) return false;
        for (Monomial& m : *p) m.c = -m.c;
        return true;
      case Op::kAdd:
      case Op::kSub:
        if (!Expand(node.a, &a) || !Expand(node.b, &b)) return false;
        if (node.op == Op::kSub) {
          for (Monomial& m : b) m.c = -m.c;
        }
        *p = a;
        p->insert(p->end(), b.begin(), b.end());
        return p->size() <= 256;
      case Op::kMul:
        if (!Expand(node.a, &a) || !Expand(node.b, &b)) return false;
        p->clear();
        for (const Monomial& x : a) {
          for (const Monomial& y : b) {
            if (x.state >= 0 && y.state >= 0) return false;  // a product of states
            Monomial m{x.c * y.c, std::max(x.state, y.state), x.powers};
            for (const auto& kv : y.powers) m.powers[kv.first] += kv.second;
            p->push_back(std::move(m));
          }
        }
        return p->size() <= 256;
      case Op::kDiv:
        if (!Expand(node.a, &a) || !Expand(node.b, &b)) return false;
        if (b.size() != 1 || b[0].state >= 0) return false;
        *p = a;
        for (Monomial& m : *p) {
          m.c /= b[0].c;
          for (const auto& kv : b[0].powers) m.powers[kv.first] -= kv.second;
        }
        return true;
      case Op::kPow:
        if (node.b >= 0 || node.value != std::round(node.value) || std::abs(node.value) > 4) return false;
        if (!Expand(node.a, &a) || a.size() != 1 || a[0].state >= 0) return false;
        *p = a;
        (*p)[0].c = std::pow(a[0].c, node.value);
        for (auto& kv : (*p)[0].powers) kv.second *= static_cast<int>(node.value);
        return true;
      default: return false;
    }
  }

  // Whether node k is 0 whatever the parameters and amounts: a polynomial whose like terms cancel
  // (V - V). False when k is not a polynomial.
  bool IdenticallyZero(int k) {
    Polynomial p;
    if (!Expand(k, &p) || p.empty()) return false;
    std::map<std::pair<int, std::map<int, int>>, double> sum;
    for (const Monomial& m : p) {
      std::map<int, int> powers;
      for (const auto& kv : m.powers) {
        if (kv.second != 0) powers.insert(kv);
      }
      sum[{m.state, powers}] += m.c;
    }
    for (const auto& kv : sum) {
      if (kv.second != 0) return false;
    }
    return true;
  }

  // The terms of `k` (a row of A or C) as LinearTerms, or false with the reason. An output's
  // amount-free monomials go to `offsets` (its baseline); a d/dt has none (a zero-order input is
  // the second stage's, DetectLinearCoefficients).
  bool Terms(int k, int row, const std::string& what, std::vector<LinearTerm>* terms,
             std::vector<LinearTerm>* offsets = nullptr) {
    Polynomial p;
    if (!Expand(k, &p)) {
      out_.declarations.why_not_linear = what + " is not linear in the amounts with coefficients c·θa/θb";
      return false;
    }
    for (Monomial& m : p) {
      if (m.c == 0) continue;
      if (m.state < 0 && offsets == nullptr) {
        out_.declarations.why_not_linear = what + " has a term without an amount (a zero-order input)";
        return false;
      }
      LinearTerm t;
      t.row = row;
      t.col = m.state;
      t.sign = m.c;
      for (const auto& kv : m.powers) {
        if (kv.second == 0) continue;
        int* slot = kv.second == 1 ? &t.numerator : kv.second == -1 ? &t.denominator : nullptr;
        if (slot == nullptr || *slot >= 0) {
          out_.declarations.why_not_linear = what + " has a coefficient that is not c·θa/θb";
          return false;
        }
        *slot = kv.first;
      }
      (m.state < 0 ? offsets : terms)->push_back(t);
    }
    return true;
  }

  void DetectLinear() {
    out_.linear = false;
    bool monomials = true;
    for (int c = 0; c < n() && monomials; ++c) {
      monomials = Terms(out_.rhs[static_cast<size_t>(c)], c, "d/dt(" + out_.compartments[static_cast<size_t>(c)] + ")",
                        &out_.a_terms);
    }
    out_.c_terms.assign(out_.outputs.size(), {});
    std::vector<std::vector<LinearTerm>> offsets(out_.outputs.size());
    bool any_offset = false;
    for (size_t k = 0; k < out_.outputs.size() && monomials; ++k) {
      monomials = Terms(out_.outputs[k], 0, "output " + out_.output_names[k], &out_.c_terms[k], &offsets[k]) &&
                  !out_.c_terms[k].empty();  // an output that reads no amount: the second stage says so
      any_offset = any_offset || !offsets[k].empty();
    }
    if (monomials) {
      if (any_offset) out_.d_terms = std::move(offsets);
      out_.linear = true;
      return;
    }
    out_.a_terms.clear();
    out_.c_terms.clear();
    DetectLinearCoefficients();
  }

  // --- linear structure with coefficients that are any expression of the parameters ----------
  // Node k as Σ_s coef[s] · x_s + constant, with one coefficient node (reading no amount) per state
  // and an amount-free part (`constant`, −1: none). False, with `why`, when k is not linear in the
  // amounts. Coefficient nodes are new nodes of the graph; they become the derived coefficients ψ,
  // and a d/dt's constant part its zero-order input K0_<n> (pk/parameters.h).
  struct LinearForm {
    int constant = -1;
    std::map<int, int> coef;
  };
  bool IsZero(int k) const {
    const Node& node = g_[static_cast<size_t>(k)];
    return node.op == Op::kConstant && node.value == 0;
  }
  int Derived(Op op, int a, int b, const Node& at, int c = -1) {
    // 1·x, x·1 and x/1 are x; −c is a constant: parameters then stay terms of their own.
    const auto one = [&](int i) {
      return i >= 0 && g_[static_cast<size_t>(i)].op == Op::kConstant && g_[static_cast<size_t>(i)].value == 1;
    };
    if (op == Op::kMul && one(a)) return b;
    if ((op == Op::kMul || op == Op::kDiv) && one(b)) return a;
    if (op == Op::kNeg && g_[static_cast<size_t>(a)].op == Op::kConstant) {
      return Constant(-g_[static_cast<size_t>(a)].value, at);
    }
    Node node;
    node.op = op;
    node.a = a;
    node.b = b;
    node.c = c;
    node.line = at.line;
    node.column = at.column;
    return NewNode(node);
  }
  bool Linearize(int k, LinearForm* form, std::string* why) {
    const auto memo = linearized_.find(k);
    if (memo != linearized_.end()) {
      *form = memo->second;
      return true;
    }
    if (!LinearizeNode(k, form, why)) return false;
    linearized_[k] = *form;
    return true;
  }
  // A sum or difference of two forms (kAdd, kSub), or a choice between them (kSelect with `cond`).
  bool Combine(Op op, const LinearForm& a, const LinearForm& b, const Node& at, int cond, LinearForm* f) {
    if (a.constant >= 0 || b.constant >= 0) {
      const int ca = a.constant >= 0 ? a.constant : Constant(0, at);
      const int cb = b.constant >= 0 ? b.constant : Constant(0, at);
      f->constant = op == Op::kSelect ? Derived(op, cond, ca, at, cb) : Derived(op, ca, cb, at);
    }
    std::map<int, int> all = a.coef;
    all.insert(b.coef.begin(), b.coef.end());
    for (const auto& kv : all) {
      const auto ia = a.coef.find(kv.first), ib = b.coef.find(kv.first);
      const int ca = ia == a.coef.end() ? Constant(0, at) : ia->second;
      const int cb = ib == b.coef.end() ? Constant(0, at) : ib->second;
      f->coef[kv.first] = op == Op::kSelect ? Derived(op, cond, ca, at, cb) : Derived(op, ca, cb, at);
    }
    return true;
  }
  bool LinearizeNode(int k, LinearForm* f, std::string* why) {
    const Node node = g_[static_cast<size_t>(k)];  // a copy: new nodes may move the graph
    if (StateRead(k) < 0) {
      f->constant = k;
      return true;
    }
    LinearForm a, b;
    const auto side = [&](int i, LinearForm* form) {
      if (IsZero(i)) return true;  // an empty form
      return Linearize(i, form, why);
    };
    switch (node.op) {
      case Op::kInput: f->coef[node.input] = Constant(1, node); return true;
      case Op::kNeg:
        if (!Linearize(node.a, &a, why)) return false;
        for (const auto& kv : a.coef) f->coef[kv.first] = Derived(Op::kNeg, kv.second, -1, node);
        if (a.constant >= 0) f->constant = Derived(Op::kNeg, a.constant, -1, node);
        return true;
      case Op::kAdd:
      case Op::kSub:
        return side(node.a, &a) && side(node.b, &b) && Combine(node.op, a, b, node, -1, f);
      case Op::kSelect:
        if (StateRead(node.a) >= 0) break;
        return side(node.b, &a) && side(node.c, &b) && Combine(Op::kSelect, a, b, node, node.a, f);
      case Op::kMul:
      case Op::kDiv: {
        const bool amount_right = StateRead(node.b) >= 0;
        if (amount_right && (node.op == Op::kDiv || StateRead(node.a) >= 0)) break;
        const int factor = amount_right ? node.a : node.b;
        if (!Linearize(amount_right ? node.b : node.a, &a, why)) return false;
        for (const auto& kv : a.coef) f->coef[kv.first] = Derived(node.op, kv.second, factor, node);
        if (a.constant >= 0) f->constant = Derived(node.op, a.constant, factor, node);
        return true;
      }
      default: break;
    }
    *why = "is not linear in the amounts";
    return false;
  }

  // The terms of a row from a linear form: a constant, a parameter, or a derived coefficient ψ_k.
  void FormTerms(const LinearForm& form, int row, std::vector<LinearTerm>* terms) {
    for (const auto& kv : form.coef) {
      const Node& c = g_[static_cast<size_t>(kv.second)];
      if (c.op == Op::kConstant && c.value == 0) continue;
      terms->push_back(Term(kv.second, row, kv.first));
    }
  }
  // Coefficient node k at (row, col) as a term: a constant, a parameter, or a new ψ_k.
  LinearTerm Term(int k, int row, int col) {
    const Node& c = g_[static_cast<size_t>(k)];
    LinearTerm t;
    t.row = row;
    t.col = col;
    if (c.op == Op::kConstant) {
      t.sign = c.value;
    } else if (c.op == Op::kInput) {
      t.numerator = c.input - n();
    } else {
      t.numerator = static_cast<int>(out_.parameters.size() + out_.derived_roots.size());
      out_.derived_roots.push_back(k);
      out_.derived_reads.push_back(ParametersRead(k));
    }
    return t;
  }

  // The model parameters node k reads, in order.
  std::vector<int> ParametersRead(int k) const {
    std::vector<char> seen(g_.size(), 0);
    std::vector<int> stack{k}, reads;
    while (!stack.empty()) {
      const int i = stack.back();
      stack.pop_back();
      if (i < 0 || seen[static_cast<size_t>(i)]) continue;
      seen[static_cast<size_t>(i)] = 1;
      const Node& node = g_[static_cast<size_t>(i)];
      if (node.op == Op::kInput && node.input >= n()) reads.push_back(node.input - n());
      stack.insert(stack.end(), {node.a, node.b, node.c});
    }
    std::sort(reads.begin(), reads.end());
    return reads;
  }

  void DetectLinearCoefficients() {
    std::string why;
    std::vector<LinearForm> rows(static_cast<size_t>(n()));
    for (int c = 0; c < n(); ++c) {
      const std::string what = "d/dt(" + out_.compartments[static_cast<size_t>(c)] + ") ";
      if (!Linearize(out_.rhs[static_cast<size_t>(c)], &rows[static_cast<size_t>(c)], &why)) {
        out_.declarations.why_not_linear = what + why;
        return;
      }
      const std::string k0 = "K0_" + std::to_string(c + 1);
      const int constant = rows[static_cast<size_t>(c)].constant;
      const auto& declared = out_.declarations.modifiers;
      const bool in_param = std::any_of(declared.begin(), declared.end(), [&](const DeclaredParameter& m) {
        return m.name == k0;
      });
      if (constant >= 0 && !IsZero(constant) &&
          (in_param ||
           std::find(out_.modifier_names.begin(), out_.modifier_names.end(), k0) != out_.modifier_names.end())) {
        Fail(g_[static_cast<size_t>(out_.rhs[static_cast<size_t>(c)])],
             what + "has a term without an amount, which is compartment " + std::to_string(c + 1) +
                 "'s zero-order input, and " + (in_param ? "$PARAM declares " : "$PK computes ") + k0 +
                 ", which the event engine adds too: the input would count twice; keep one");
      }
    }
    std::vector<LinearForm> outputs(out_.outputs.size());
    for (size_t k = 0; k < outputs.size(); ++k) {
      // An amount-free part (a baseline, E0 + SLOPE·CE) is the output's offset d_k(θ).
      if (!Linearize(out_.outputs[k], &outputs[k], &why) || outputs[k].coef.empty()) {
        if (why.empty()) why = "reads no amount";
        out_.declarations.why_not_linear = "output " + out_.output_names[k] + " " + why;
        return;
      }
    }
    // A d/dt's amount-free part is the compartment's zero-order input, a modifier computed like $PK's.
    for (int c = 0; c < n(); ++c) {
      const int constant = rows[static_cast<size_t>(c)].constant;
      if (constant < 0 || IsZero(constant)) continue;
      out_.modifier_names.push_back("K0_" + std::to_string(c + 1));
      out_.modifier_roots.push_back(constant);
      out_.modifier_reads.push_back(ParametersRead(constant));
    }
    for (int c = 0; c < n(); ++c) FormTerms(rows[static_cast<size_t>(c)], c, &out_.a_terms);
    out_.c_terms.assign(outputs.size(), {});
    out_.d_terms.clear();
    for (size_t k = 0; k < outputs.size(); ++k) {
      FormTerms(outputs[k], 0, &out_.c_terms[k]);
      const int constant = outputs[k].constant;
      if (constant < 0 || IsZero(constant)) continue;
      out_.d_terms.resize(outputs.size());
      out_.d_terms[k].push_back(Term(constant, 0, -1));
    }
    out_.declarations.why_not_linear.clear();
    out_.linear = true;
  }

  const bool bind_etas_;
  std::vector<int> eta_input_;  // per η: its model parameter (bind_etas_ only)
  CompiledModel out_;
  std::vector<Node> g_;
  std::map<std::string, Symbol> symbols_;
  std::vector<double> defaults_;
  std::map<int, int> input_node_;
  std::vector<int> resolved_def_, def_state_, stack_;
  std::vector<int> modifier_definitions_;  // definitions that compute a dose modifier (F1 = … in $PK)
  std::vector<bool> used_, eta_used_;
  std::vector<int> state_read_;                              // per node: StateRead, -2 not yet known
  std::map<int, std::pair<bool, Polynomial>> expanded_;      // per node: Expand
  std::map<int, LinearForm> linearized_;                     // per node: Linearize
};

}  // namespace

CompiledModel Analyse(ModelText text, bool bind_etas) { return Analyser(std::move(text), bind_etas).Run(); }

}  // namespace lang
}  // namespace internal
}  // namespace pk
