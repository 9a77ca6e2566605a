// Compressed sparse Jacobians of f: the pattern, its colouring, and the stages' products (see the header).
#include "ode/coloured_jacobian.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <utility>

namespace pk {
namespace internal {
namespace {

constexpr int kMaxModelsKept = 4;  // colourings kept per thread

// One group of V (a vector type of 2 or 4 doubles): weight · lanes into weighed unless it is null, and
// added to sum unless that is null.
template <typename V>
void Weigh(double weight, const double* lanes, double* weighed, double* sum) {
  V d, s;
  std::memcpy(&d, lanes, sizeof d);
  d *= weight;
  if (weighed != nullptr) std::memcpy(weighed, &d, sizeof d);
  if (sum == nullptr) return;
  std::memcpy(&s, sum, sizeof s);
  s += d;
  std::memcpy(sum, &s, sizeof s);
}

// The lanes of each of n rows weighed by its row's w_i into weighed, and the θ lanes [B, W) added to the
// running sum; when kOnlySummed, no x column reads those, and they are not kept in weighed. B, W and
// kOnlySummed are constants, so each row is a few straight-line instructions.
template <int W, int B, bool kOnlySummed>
void WeighRows(int n, const FixedDual<W>* lanes, const double* w, double* weighed, double* total) {
  for (int i = 0; i < n; ++i) {
    const double* const d = lanes[i].derivatives();
    const double wi = w[i];
    double* const pi = weighed + i * W;
    double* const si = total + i * W;
    int l = 0;
#if defined(__GNUC__)
    // As in FixedDual: GCC left these loops scalar. Four lanes an instruction in the AVX2 clone.
    typedef double Four __attribute__((vector_size(32)));
    typedef double Two __attribute__((vector_size(16)));
    for (; l + 2 <= B; l += 2) Weigh<Two>(wi, d + l, pi + l, nullptr);
    for (; l + 4 <= W; l += 4) Weigh<Four>(wi, d + l, kOnlySummed ? nullptr : pi + l, si + l);
    for (; l + 2 <= W; l += 2) Weigh<Two>(wi, d + l, kOnlySummed ? nullptr : pi + l, si + l);
#endif
    for (; l < W; ++l) {
      const double product = wi * d[l];
      if (l < B || !kOnlySummed) pi[l] = product;
      if (l >= B) si[l] += product;
    }
  }
}

// WeighRows<W, begin, only_summed> for an even begin ≤ W known only at run time.
template <int W, int B = 0>
void WeighRowsFrom(int begin, bool only_summed, int n, const FixedDual<W>* lanes, const double* w, double* weighed,
                   double* total) {
  if constexpr (B < W) {
    if (begin != B) return WeighRowsFrom<W, B + 2>(begin, only_summed, n, lanes, w, weighed, total);
  }
  if (only_summed) return WeighRows<W, B, true>(n, lanes, w, weighed, total);
  WeighRows<W, B, false>(n, lanes, w, weighed, total);
}

// Greedy colouring of the columns in their order: each takes the least colour no column sharing one of
// its rows has. Chains and other banded patterns come out optimal in this order.
void Colour(JacobianColouring* c) {
  const int columns = c->n + c->m;
  std::vector<std::vector<int>> in_row(static_cast<size_t>(c->n));  // the columns met in each row so far
  c->colour.assign(static_cast<size_t>(columns), 0);
  std::vector<char> taken;
  for (int k = 0; k < columns; ++k) {
    taken.assign(static_cast<size_t>(columns) + 1, 0);
    for (int p = c->column_start[k]; p < c->column_start[k + 1]; ++p) {
      for (int other : in_row[static_cast<size_t>(c->rows[p])]) taken[static_cast<size_t>(c->colour[other])] = 1;
    }
    int colour = 0;
    while (taken[static_cast<size_t>(colour)]) ++colour;
    c->colour[static_cast<size_t>(k)] = colour;
    if (c->column_start[k] < c->column_start[k + 1]) c->colours = std::max(c->colours, colour + 1);
    for (int p = c->column_start[k]; p < c->column_start[k + 1]; ++p) {
      in_row[static_cast<size_t>(c->rows[p])].push_back(k);
    }
  }
}

}  // namespace

template <int W>
bool ColouredJacobian::EvaluatesOnLanes(const OdeModel& model) {
  const std::vector<FixedDual<W>> x(static_cast<size_t>(model.num_compartments()), FixedDual<W>(1.0)),
      theta(static_cast<size_t>(model.num_parameters()), FixedDual<W>(1.0));
  std::vector<FixedDual<W>> f(x.size());
  try {
    return model.ColouredRhs(x.data(), theta.data(), f.data());
  } catch (const std::exception&) {
    return false;  // f never looked at a value here, so it would throw at every point: the tape serves
  }
}

// Whether the model's f runs on FixedDual<width> at all: a model may give its pattern and still not
// offer the lanes (OdeModel's defaults decline), and must then keep the tape, asked once here.
bool ColouredJacobian::EvaluatesOnLanes(const OdeModel& model, int width) {
  switch (width) {
    case 4: return EvaluatesOnLanes<4>(model);
    case 6: return EvaluatesOnLanes<6>(model);
    default: return EvaluatesOnLanes<8>(model);
  }
}

std::shared_ptr<const JacobianColouring> ColouredJacobian::ColouringOf(const OdeModel& model) {
  thread_local std::vector<std::pair<unsigned long, std::shared_ptr<const JacobianColouring>>> kept;
  for (auto it = kept.begin(); it != kept.end(); ++it) {
    if (it->first == model.id_) {
      std::rotate(kept.begin(), it, it + 1);  // the most recent first
      return kept.front().second;
    }
  }
  auto c = std::make_shared<JacobianColouring>();
  c->n = model.num_compartments();
  c->m = model.num_parameters();
  // f's rows start as a marker input: a row that still depends on it was left unset or read before it
  // was written (f[i] += …), and Evaluate must zero the rows first, as for Rhs on double.
  const int unset = c->n + c->m;
  std::vector<SparsityScalar> x, theta, f(static_cast<size_t>(c->n), SparsityScalar::Input(unset));
  for (int i = 0; i < c->n; ++i) x.push_back(SparsityScalar::Input(i));
  for (int k = 0; k < c->m; ++k) theta.push_back(SparsityScalar::Input(c->n + k));
  const long reads = SparsityScalar::ValueReads();
  bool known = false;
  try {
    known = model.RhsSparsity(x.data(), theta.data(), f.data());
  } catch (const std::exception&) {
    // f checked a value and refused it (a SparsityScalar's value is 0): no pattern, the tape serves.
    f.assign(f.size(), SparsityScalar());
  }
  c->looks_at_values = SparsityScalar::ValueReads() != reads;
  c->sets_every_row = true;
  for (SparsityScalar& fi : f) {
    const std::vector<int>& in = fi.inputs();
    if (std::find(in.begin(), in.end(), unset) == in.end()) continue;
    c->sets_every_row = false;
    SparsityScalar without;  // the row's pattern without the marker
    for (int k : in) {
      if (k != unset) without = without + SparsityScalar::Input(k);
    }
    fi = without;
  }
  // The pattern by columns.
  c->column_start.assign(static_cast<size_t>(c->n + c->m) + 1, 0);
  for (const SparsityScalar& fi : f) {
    for (int k : fi.inputs()) ++c->column_start[static_cast<size_t>(k) + 1];
  }
  for (size_t k = 1; k < c->column_start.size(); ++k) c->column_start[k] += c->column_start[k - 1];
  c->rows.resize(static_cast<size_t>(c->column_start.back()));
  std::vector<int> next(c->column_start.begin(), c->column_start.end() - 1);
  for (int i = 0; i < c->n; ++i) {
    for (int k : f[static_cast<size_t>(i)].inputs()) c->rows[static_cast<size_t>(next[static_cast<size_t>(k)]++)] = i;
  }
  Colour(c.get());
  if (known && !c->looks_at_values) {
    for (int w : {4, 6, 8}) {
      if (c->colours <= w) {
        c->width = w;
        break;
      }
    }
    if (c->width > 0 && !EvaluatesOnLanes(model, c->width)) c->width = 0;
  }
  c->theta_lanes_begin = c->width;
  for (int k = 0; k < c->n + c->m; ++k) {
    for (int p = c->column_start[k]; p < c->column_start[k + 1]; ++p) {
      c->lane_offset.push_back(c->rows[p] * c->width + c->colour[static_cast<size_t>(k)]);
      if (k >= c->n) c->theta_lanes_begin = std::min(c->theta_lanes_begin, c->colour[static_cast<size_t>(k)] & ~1);
    }
  }
  c->x_lanes_below_theta = true;
  for (int k = 0; k < c->n; ++k) {
    if (c->column_start[k] < c->column_start[k + 1] && c->colour[static_cast<size_t>(k)] >= c->theta_lanes_begin) {
      c->x_lanes_below_theta = false;
    }
  }
  for (int k = 0; k < c->n; ++k) c->x_slots = std::max(c->x_slots, c->column_start[k + 1] - c->column_start[k]);
  c->x_gather.assign(static_cast<size_t>(c->x_slots) * static_cast<size_t>(c->n), c->n * c->width);
  for (int k = 0; k < c->n; ++k) {
    for (int p = c->column_start[k]; p < c->column_start[k + 1]; ++p) {
      c->x_gather[static_cast<size_t>((p - c->column_start[k]) * c->n + k)] = c->lane_offset[static_cast<size_t>(p)];
    }
  }
  kept.insert(kept.begin(), {model.id_, c});
  if (kept.size() > kMaxModelsKept) kept.pop_back();
  return c;
}

std::unique_ptr<ColouredJacobian> ColouredJacobian::For(const OdeModel& model, const Eigen::VectorXd& theta) {
  std::shared_ptr<const JacobianColouring> c = ColouringOf(model);
  if (c->width == 0) return nullptr;
  return std::unique_ptr<ColouredJacobian>(new ColouredJacobian(model, std::move(c), theta));
}

ColouredJacobian::ColouredJacobian(const OdeModel& model, std::shared_ptr<const JacobianColouring> colouring,
                                   const Eigen::VectorXd& theta)
    : model_(model),
      colouring_(std::move(colouring)),
      c_(*colouring_),
      weighted_sum_(static_cast<size_t>(c_.n) * static_cast<size_t>(c_.width), 0.0),
      weighed_(weighted_sum_.size() + 1, 0.0) {
  switch (c_.width) {
    case 4: Seed(theta, &lanes4_); break;
    case 6: Seed(theta, &lanes6_); break;
    default: Seed(theta, &lanes8_); break;
  }
}

// θ's lanes and x's seeds once (θ is constant over the steps, and f does not write its inputs); an
// evaluation only sets x's values (Evaluate).
template <int W>
void ColouredJacobian::Seed(const Eigen::VectorXd& theta, Lanes<W>* lanes) {
  if (theta.size() != c_.m) throw std::invalid_argument("ColouredJacobian: θ has the wrong size");
  lanes->x.assign(static_cast<size_t>(c_.n), FixedDual<W>(0.0));
  for (int i = 0; i < c_.n; ++i) lanes->x[static_cast<size_t>(i)].derivative(c_.colour[static_cast<size_t>(i)]) = 1;
  lanes->theta.clear();
  lanes->theta.reserve(static_cast<size_t>(c_.m));
  for (int k = 0; k < c_.m; ++k) {
    lanes->theta.emplace_back(theta(k));
    lanes->theta.back().derivative(c_.colour[static_cast<size_t>(c_.n + k)]) = 1;
  }
}

// f on the lanes at x, into out[0, n).
template <int W>
void ColouredJacobian::Evaluate(const Eigen::VectorXd& x, Lanes<W>* lanes, FixedDual<W>* out) {
  for (int i = 0; i < c_.n; ++i) lanes->x[static_cast<size_t>(i)].set_value(x(i));
  // A row f leaves unset is 0, as on the tape. Zeroing n × (W + 1) numbers was 7 % of the 32-chain's
  // adjoint, so it is skipped for a model that writes every row without reading it.
  if (!c_.sets_every_row) std::fill(out, out + c_.n, FixedDual<W>(0.0));
  if (!model_.ColouredRhs(lanes->x.data(), lanes->theta.data(), out)) {
    // ColouringOf asked the model once (EvaluatesOnLanes): a model that declines later is inconsistent.
    throw std::logic_error("ColouredJacobian: the model evaluated on FixedDual once and declines now");
  }
}

void ColouredJacobian::Record(const Eigen::VectorXd& x, Eigen::VectorXd* f) {
  f->resize(c_.n);
  Record(x, f->data());
}

// Into the step's next stage slot.
void ColouredJacobian::Record(const Eigen::VectorXd& x, double* f) {
  const size_t slot = static_cast<size_t>(stages_);
  switch (c_.width) {
    case 4: RecordInto(&lanes4_.f, slot, SIZE_MAX, x, &lanes4_, f); break;
    case 6: RecordInto(&lanes6_.f, slot, SIZE_MAX, x, &lanes6_, f); break;
    default: RecordInto(&lanes8_.f, slot, SIZE_MAX, x, &lanes8_, f); break;
  }
  ++stages_;
}

template <int W>
void ColouredJacobian::RecordInto(std::vector<FixedDual<W>>* store, size_t slot, size_t limit,
                                  const Eigen::VectorXd& x, Lanes<W>* lanes, double* f) {
  const size_t n = static_cast<size_t>(c_.n), first = slot * n;
  // Growing by at least eight stages (Dormand–Prince records six a step), doubling beyond, never past
  // the limit: kept stages have a budget (OdeOptions::adjoint_kept_stage_bytes), and a doubling would
  // touch up to twice that.
  if (store->size() < first + n) {
    const size_t cap = limit <= SIZE_MAX / n ? limit * n : SIZE_MAX;  // SIZE_MAX: no limit
    store->resize(std::max(first + n, std::min(std::max(2 * store->size(), 8 * n), cap)));
  }
  FixedDual<W>* const out = store->data() + first;
  Evaluate(x, lanes, out);
  for (size_t i = 0; i < n; ++i) f[i] = out[i].value();
}

void ColouredJacobian::RecordSlot(StageSlots* slots, size_t slot, size_t limit, const Eigen::VectorXd& x,
                                  double* f) {
  switch (c_.width) {
    case 4: RecordInto(&slots->lanes4, slot, limit, x, &lanes4_, f); break;
    case 6: RecordInto(&slots->lanes6, slot, limit, x, &lanes6_, f); break;
    default: RecordInto(&slots->lanes8, slot, limit, x, &lanes8_, f); break;
  }
}

template <int W>
const FixedDual<W>* ColouredJacobian::KeptSlot(const std::vector<FixedDual<W>>& store, size_t slot) const {
  const size_t n = static_cast<size_t>(c_.n), first = slot * n;
  if (first + n > store.size()) throw std::logic_error("ColouredJacobian: a slot not recorded");
  return store.data() + first;
}

double ColouredJacobian::StateRowSumNormAt(const StageSlots& slots, size_t slot) {
  switch (c_.width) {
    case 4: return RowSumNormOf(KeptSlot(slots.lanes4, slot));
    case 6: return RowSumNormOf(KeptSlot(slots.lanes6, slot));
    default: return RowSumNormOf(KeptSlot(slots.lanes8, slot));
  }
}

void ColouredJacobian::SweepSlot(const StageSlots& slots, size_t slot, const Eigen::VectorXd& w, double* wfx) {
  switch (c_.width) {
    case 4: CallOnLanes([&] { SweepLanes(KeptSlot(slots.lanes4, slot), w.data(), wfx); }); break;
    case 6: CallOnLanes([&] { SweepLanes(KeptSlot(slots.lanes6, slot), w.data(), wfx); }); break;
    default: CallOnLanes([&] { SweepLanes(KeptSlot(slots.lanes8, slot), w.data(), wfx); }); break;
  }
}

// Σ_k |J_ik| over the x columns of each row, from one evaluation into the scratch slot.
template <int W>
double ColouredJacobian::RowSumNorm(const Eigen::VectorXd& x, Lanes<W>* lanes) {
  lanes->scratch.resize(static_cast<size_t>(c_.n));
  Evaluate(x, lanes, lanes->scratch.data());
  return RowSumNormOf(lanes->scratch.data());
}

template <int W>
double ColouredJacobian::RowSumNormOf(const FixedDual<W>* f) {
  row_sums_.assign(static_cast<size_t>(c_.n), 0.0);
  for (int k = 0; k < c_.n; ++k) {
    const int colour = c_.colour[static_cast<size_t>(k)];
    for (int p = c_.column_start[k]; p < c_.column_start[k + 1]; ++p) {
      const size_t row = static_cast<size_t>(c_.rows[static_cast<size_t>(p)]);
      row_sums_[row] += std::fabs(f[row].derivative(colour));
    }
  }
  double norm = 0;
  for (double r : row_sums_) {
    if (std::isnan(r)) return r;  // the caller tests finiteness
    norm = std::max(norm, r);
  }
  return norm;
}

double ColouredJacobian::StateRowSumNorm(const Eigen::VectorXd& x) {
  switch (c_.width) {
    case 4: return RowSumNorm(x, &lanes4_);
    case 6: return RowSumNorm(x, &lanes6_);
    default: return RowSumNorm(x, &lanes8_);
  }
}

// (wᵀf_x)_k = Σ over column k's rows i of w_i J_ik, J_ik read from the lane of k's colour; and w_i times
// each θ lane of f_i added to the running sum, from which ThetaProduct picks the θ columns once (an entry
// (i, c) of the sum belongs to the one column of colour c with a nonzero in row i, if any: no two columns
// of a colour share a row). Every lane of a row is weighed at once, a few lanes an instruction, into
// the stage's weighed lanes, and the θ lanes added to the running sum as they are (WeighRows, its
// loops unrolled for the colouring's width and first θ lane); each x column then sums its nonzeros'
// weighed lanes, one load a nonzero, a slot of the gather table at a time over every column
// (JacobianColouring::x_gather). A gather that weighed as it went took a row, a colour, w and the lane a
// nonzero and cost as much as f on the lanes; one that looped over each column's nonzeros (CSC) spent
// half the sweep in its short inner loops. The products and their order are the same in all three (the
// same bits).
template <int W>
void ColouredJacobian::SweepLanes(const FixedDual<W>* lanes, const double* w, double* wfx) {
  const int n = c_.n;
  double* const weighed = weighed_.data();
  WeighRowsFrom<W>(c_.theta_lanes_begin, c_.x_lanes_below_theta, n, lanes, w, weighed, weighted_sum_.data());
  const int* gather = c_.x_gather.data();
  if (c_.x_slots == 0) {
    std::fill(wfx, wfx + n, 0.0);
    return;
  }
  // 0 + the first nonzero, as a sum begun at 0 (a −0 becomes +0); a loop of stores of 0 before was a
  // call of memset.
  for (int k = 0; k < n; ++k) wfx[k] = 0.0 + weighed[gather[k]];
  for (int j = 1; j < c_.x_slots; ++j) {
    gather += n;
    for (int k = 0; k < n; ++k) wfx[k] += weighed[gather[k]];
  }
}

void ColouredJacobian::Sweep(int stage, const Eigen::VectorXd& w, Eigen::VectorXd* wfx) {
  wfx->resize(c_.n);
  Sweep(stage, w, wfx->data());
}

void ColouredJacobian::Sweep(int stage, const Eigen::VectorXd& w, double* wfx) {
  if (stage < 0 || stage >= stages_) throw std::logic_error("ColouredJacobian: a stage not recorded in this step");
  const size_t first = static_cast<size_t>(stage) * static_cast<size_t>(c_.n);
  switch (c_.width) {
    case 4: CallOnLanes([&] { SweepLanes(lanes4_.f.data() + first, w.data(), wfx); }); break;
    case 6: CallOnLanes([&] { SweepLanes(lanes6_.f.data() + first, w.data(), wfx); }); break;
    default: CallOnLanes([&] { SweepLanes(lanes8_.f.data() + first, w.data(), wfx); }); break;
  }
}

Eigen::VectorXd ColouredJacobian::ThetaProduct() const {
  Eigen::VectorXd product(c_.m);
  for (int k = 0; k < c_.m; ++k) {
    double sum = 0;
    for (int p = c_.column_start[c_.n + k]; p < c_.column_start[c_.n + k + 1]; ++p) {
      sum += weighted_sum_[static_cast<size_t>(c_.lane_offset[p])];
    }
    product(k) = sum;
  }
  return product;
}

}  // namespace internal
}  // namespace pk
