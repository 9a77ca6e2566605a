// The expression graph of a model file, and its evaluation on any scalar type (not installed).
//
// A model file's definitions, right-hand sides and outputs are nodes of one graph (a DAG: a name
// used twice is one node). Evaluation runs a Program, the nodes a set of roots needs in
// topological order, over a slot per node. Because Run is a template on the scalar type, one
// program gives values (double), forward derivatives (pk::Dual), tape recordings for reverse mode
// (pk::TapeScalar) and anything else libpk differentiates with: the model's f_x, f_θ, g_x and g_θ
// are exact, and no code is generated or compiled.
#ifndef PK_SRC_LANGUAGE_EXPRESSION_H_
#define PK_SRC_LANGUAGE_EXPRESSION_H_

#include <cmath>
#include <string>
#include <vector>

namespace pk {
namespace internal {
namespace lang {

enum class Op : unsigned char {
  kConstant,
  kInput,  // a state (input < num_states) or a parameter
  kSymbol, // a name not yet resolved (parser output only)
  kNeg, kAdd, kSub, kMul, kDiv, kPow,
  kExp, kLog, kLog10, kSqrt, kAbs, kLogistic, kLogit,
  kMin, kMax,
  kLess, kLessEqual, kGreater, kGreaterEqual, kEqual, kNotEqual, kAnd, kOr, kNot,
  kSelect,  // a ? b : c
};

struct Node {
  Op op = Op::kConstant;
  int a = -1, b = -1, c = -1;  // operands (node indices)
  double value = 0;            // kConstant
  int input = -1;              // kInput
  std::string name;            // kSymbol (upper case)
  int line = 0, column = 0;    // where the node was written
};

/// Number of operands an operation takes.
int Arity(Op op);

inline double ValueOf(double v) { return v; }
template <typename T>
double ValueOf(const T& v) {
  return v.value();
}

/// The nodes that `roots` need, in evaluation order, as slot-addressed instructions.
class Program {
 public:
  Program() = default;
  Program(const std::vector<Node>& graph, const std::vector<int>& roots, int num_states);

  int num_roots() const { return static_cast<int>(roots_.size()); }
  int size() const { return static_cast<int>(code_.size()); }

  /// out[i] = value of root i, with states x and parameters p; `slots` is scratch (resized here).
  template <typename T>
  void Run(const T* x, const T* p, T* out, std::vector<T>* slots) const;

 private:
  struct Instruction {
    Op op;
    int a, b, c;    // operand slots
    double value;   // constant, or a constant exponent of kPow (b < 0)
    int input;
  };
  std::vector<Instruction> code_;
  std::vector<int> roots_;  // slot of each root
  int num_states_ = 0;
};

template <typename T>
void Program::Run(const T* x, const T* p, T* out, std::vector<T>* slots) const {
  using std::exp;
  using std::log;
  using std::pow;
  using std::sqrt;
  using std::abs;
  if (slots->size() < code_.size()) slots->resize(code_.size());
  T* s = slots->data();
  const T one(1.0), zero(0.0);
  for (size_t k = 0; k < code_.size(); ++k) {
    const Instruction& i = code_[k];
    switch (i.op) {
      case Op::kConstant: s[k] = T(i.value); break;
      case Op::kInput: s[k] = i.input < num_states_ ? x[i.input] : p[i.input - num_states_]; break;
      case Op::kSymbol: s[k] = zero; break;  // never: resolved before a Program is built
      case Op::kNeg: s[k] = -s[i.a]; break;
      case Op::kAdd: s[k] = s[i.a] + s[i.b]; break;
      case Op::kSub: s[k] = s[i.a] - s[i.b]; break;
      case Op::kMul: s[k] = s[i.a] * s[i.b]; break;
      case Op::kDiv: s[k] = s[i.a] / s[i.b]; break;
      case Op::kPow: s[k] = i.b < 0 ? T(pow(s[i.a], i.value)) : T(pow(s[i.a], s[i.b])); break;
      case Op::kExp: s[k] = exp(s[i.a]); break;
      case Op::kLog: s[k] = log(s[i.a]); break;
      case Op::kLog10: s[k] = log(s[i.a]) / std::log(10.0); break;
      case Op::kSqrt: s[k] = sqrt(s[i.a]); break;
      case Op::kAbs: s[k] = abs(s[i.a]); break;
      case Op::kLogistic: s[k] = one / (one + exp(-s[i.a])); break;
      case Op::kLogit: s[k] = log(s[i.a] / (one - s[i.a])); break;
      case Op::kMin: s[k] = ValueOf(s[i.b]) < ValueOf(s[i.a]) ? s[i.b] : s[i.a]; break;
      case Op::kMax: s[k] = ValueOf(s[i.b]) > ValueOf(s[i.a]) ? s[i.b] : s[i.a]; break;
      case Op::kLess: s[k] = ValueOf(s[i.a]) < ValueOf(s[i.b]) ? one : zero; break;
      case Op::kLessEqual: s[k] = ValueOf(s[i.a]) <= ValueOf(s[i.b]) ? one : zero; break;
      case Op::kGreater: s[k] = ValueOf(s[i.a]) > ValueOf(s[i.b]) ? one : zero; break;
      case Op::kGreaterEqual: s[k] = ValueOf(s[i.a]) >= ValueOf(s[i.b]) ? one : zero; break;
      case Op::kEqual: s[k] = ValueOf(s[i.a]) == ValueOf(s[i.b]) ? one : zero; break;
      case Op::kNotEqual: s[k] = ValueOf(s[i.a]) != ValueOf(s[i.b]) ? one : zero; break;
      case Op::kAnd: s[k] = ValueOf(s[i.a]) != 0 && ValueOf(s[i.b]) != 0 ? one : zero; break;
      case Op::kOr: s[k] = ValueOf(s[i.a]) != 0 || ValueOf(s[i.b]) != 0 ? one : zero; break;
      case Op::kNot: s[k] = ValueOf(s[i.a]) == 0 ? one : zero; break;
      case Op::kSelect: s[k] = ValueOf(s[i.a]) != 0 ? s[i.b] : s[i.c]; break;
    }
  }
  for (size_t r = 0; r < roots_.size(); ++r) out[r] = s[roots_[r]];
}

}  // namespace lang
}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_LANGUAGE_EXPRESSION_H_
