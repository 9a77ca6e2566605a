// libpk: a reverse-mode automatic-differentiation scalar.
//
// The adjoint route needs the vector–Jacobian products λᵀf_x and λᵀf_θ at
// every backward step. Forward mode (pk::Dual) would cost one pass per state
// or parameter; reverse mode gets both from one pass over a recording of f,
// at a few times the cost of f itself, whatever n and m are. libpk evaluates
// model functors on TapeScalar for that (pk/ode_model.h); a model never uses
// it directly, it only has to be a template on its scalar type.
//
// The tape is per thread: one evaluation records onto it, is swept backward,
// and is cleared before the next.
#ifndef PK_TAPE_SCALAR_H_
#define PK_TAPE_SCALAR_H_

#include <cmath>
#include <utility>
#include <vector>

// Recording an operation is a handful of stores; a call around it cost as much again (a 32-compartment
// saturable chain's adjoint in pkbench), so the few functions on that path are always inlined.
#if defined(__GNUC__)
#define PK_TAPE_INLINE __attribute__((always_inline)) inline
#else
#define PK_TAPE_INLINE inline
#endif

namespace pk {

namespace internal {
class StageTape;  // records a one-step method's stages on one tape (libpk/src/ode/ode_system.h)
}  // namespace internal

/// The recording: node k has up to two parents with their partial derivatives.
class Tape {
 public:
  struct Node {
    int a, b;
    double da, db;
  };
  void Clear() { size_ = 0; }
  /// Drops the nodes from `size` on (a recording made after the first `size` nodes).
  void Truncate(int size) {
    if (size < size_) size_ = size;
  }
  /// Exchanges the recordings (to keep one while the active tape records others).
  void Swap(Tape& other) {
    nodes_.swap(other.nodes_);
    std::swap(size_, other.size_);
    std::swap(capacity_, other.capacity_);
  }
  int size() const { return size_; }
  PK_TAPE_INLINE int Push(int a, double da, int b = -1, double db = 0) {
    // Written field by field into storage kept between recordings: a Node
    // built on the stack and copied stalled store forwarding here.
    if (size_ == capacity_) {
      capacity_ = capacity_ == 0 ? 256 : 2 * capacity_;
      nodes_.resize(static_cast<size_t>(capacity_));
    }
    Node& n = nodes_[static_cast<size_t>(size_)];
    n.a = a;
    n.b = b;
    n.da = da;
    n.db = db;
    return size_++;
  }
  /// Back-propagates the adjoints in `adj` (one per node, seeded by the caller).
  /// Nodes below `first` must have no parents (the independent variables,
  /// recorded first) and are not visited.
  void Sweep(std::vector<double>* adj, int first = 0) const { Sweep(adj, first, size()); }
  /// The same over the nodes [first, end) only: one of several recordings on the tape, whose
  /// nodes' parents are before `end`.
  void Sweep(std::vector<double>* adj, int first, int end) const { SweepNodes(nodes_.data(), adj->data(), first, end); }
  /// Forward mode over the recording: `tangents` holds `width` values per node
  /// (node-major), the derivatives of that node along `width` directions. The
  /// rows of the independent variables (the nodes without parents) are set by
  /// the caller; every other row is computed here from its parents'.
  /// Where a partial is infinite (sqrt, log, pow at 0) a tangent that is 0 stays 0, not 0·∞ = NaN, as
  /// on pk::Dual and pk::FixedDual: directions that do not pass through the point keep their finite
  /// derivatives, whatever their number.
  void Tangents(int width, std::vector<double>* tangents) const {
    double* t = tangents->data();
    const size_t w = static_cast<size_t>(width);
    for (int k = 0; k < size(); ++k) {
      const Node& n = nodes_[k];
      if (n.a < 0) continue;
      double* row = t + k * w;
      const double* ra = t + n.a * w;
      const bool finite = std::isfinite(n.da) && (n.b < 0 || std::isfinite(n.db));
      if (n.b < 0) {
        for (size_t j = 0; j < w; ++j) row[j] = finite ? n.da * ra[j] : Times(n.da, ra[j]);
      } else {
        const double* rb = t + n.b * w;
        for (size_t j = 0; j < w; ++j) {
          row[j] = finite ? n.da * ra[j] + n.db * rb[j] : Times(n.da, ra[j]) + Times(n.db, rb[j]);
        }
      }
    }
  }
  /// The tape of the calling thread.
  static Tape& Active() {
    static thread_local Tape tape;
    return tape;
  }

 private:
  static double Times(double partial, double tangent) { return tangent == 0 ? 0.0 : partial * tangent; }
  // The sweep's loop on its own: inlined into a caller with more live values, its adjoints' base was
  // spilled and reloaded at every node.
#if defined(__GNUC__)
  __attribute__((noinline))
#endif
  static void SweepNodes(const Node* nodes, double* a, int first, int end) {
    for (int k = end - 1; k >= first; --k) {
      const double w = a[k];
      if (w == 0) continue;
      const Node& n = nodes[k];
      if (n.a >= 0) a[n.a] += n.da * w;
      if (n.b >= 0) a[n.b] += n.db * w;
    }
  }

  std::vector<Node> nodes_;  // nodes_[0, size_) are the recording; nodes_.size() == capacity_
  int size_ = 0;
  int capacity_ = 0;
};

class TapeScalar {
 public:
  TapeScalar() = default;
  TapeScalar(double value) : v_(value) {}  // NOLINT: constants convert implicitly
  /// A new independent variable on the active tape.
  static TapeScalar Variable(double value) { return TapeScalar(value, Tape::Active().Push(-1, 0)); }

  double value() const { return v_; }
  int index() const { return i_; }  ///< node on the tape, -1 for a constant

  /// f(x) with f'(x): one unary node.
  PK_TAPE_INLINE TapeScalar Unary(double f, double df) const { return i_ < 0 ? TapeScalar(f) : TapeScalar(f, Tape::Active().Push(i_, df)); }
  /// f(x, y) with its partials: one binary node.
  PK_TAPE_INLINE static TapeScalar Binary(double f, const TapeScalar& x, double dx, const TapeScalar& y, double dy) {
    if (x.i_ < 0 && y.i_ < 0) return TapeScalar(f);
    if (x.i_ < 0) return TapeScalar(f, Tape::Active().Push(y.i_, dy));
    if (y.i_ < 0) return TapeScalar(f, Tape::Active().Push(x.i_, dx));
    return TapeScalar(f, Tape::Active().Push(x.i_, dx, y.i_, dy));
  }

  friend TapeScalar operator+(const TapeScalar& a, const TapeScalar& b) { return Binary(a.v_ + b.v_, a, 1, b, 1); }
  friend TapeScalar operator-(const TapeScalar& a, const TapeScalar& b) { return Binary(a.v_ - b.v_, a, 1, b, -1); }
  friend TapeScalar operator*(const TapeScalar& a, const TapeScalar& b) { return Binary(a.v_ * b.v_, a, b.v_, b, a.v_); }
  friend TapeScalar operator/(const TapeScalar& a, const TapeScalar& b) {
    // q exactly as in double; its partials from one more division that does not wait for q's.
    const double q = a.v_ / b.v_, inv = 1 / b.v_;
    return Binary(q, a, inv, b, -q * inv);
  }
  TapeScalar operator-() const { return Unary(-v_, -1); }
  TapeScalar operator+() const { return *this; }
  TapeScalar& operator+=(const TapeScalar& o) { return *this = *this + o; }
  TapeScalar& operator-=(const TapeScalar& o) { return *this = *this - o; }
  TapeScalar& operator*=(const TapeScalar& o) { return *this = *this * o; }
  TapeScalar& operator/=(const TapeScalar& o) { return *this = *this / o; }

  friend bool operator<(const TapeScalar& a, const TapeScalar& b) { return a.v_ < b.v_; }
  friend bool operator>(const TapeScalar& a, const TapeScalar& b) { return a.v_ > b.v_; }
  friend bool operator<=(const TapeScalar& a, const TapeScalar& b) { return a.v_ <= b.v_; }
  friend bool operator>=(const TapeScalar& a, const TapeScalar& b) { return a.v_ >= b.v_; }

 private:
  friend class internal::StageTape;
  TapeScalar(double value, int index) : v_(value), i_(index) {}
  // The variable recorded earlier as node `index` of the active tape, at a new value: recordings that
  // follow one another on a tape may share their variables (nodes without parents hold no value), each
  // sweep reading the variables' adjoints before the next. For libpk's stage recordings only: an
  // index that is not a variable's node would send a sweep out of bounds.
  static TapeScalar OnTape(double value, int index) { return TapeScalar(value, index); }
  double v_ = 0;
  int i_ = -1;
};

inline TapeScalar exp(const TapeScalar& x) {
  const double e = std::exp(x.value());
  return x.Unary(e, e);
}
inline TapeScalar log(const TapeScalar& x) { return x.Unary(std::log(x.value()), 1 / x.value()); }
inline TapeScalar sqrt(const TapeScalar& x) {
  const double s = std::sqrt(x.value());
  return x.Unary(s, 0.5 / s);
}
inline TapeScalar abs(const TapeScalar& x) { return x.value() < 0 ? -x : x; }
inline TapeScalar fabs(const TapeScalar& x) { return abs(x); }
inline TapeScalar pow(const TapeScalar& x, double p) {
  return x.Unary(std::pow(x.value(), p), p == 0 ? 0.0 : p * std::pow(x.value(), p - 1));
}
/// x^p; at x = 0 the derivative with respect to p is taken as 0 (as for pk::Dual).
inline TapeScalar pow(const TapeScalar& x, const TapeScalar& p) {
  const double v = std::pow(x.value(), p.value());
  const double dx = p.value() == 0 ? 0.0 : p.value() * std::pow(x.value(), p.value() - 1);
  const double dp = x.value() > 0 ? v * std::log(x.value()) : 0.0;
  return TapeScalar::Binary(v, x, dx, p, dp);
}
inline TapeScalar pow(double x, const TapeScalar& p) { return pow(TapeScalar(x), p); }

}  // namespace pk

#endif  // PK_TAPE_SCALAR_H_
