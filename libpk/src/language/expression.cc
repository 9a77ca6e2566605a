#include "language/expression.h"

#include <algorithm>
#include <stdexcept>

namespace pk {
namespace internal {
namespace lang {

int Arity(Op op) {
  switch (op) {
    case Op::kConstant:
    case Op::kInput:
    case Op::kSymbol: return 0;
    case Op::kNeg:
    case Op::kExp:
    case Op::kLog:
    case Op::kLog10:
    case Op::kSqrt:
    case Op::kAbs:
    case Op::kLogistic:
    case Op::kLogit:
    case Op::kNot: return 1;
    case Op::kSelect: return 3;
    default: return 2;
  }
}

Program::Program(const std::vector<Node>& graph, const std::vector<int>& roots, int num_states)
    : num_states_(num_states) {
  // Depth-first order from the roots gives operands before their users; each node once.
  std::vector<int> slot(graph.size(), -1);
  std::vector<std::pair<int, int>> stack;  // node, next operand to visit
  for (int root : roots) {
    if (slot[static_cast<size_t>(root)] < 0) stack.push_back({root, 0});
    while (!stack.empty()) {
      auto& top = stack.back();
      const Node& node = graph[static_cast<size_t>(top.first)];
      const int operands[3] = {node.a, node.b, node.c};
      if (top.second < 3) {
        const int o = operands[top.second++];
        if (o >= 0 && slot[static_cast<size_t>(o)] < 0) stack.push_back({o, 0});
        continue;
      }
      if (node.op == Op::kSymbol) throw std::logic_error("an unresolved name in a model program");
      Instruction i{node.op, -1, -1, -1, node.value, node.input};
      i.a = node.a >= 0 ? slot[static_cast<size_t>(node.a)] : -1;
      i.b = node.b >= 0 ? slot[static_cast<size_t>(node.b)] : -1;
      i.c = node.c >= 0 ? slot[static_cast<size_t>(node.c)] : -1;
      slot[static_cast<size_t>(top.first)] = static_cast<int>(code_.size());
      code_.push_back(i);
      stack.pop_back();
    }
    roots_.push_back(slot[static_cast<size_t>(root)]);
  }
}

}  // namespace lang
}  // namespace internal
}  // namespace pk
