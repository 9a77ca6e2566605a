// libpk: a scalar that carries which inputs a value depends on, not the value.
//
// libpk evaluates a model's right-hand side on it once to find the sparsity pattern of [f_x f_θ]:
// every operation's result depends on the union of its operands' inputs. The pattern holds wherever
// f is evaluated only if f computes the same operations everywhere, so anything that looks at a value
// (a comparison, value(), hence a branch) is counted, and a model that did so is not given a
// compressed Jacobian (src/ode/coloured_jacobian.h). A model never uses this type directly.
#ifndef PK_SPARSITY_SCALAR_H_
#define PK_SPARSITY_SCALAR_H_

#include <algorithm>
#include <iterator>
#include <vector>

namespace pk {

class SparsityScalar {
 public:
  SparsityScalar() = default;
  SparsityScalar(double) {}  // NOLINT: a constant depends on nothing
  /// Input `index` itself.
  static SparsityScalar Input(int index) {
    SparsityScalar s;
    s.inputs_.push_back(index);
    return s;
  }

  /// The inputs this value depends on, ascending.
  const std::vector<int>& inputs() const { return inputs_; }

  /// There is no value: reading it counts as looking at one, and gives 0.
  double value() const {
    ++ValueReads();
    return 0;
  }
  /// How many times this thread looked at a value (value() or a comparison) so far.
  static long& ValueReads() {
    static thread_local long reads = 0;
    return reads;
  }

  friend SparsityScalar operator+(const SparsityScalar& a, const SparsityScalar& b) { return Union(a, b); }
  friend SparsityScalar operator-(const SparsityScalar& a, const SparsityScalar& b) { return Union(a, b); }
  friend SparsityScalar operator*(const SparsityScalar& a, const SparsityScalar& b) { return Union(a, b); }
  friend SparsityScalar operator/(const SparsityScalar& a, const SparsityScalar& b) { return Union(a, b); }
  SparsityScalar operator-() const { return *this; }
  SparsityScalar operator+() const { return *this; }
  SparsityScalar& operator+=(const SparsityScalar& o) { return *this = Union(*this, o); }
  SparsityScalar& operator-=(const SparsityScalar& o) { return *this = Union(*this, o); }
  SparsityScalar& operator*=(const SparsityScalar& o) { return *this = Union(*this, o); }
  SparsityScalar& operator/=(const SparsityScalar& o) { return *this = Union(*this, o); }

  friend bool operator<(const SparsityScalar& a, const SparsityScalar& b) { return a.value() < b.value(); }
  friend bool operator>(const SparsityScalar& a, const SparsityScalar& b) { return a.value() > b.value(); }
  friend bool operator<=(const SparsityScalar& a, const SparsityScalar& b) { return a.value() <= b.value(); }
  friend bool operator>=(const SparsityScalar& a, const SparsityScalar& b) { return a.value() >= b.value(); }

  static SparsityScalar Union(const SparsityScalar& a, const SparsityScalar& b) {
    SparsityScalar r;
    r.inputs_.reserve(a.inputs_.size() + b.inputs_.size());
    std::set_union(a.inputs_.begin(), a.inputs_.end(), b.inputs_.begin(), b.inputs_.end(),
                   std::back_inserter(r.inputs_));
    return r;
  }

 private:
  std::vector<int> inputs_;
};

// Elementary functions keep their argument's inputs; abs is one operation whichever sign it takes.
inline SparsityScalar exp(const SparsityScalar& x) { return x; }
inline SparsityScalar log(const SparsityScalar& x) { return x; }
inline SparsityScalar sqrt(const SparsityScalar& x) { return x; }
inline SparsityScalar abs(const SparsityScalar& x) { return x; }
inline SparsityScalar fabs(const SparsityScalar& x) { return x; }
inline SparsityScalar pow(const SparsityScalar& x, double) { return x; }
inline SparsityScalar pow(const SparsityScalar& x, const SparsityScalar& p) { return SparsityScalar::Union(x, p); }
inline SparsityScalar pow(double, const SparsityScalar& p) { return p; }

}  // namespace pk

#endif  // PK_SPARSITY_SCALAR_H_
