// The recursive-descent parser of model files (grammar: docs/model_language.md).
#include <algorithm>
#include <cmath>
#include <initializer_list>
#include <iterator>
#include <map>
#include <utility>

#include "internal_text.h"
#include "language/lexer.h"
#include "language/model_text.h"
#include "pk/error.h"

namespace pk {
namespace internal {
namespace lang {
namespace {

using Kind = Token::Kind;

// The functions of the language: name, operation, number of arguments (-1: two or more).
struct Function {
  const char* name;
  Op op;
  int args;
};
const Function kFunctions[] = {
    {"EXP", Op::kExp, 1},         {"LOG", Op::kLog, 1},        {"LN", Op::kLog, 1},
    {"LOG10", Op::kLog10, 1},     {"SQRT", Op::kSqrt, 1},      {"ABS", Op::kAbs, 1},
    {"LOGISTIC", Op::kLogistic, 1}, {"EXPIT", Op::kLogistic, 1}, {"INV_LOGIT", Op::kLogistic, 1},
    {"LOGIT", Op::kLogit, 1},     {"POW", Op::kPow, 2},        {"MIN", Op::kMin, -1},
    {"MAX", Op::kMax, -1},        {"IFELSE", Op::kSelect, 3},
};

std::vector<std::string> FunctionNames() {
  std::vector<std::string> names;
  for (const Function& f : kFunctions) names.push_back(ToLower(f.name));
  return names;
}

class Parser {
 public:
  Parser(std::vector<Token> tokens, const std::string& text, ModelText* out)
      : tok_(std::move(tokens)), text_(text), m_(out) {}

  void Run() {
    SkipNewlines();
    while (Peek().kind != Kind::kEnd) {
      if (Peek().kind != Kind::kBlock) Fail(Peek(), "expected a block heading such as $PARAM, $CMT or $ODE");
      const Token block = Next();
      Block(block);
      SkipNewlines();
    }
    InitialAmounts();
  }

 private:
  // --- tokens -----------------------------------------------------------------------------
  const Token& Peek(int ahead = 0) const { return tok_[std::min(pos_ + ahead, tok_.size() - 1)]; }
  Token Next() { return tok_[std::min(pos_++, tok_.size() - 1)]; }
  bool IsPunct(const char* p, int ahead = 0) const {
    return Peek(ahead).kind == Kind::kPunct && Peek(ahead).text == p;
  }
  bool Accept(const char* p) {
    if (!IsPunct(p)) return false;
    ++pos_;
    return true;
  }
  [[noreturn]] void Fail(const Token& t, const std::string& message) const {
    throw InputError(m_->source, t.line, t.column, message);
  }
  static std::string Describe(const Token& t) {
    switch (t.kind) {
      case Kind::kNewline: return "the end of the line";
      case Kind::kEnd: return "the end of the file";
      case Kind::kBlock: return "$" + t.text;
      default: return "'" + Printable(t.text) + "'";
    }
  }
  void Expect(const char* p, const char* what) {
    if (!Accept(p)) Fail(Peek(), std::string("expected ") + what + ", found " + Describe(Peek()));
  }
  std::string Name(const char* what) {
    if (Peek().kind != Kind::kIdentifier) Fail(Peek(), std::string("expected ") + what + ", found " + Describe(Peek()));
    return ToUpper(Next().text);
  }
  void EndOfStatement() {
    if (Peek().kind == Kind::kNewline) {
      ++pos_;
      return;
    }
    if (Peek().kind == Kind::kEnd || Peek().kind == Kind::kBlock) return;
    Fail(Peek(), "expected the end of the line, found " + Describe(Peek()));
  }
  void SkipNewlines() {
    while (Peek().kind == Kind::kNewline) ++pos_;
  }
  bool AtBlockEnd() const { return Peek().kind == Kind::kBlock || Peek().kind == Kind::kEnd; }
  // The source text of the tokens from `first` up to the end of the line (a unit: "mg/L").
  std::string RestOfLine() {
    if (Peek().kind == Kind::kNewline || AtBlockEnd()) return "";
    const Token first = Peek();
    Token last = first;
    while (Peek().kind != Kind::kNewline && !AtBlockEnd()) last = Next();
    return text_.substr(first.offset, last.offset + last.length - first.offset);
  }
  double SignedNumber(const char* what) {
    const bool negative = Accept("-");
    if (!negative) Accept("+");
    if (Peek().kind == Kind::kIdentifier && ToUpper(Peek().text) == "INF") {
      ++pos_;
      return negative ? -INFINITY : INFINITY;
    }
    if (Peek().kind != Kind::kNumber) Fail(Peek(), std::string("expected ") + what + ", found " + Describe(Peek()));
    const double v = Next().number;
    return negative ? -v : v;
  }

  // --- blocks -----------------------------------------------------------------------------
  void Block(const Token& block) {
    const std::string& b = block.text;
    if (b == "PROBLEM" || b == "PROB") return Problem(block);
    // Statements start on the next line.
    EndOfStatement();
    SkipNewlines();
    if (b == "PARAM" || b == "PARAMETERS" || b == "THETA") return Lines(&Parser::ParameterLine);
    if (b == "COVARIATE" || b == "COVARIATES" || b == "COV") return Lines(&Parser::CovariateLine);
    if (b == "OMEGA" || b == "ETA") return Lines(&Parser::EtaLine);
    if (b == "CMT" || b == "COMPARTMENTS") return Lines(&Parser::CompartmentLine);
    if (b == "PK" || b == "MAIN" || b == "INDIVIDUAL") return Statements(true);
    if (b == "ODE" || b == "DES") return Statements(false);
    if (b == "OUTPUT" || b == "OUT") return Lines(&Parser::OutputLine);
    if (b == "ERROR" || b == "SIGMA") return Lines(&Parser::ErrorLine);
    if (b == "INIT") return Lines(&Parser::InitLine);
    Fail(block, "unknown block $" + b +
                    " (the blocks are $PROBLEM, $PARAM, $COVARIATE, $OMEGA, $CMT, $INIT, $PK, $ODE, $OUTPUT, $ERROR)");
  }

  void Problem(const Token& block) {
    const Token text = Peek().kind == Kind::kText ? Next() : block;
    const std::string line = text.kind == Kind::kText ? text.text : "";
    if (line.empty()) Fail(block, "$PROBLEM needs the model's name (and, after it, a description)");
    const size_t space = line.find_first_of(" \t");
    m_->name = line.substr(0, space);
    m_->name_at = {text.line, text.column};
    std::string rest = space == std::string::npos ? "" : Trim(line.substr(space));
    if (rest.size() >= 2 && rest.front() == '"' && rest.back() == '"') rest = rest.substr(1, rest.size() - 2);
    m_->description = rest;
    EndOfStatement();
  }

  void Lines(void (Parser::*line)()) {
    while (!AtBlockEnd()) {
      (this->*line)();
      EndOfStatement();
      SkipNewlines();
    }
  }

  // NAME = initial [(lower, upper)] [unit]
  void ParameterLine() {
    ParameterDecl p;
    p.at = {Peek().line, Peek().column};
    p.name = Name("a parameter name");
    Expect("=", "'=' and the initial value");
    p.initial = SignedNumber("the initial value");
    if (Accept("(")) {
      p.has_bounds = true;
      p.lower = IsPunct(",") ? -INFINITY : SignedNumber("a lower bound");
      Expect(",", "',' between the bounds");
      p.upper = IsPunct(")") ? INFINITY : SignedNumber("an upper bound");
      Expect(")", "')' after the bounds");
    }
    p.unit = RestOfLine();
    m_->parameters.push_back(std::move(p));
  }

  // NAME [= reference] [unit]
  void CovariateLine() {
    CovariateDecl c;
    c.at = {Peek().line, Peek().column};
    c.name = Name("a covariate (a dataset column)");
    if (Accept("=")) c.reference = SignedNumber("a reference value");
    c.unit = RestOfLine();
    m_->covariates.push_back(std::move(c));
  }

  // NAME ~ variance
  // NAME ~ ω² [FIX]   or   NAME + NAME … ~ c(ω²₁, ω₂₁, ω²₂, …) [FIX]: a block, its lower triangle
  // by rows as in NONMEM's $OMEGA BLOCK(n) (nlmixr2 writes the same with c(); block() is accepted too).
  void EtaLine() {
    OmegaLine line;
    line.at = {Peek().line, Peek().column};
    do {
      EtaDecl e;
      e.at = {Peek().line, Peek().column};
      e.name = Name("a random effect's name");
      line.etas.push_back(static_cast<int>(m_->etas.size()));
      m_->etas.push_back(std::move(e));
    } while (Accept("+"));
    const size_t n = line.etas.size();
    Expect("~", n == 1 ? "'~' and its variance ω²" : "'~' and the block's values, c(…)");
    if (Peek().kind == Kind::kIdentifier && ToUpper(Peek().text) == "SAME") {
      SameBlock(Next(), &line);
      return;
    }
    const bool list = Peek().kind == Kind::kIdentifier && IsPunct("(", 1) &&
                      (ToLower(Peek().text) == "c" || ToLower(Peek().text) == "block");
    if (list) {
      pos_ += 2;
      do {
        line.lower.push_back(SignedNumber("a value of Ω's block"));
      } while (Accept(","));
      Expect(")", "')' after the block's values");
    } else {
      if (n > 1) Fail(Peek(), "expected the block's values, c(ω²₁, ω₂₁, ω²₂, …), found " + Describe(Peek()));
      line.lower.push_back(SignedNumber("the variance ω²"));
    }
    if (line.lower.size() != n * (n + 1) / 2) {
      Token at;
      at.line = line.at.line;
      at.column = line.at.column;
      Fail(at, "a block of " + std::to_string(n) + " random effects needs " + std::to_string(n * (n + 1) / 2) +
               " values (the lower triangle by rows, as NONMEM's BLOCK(" + std::to_string(n) + ")), not " +
               std::to_string(line.lower.size()));
    }
    if (Peek().kind == Kind::kIdentifier) {
      const Token word = Next();
      if (ToUpper(word.text) != "FIX" && ToUpper(word.text) != "FIXED") {
        Fail(word, "expected FIX or the end of the line, found " + Describe(word));
      }
      line.fixed = true;
    }
    for (size_t i = 0; i < n; ++i) {
      m_->etas[static_cast<size_t>(line.etas[i])].variance = line.lower[(i + 1) * (i + 2) / 2 - 1];
    }
    m_->omega.push_back(std::move(line));
  }

  // NAME [+ NAME …] ~ SAME: NONMEM's $OMEGA BLOCK(n) SAME, the line before's block repeated for
  // other η (inter-occasion variability: one η per occasion, one variance). Its values are that
  // block's, estimated or fixed with it.
  void SameBlock(const Token& word, OmegaLine* line) {
    if (m_->omega.empty()) Fail(word, "SAME repeats the $OMEGA line before it, and there is none");
    const OmegaLine& before = m_->omega.back();
    const size_t n = line->etas.size();
    if (before.etas.size() != n) {
      Fail(word, "SAME repeats the block before it, of " + std::to_string(before.etas.size()) +
                     " random effect" + (before.etas.size() > 1 ? "s" : "") + ", so this line needs as many, not " +
                     std::to_string(n));
    }
    line->lower = before.lower;
    line->fixed = before.fixed;
    line->same = true;
    if (Peek().kind == Kind::kIdentifier) Fail(Peek(), "expected the end of the line after SAME, found " + Describe(Peek()));
    for (size_t i = 0; i < n; ++i) {
      m_->etas[static_cast<size_t>(line->etas[i])].variance = line->lower[(i + 1) * (i + 2) / 2 - 1];
    }
    m_->omega.push_back(std::move(*line));
  }

  // NAME [dose] [central]
  void CompartmentLine() {
    CompartmentDecl c;
    c.at = {Peek().line, Peek().column};
    c.name = Name("a compartment name");
    while (Peek().kind == Kind::kIdentifier) {
      const Token a = Next();
      const std::string attr = ToLower(a.text);
      if (attr == "dose" || attr == "depot") {
        c.dose = true;
      } else if (attr == "central" || attr == "obs") {
        c.central = true;
      } else {
        Fail(a, "unknown compartment attribute '" + a.text + "' (the attributes are dose and central)");
      }
    }
    m_->compartments.push_back(std::move(c));
  }

  // NAME = expression
  void OutputLine() {
    OutputDecl o;
    o.at = {Peek().line, Peek().column};
    o.name = Name("an output name");
    Expect("=", "'=' and the output's expression");
    o.node = Expression();
    m_->outputs.push_back(std::move(o));
  }

  // COMPARTMENT = expression [, COMPARTMENT = expression …]: its amount at time 0 and after a
  // reset (mrgsolve's $INIT), which becomes X0_<n> computed after $PK (InitialAmounts).
  void InitLine() {
    do {
      Definition d;
      d.at = {Peek().line, Peek().column};
      d.name = Name("a compartment name");
      Expect("=", "'=' and the compartment's initial amount");
      d.node = Expression();
      d.in_pk = true;
      inits_.push_back(std::move(d));
    } while (Accept(","));
  }

  // $INIT's lines as X0_<n> definitions after every $PK definition (which they may read). A
  // compartment that does not exist, or an amount given twice, is an error at its line.
  void InitialAmounts() {
    // nlmixr2's CMT(0) = … in $PK (named "CMT(0)" by Statement, merged through if/else) joins
    // $INIT's lines, all in the order written (a merged if/else at its first branch's place).
    std::vector<Definition> from_pk;
    auto& defs = m_->definitions;
    for (auto it = defs.begin(); it != defs.end();) {
      if (it->name.size() > 3 && it->name.compare(it->name.size() - 3, 3, "(0)") == 0) {
        from_pk.push_back(std::move(*it));
        from_pk.back().name.resize(from_pk.back().name.size() - 3);
        it = defs.erase(it);
      } else {
        ++it;
      }
    }
    inits_.insert(inits_.begin(), std::make_move_iterator(from_pk.begin()), std::make_move_iterator(from_pk.end()));
    std::stable_sort(inits_.begin(), inits_.end(), [](const Definition& a, const Definition& b) {
      return a.at.line != b.at.line ? a.at.line < b.at.line : a.at.column < b.at.column;
    });
    for (Definition& d : inits_) {
      Token at;
      at.line = d.at.line;
      at.column = d.at.column;
      const auto& cmts = m_->compartments;
      const auto it = std::find_if(cmts.begin(), cmts.end(), [&](const CompartmentDecl& c) { return c.name == d.name; });
      if (it == cmts.end()) {
        std::string names;
        for (const CompartmentDecl& c : cmts) names += (names.empty() ? "" : ", ") + c.name;
        Fail(at, "the initial amount of " + d.name + " is set, but it is not a compartment (the compartments are " +
                     (names.empty() ? std::string("none: declare them in $CMT") : names) + ")");
      }
      const std::string x0 = "X0_" + std::to_string(it - cmts.begin() + 1);
      const std::string cmt = d.name;
      for (const Definition& e : m_->definitions) {
        if (e.name != x0) continue;
        if (!e.initial_of.empty()) {
          Fail(at, "the initial amount of " + cmt + " is set twice: here and at line " + std::to_string(e.at.line));
        }
        Fail(at, "the initial amount of " + cmt + " is given twice: here and as " + x0 + " at line " +
                     std::to_string(e.at.line) + (e.in_pk ? "" : " of $ODE"));
      }
      for (const ParameterDecl& p : m_->parameters) {
        if (p.name == x0) Fail(at, "the initial amount of " + cmt + " is given twice: here and as " + x0 +
                                       " in $PARAM at line " + std::to_string(p.at.line));
      }
      d.initial_of = cmt;
      d.name = x0;
      m_->definitions.push_back(std::move(d));
    }
  }

  // OUTPUT ~ model[(σ, ...)]
  void ErrorLine() {
    ErrorDecl e;
    e.at = {Peek().line, Peek().column};
    e.output = Name("an output name");
    Expect("~", "'~' and an error model");
    e.model = ToLower(Name("an error model (additive, proportional, combined or exponential)"));
    if (Accept("(")) {
      do {
        e.sigma.push_back(SignedNumber("an initial σ"));
      } while (Accept(","));
      Expect(")", "')' after the σ values");
    }
    m_->errors.push_back(std::move(e));
  }

  // --- statements ($PK, $ODE) ---------------------------------------------------------------
  using Assignments = std::vector<std::pair<Definition, bool>>;  // bool: a d/dt

  void Statements(bool pk) {
    while (!AtBlockEnd()) {
      Assignments list;
      Statement(pk, &list);
      for (auto& a : list) Store(std::move(a.first), a.second);
      SkipNewlines();
    }
  }

  void Store(Definition d, bool derivative) {
    if (derivative) {
      m_->derivatives.push_back({d.name, d.node, d.at});
    } else {
      m_->definitions.push_back(std::move(d));
    }
  }

  // One statement: an assignment, a derivative, or an if/else whose branches assign.
  void Statement(bool pk, Assignments* out) {
    const Token first = Peek();
    if (first.kind == Kind::kIdentifier && ToUpper(first.text) == "IF") return IfStatement(pk, out);
    Definition d;
    d.at = {first.line, first.column};
    d.in_pk = pk;
    bool derivative = false;
    if (first.kind == Kind::kIdentifier && ToUpper(first.text) == "D" && IsPunct("/", 1) &&
        Peek(2).kind == Kind::kIdentifier && ToUpper(Peek(2).text) == "DT") {
      pos_ += 3;
      derivative = true;
    } else if (first.kind == Kind::kIdentifier && ToUpper(first.text) == "DADT" && IsPunct("(", 1)) {
      pos_ += 1;
      derivative = true;
    }
    if (!derivative && first.kind == Kind::kIdentifier && ToUpper(first.text) == "A_0" && IsPunct("(", 1)) {
      // NONMEM's A_0(n) = …: the initial amount in compartment n, libpk's X0_n.
      pos_ += 2;
      const Token n = Peek();
      if (n.kind != Kind::kNumber || !(n.number >= 1) || n.number != std::floor(n.number) || n.number > 999) {
        Fail(n, "expected a compartment number in A_0(…), found " + Describe(n));
      }
      ++pos_;
      Expect(")", "')'");
      d.name = "X0_" + std::to_string(static_cast<int>(n.number));
      Expect("=", "'='");
      d.node = Expression();
      EndOfStatement();
      out->push_back({std::move(d), false});
      return;
    }
    if (!derivative && first.kind == Kind::kIdentifier && IsPunct("(", 1) && Peek(2).kind == Kind::kNumber &&
        Peek(2).number == 0 && IsPunct(")", 3)) {
      if (!pk) Fail(first, "an initial amount, " + first.text + "(0), belongs in $PK or $INIT, not in $ODE");
      // nlmixr2's CMT(0) = …: the compartment's initial amount, as a line of $INIT (InitialAmounts).
      pos_ += 4;
      d.name = ToUpper(first.text) + "(0)";
      Expect("=", "'=' and the compartment's initial amount");
      d.node = Expression();
      EndOfStatement();
      out->push_back({std::move(d), false});
      return;
    }
    if (derivative) {
      if (pk) Fail(first, "a derivative belongs in $ODE, not in $PK");
      Expect("(", "'(' and a compartment name");
      d.name = Name("a compartment name");
      Expect(")", "')'");
    } else {
      d.name = Name("a name to define, d/dt(COMPARTMENT) or if");
    }
    Expect("=", "'='");
    d.node = Expression();
    EndOfStatement();
    out->push_back({std::move(d), derivative});
  }

  // if (c) { … } [else if (c) { … }]… [else { … }]: each name assigned in one branch must be
  // assigned in every branch, and becomes ifelse(c, then, else).
  void IfStatement(bool pk, Assignments* out) {
    const Token head = Next();
    Expect("(", "'(' and a condition after if");
    const int cond = Expression();
    Expect(")", "')' after the condition");
    Assignments then_list = Braced(pk);
    Assignments else_list;
    bool has_else = false;
    const size_t save = pos_;
    SkipNewlines();
    if (Peek().kind == Kind::kIdentifier && ToUpper(Peek().text) == "ELSE") {
      ++pos_;
      has_else = true;
      if (Peek().kind == Kind::kIdentifier && ToUpper(Peek().text) == "IF") {
        IfStatement(pk, &else_list);
      } else {
        else_list = Braced(pk);
      }
    } else {
      pos_ = save;
      EndOfStatement();
    }
    Merge(head, cond, then_list, else_list, has_else, out);
  }

  Assignments Braced(bool pk) {
    SkipNewlines();
    Expect("{", "'{'");
    Assignments list;
    SkipNewlines();
    while (!Accept("}")) {
      if (AtBlockEnd()) Fail(Peek(), "expected '}' to close the branch, found " + Describe(Peek()));
      Statement(pk, &list);
      SkipNewlines();
    }
    return list;
  }

  void Merge(const Token& head, int cond, const Assignments& a, const Assignments& b, bool has_else,
             Assignments* out) {
    std::map<std::string, const std::pair<Definition, bool>*> in_a, in_b;
    for (const auto& x : a) in_a[(x.second ? "d/dt " : "") + x.first.name] = &x;
    for (const auto& x : b) in_b[(x.second ? "d/dt " : "") + x.first.name] = &x;
    for (const auto* list : {&a, &b}) {
      for (const auto& x : *list) {
        const std::string key = (x.second ? "d/dt " : "") + x.first.name;
        const bool both = in_a.count(key) && in_b.count(key);
        if (!both) {
          Fail(head, "if: " + (x.second ? "d/dt(" + x.first.name + ")" : x.first.name) + " is assigned " +
                         (in_a.count(key) ? "when the condition holds" : "in the else branch") + " but not " +
                         (in_a.count(key) ? (has_else ? "in the else branch" : "otherwise (add an else)")
                                          : "when it holds") +
                         "; every branch must assign the same names");
        }
      }
    }
    for (const auto& x : a) {
      const auto* y = in_b[(x.second ? "d/dt " : "") + x.first.name];
      Definition d = x.first;
      d.node = Add(Op::kSelect, cond, x.first.node, y->first.node, head);
      out->push_back({std::move(d), x.second});
    }
  }

  // --- expressions --------------------------------------------------------------------------
  int Add(Op op, int a, int b, int c, const Token& at) {
    Node n;
    n.op = op;
    n.a = a;
    n.b = b;
    n.c = c;
    n.line = at.line;
    n.column = at.column;
    m_->graph.push_back(std::move(n));
    return static_cast<int>(m_->graph.size()) - 1;
  }

  using OperatorList = std::initializer_list<std::pair<const char*, Op>>;

  // operand {operator operand}, left-associative: a - b - c = (a - b) - c.
  int LeftAssociative(int (Parser::*operand)(), OperatorList ops) {
    int left = (this->*operand)();
    for (;;) {
      const std::pair<const char*, Op>* match = nullptr;
      for (const auto& op : ops) {
        if (IsPunct(op.first)) match = &op;
      }
      if (match == nullptr) return left;
      const Token t = Next();
      const int right = (this->*operand)();
      left = Add(match->second, left, right, -1, t);
    }
  }

  int Expression() { return Or(); }
  int Or() { return LeftAssociative(&Parser::And, {{"||", Op::kOr}}); }
  int And() { return LeftAssociative(&Parser::Comparison, {{"&&", Op::kAnd}}); }
  int Comparison() {
    const int left = Sum();
    static const std::pair<const char*, Op> kOps[] = {{"<", Op::kLess}, {"<=", Op::kLessEqual},
                                                      {">", Op::kGreater}, {">=", Op::kGreaterEqual},
                                                      {"==", Op::kEqual}, {"!=", Op::kNotEqual}};
    for (const auto& op : kOps) {
      if (IsPunct(op.first)) {
        const Token t = Next();
        const int right = Sum();
        return Add(op.second, left, right, -1, t);
      }
    }
    if (IsPunct("=")) Fail(Peek(), "'=' in an expression: write '==' to compare");
    return left;
  }
  int Sum() { return LeftAssociative(&Parser::Product, {{"+", Op::kAdd}, {"-", Op::kSub}}); }
  int Product() { return LeftAssociative(&Parser::Unary, {{"*", Op::kMul}, {"/", Op::kDiv}}); }
  int Unary() {
    if (IsPunct("-")) {
      const Token op = Next();
      return Add(Op::kNeg, Unary(), -1, -1, op);
    }
    if (IsPunct("!")) {
      const Token op = Next();
      return Add(Op::kNot, Unary(), -1, -1, op);
    }
    if (Accept("+")) return Unary();
    return Power();
  }
  int Power() {
    const int base = Primary();
    if (IsPunct("^") || IsPunct("**")) {
      const Token op = Next();
      return Add(Op::kPow, base, Unary(), -1, op);  // right-associative: 2^3^2 = 2^(3^2)
    }
    return base;
  }
  int Primary() {
    const Token t = Peek();
    if (t.kind == Kind::kNumber) {
      ++pos_;
      const int n = Add(Op::kConstant, -1, -1, -1, t);
      m_->graph[n].value = t.number;
      return n;
    }
    if (Accept("(")) {
      const int e = Expression();
      Expect(")", "')'");
      return e;
    }
    if (t.kind != Kind::kIdentifier) Fail(t, "expected a number, a name or '(', found " + Describe(t));
    ++pos_;
    if (IsPunct("(")) return Call(t);
    const int n = Add(Op::kSymbol, -1, -1, -1, t);
    m_->graph[n].name = ToUpper(t.text);
    return n;
  }
  int Call(const Token& name) {
    const std::string upper = ToUpper(name.text);
    const Function* f = nullptr;
    for (const Function& g : kFunctions) {
      if (upper == g.name) f = &g;
    }
    if (f == nullptr) {
      const std::string closest = ClosestName(ToLower(name.text), FunctionNames());
      Fail(name, "unknown function '" + name.text + "'" + (closest.empty() ? "" : " (did you mean " + closest + "?)") +
                     "; the functions are " + Join(FunctionNames(), ", "));
    }
    Expect("(", "'('");
    std::vector<int> args;
    if (!IsPunct(")")) {
      do {
        args.push_back(Expression());
      } while (Accept(","));
    }
    Expect(")", "')' after the arguments");
    const int n = static_cast<int>(args.size());
    if ((f->args > 0 && n != f->args) || (f->args < 0 && n < 2)) {
      Fail(name, ToLower(f->name) + "() takes " +
                     (f->args < 0 ? std::string("two or more arguments") : std::to_string(f->args) + " argument" +
                                                                              (f->args > 1 ? "s" : "")) +
                     ", not " + std::to_string(n));
    }
    if (f->args < 0) {  // min(a, b, c) = min(min(a, b), c)
      int acc = args[0];
      for (int i = 1; i < n; ++i) acc = Add(f->op, acc, args[static_cast<size_t>(i)], -1, name);
      return acc;
    }
    return Add(f->op, args[0], n > 1 ? args[1] : -1, n > 2 ? args[2] : -1, name);
  }

  std::vector<Token> tok_;
  size_t pos_ = 0;
  std::vector<Definition> inits_;  // $INIT's lines, named by compartment until InitialAmounts
  const std::string& text_;
  ModelText* m_;
};

}  // namespace

ModelText Parse(const std::string& text, const std::string& source) {
  ModelText m;
  m.source = source;
  Parser(Tokenize(text, source), text, &m).Run();
  return m;
}

}  // namespace lang
}  // namespace internal
}  // namespace pk
