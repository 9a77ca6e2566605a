#include "modal.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Eigenvalues>
#include <Eigen/Jacobi>
#include <Eigen/LU>
#include <unsupported/Eigen/MatrixFunctions>

#include "discretization.h"
#include "exact_routes.h"
#include "modal_evaluator.h"

namespace pk {
namespace internal {

// ---------------------------------------------------------------------------
// Recording the schedule.

namespace {

class ScheduleRecorder {
 public:
  ScheduleRecorder(const PreparedSubject& s, EventSchedule* out) : s_(s), out_(*out) {
    sample_ = SampleIndex(s, &out_.num_samples);
  }
  void Advance(double h, const Eigen::VectorXd& u, int set) {
    Push(ScheduleOp::kAdvance, set, Intern(u)).step = Step(h);
  }
  void Bolus(int cmt, double amount, int set) {
    ScheduleOp& op = Push(ScheduleOp::kBolus, set, -1);
    op.cmt = cmt;
    op.value = amount;
  }
  void Reset() { Push(ScheduleOp::kReset, last_set_, -1); }
  void SteadyState(const SteadyStateCycle<double>& c, int set, bool add) {
    ScheduleCycle cycle;
    cycle.cmt = c.cmt;
    cycle.bolus = c.bolus;
    for (const Segment<double>& seg : c.period) cycle.period.push_back({Step(seg.duration), Intern(seg.rate)});
    for (const Segment<double>& seg : c.to_record) cycle.to_record.push_back({Step(seg.duration), Intern(seg.rate)});
    out_.cycles.push_back(std::move(cycle));
    Push(ScheduleOp::kSteadyState, set, static_cast<int>(out_.cycles.size()) - 1).add = add;
  }
  void SteadyInfusion(const Eigen::VectorXd& u, int set, bool add) {
    Push(ScheduleOp::kSteadyInfusion, set, Intern(u)).add = add;
  }
  void DoseEntered(double, int) {}
  void RecordDone(int r, int set) {
    if (sample_[r] < 0) return;
    Push(ScheduleOp::kSample, set, sample_[r]).cmt = s_.cmt[r] + 1;
  }

 private:
  int Step(double h) {
    for (size_t i = 0; i < out_.steps.size(); ++i) {
      if (out_.steps[i] == h) return static_cast<int>(i);
    }
    out_.steps.push_back(h);
    return static_cast<int>(out_.steps.size()) - 1;
  }
  int Intern(const Eigen::VectorXd& u) {
    if (u.isZero(0.0)) return -1;
    for (size_t i = 0; i < out_.inputs.size(); ++i) {
      if (out_.inputs[i] == u) return static_cast<int>(i);
    }
    out_.inputs.push_back(u);
    return static_cast<int>(out_.inputs.size()) - 1;
  }
  ScheduleOp& Push(ScheduleOp::Kind kind, int set, int index) {
    ScheduleOp op;
    op.kind = kind;
    op.set = set;
    op.index = index;
    last_set_ = set;
    out_.ops.push_back(op);
    return out_.ops.back();
  }

  const PreparedSubject& s_;
  EventSchedule& out_;
  std::vector<int> sample_;
  int last_set_ = 0;
};

}  // namespace

EventSchedule RecordSchedule(const ParameterLayout& layout, const PreparedSubject& subject) {
  EventSchedule out;
  ScheduleRecorder recorder(subject, &out);
  EventEngine<double, ScheduleRecorder> engine(subject, layout, subject.sets, &recorder);
  engine.Run();
  for (const ScheduleOp& op : out.ops) {
    out.simple = out.simple && op.kind != ScheduleOp::kSteadyState && op.kind != ScheduleOp::kSteadyInfusion;
  }
  // Steps that are 2, 3 or 4 times a shorter one, shortest first (so that bases are settled before use).
  const size_t num_steps = out.steps.size();
  out.step_powers.assign(num_steps, {});
  std::vector<int> order(num_steps), total(num_steps, 1);  // total: the product of the powers down to an exp
  for (size_t i = 0; i < num_steps; ++i) order[i] = static_cast<int>(i);
  std::sort(order.begin(), order.end(), [&](int a, int b) { return out.steps[a] < out.steps[b]; });
  for (const int j : order) {
    const double h = out.steps[j];
    if (!(h > 0)) continue;
    for (int power = 2; power <= 4 && out.step_powers[j].base < 0; ++power) {
      for (const int i : order) {
        if (out.steps[i] >= h) break;
        if (out.steps[i] > 0 && power * out.steps[i] == h && power * total[i] <= EventSchedule::kMaxStepPower) {
          out.step_powers[j] = {i, power};
          total[j] = power * total[i];
          break;
        }
      }
    }
  }
  return out;  // the caller sets the key (ObjectiveState::ScheduleKey)
}

// ---------------------------------------------------------------------------
// Divided differences of f(λ) = e^{λh}.

double DividedExp2Close(double a, double b, double ea, double eb, double h) {
  // Below |(a − b)h| = 0.1 the sinh form is exact to rounding.
  return h * std::sqrt(ea) * std::sqrt(eb) * Sinhc(0.5 * (a - b) * h);
}

double DividedExp3(double a, double b, double ea, double eb, double h) {
  const double sab = std::fabs(a - b), sa = std::fabs(a), sb = std::fabs(b);
  const double smax = std::max(sab, std::max(sa, sb));
  if (smax * h >= 0.1) {
    // Recurrence on the two points farthest apart: f[x, y, z] = (f[x, z] − f[y, z]) / (x − y).
    if (sab == smax) return (DividedExp2(a, 0, ea, 1, h) - DividedExp2(b, 0, eb, 1, h)) / (a - b);
    const double fab = DividedExp2(a, b, ea, eb, h);
    if (sa == smax) return (fab - DividedExp2(b, 0, eb, 1, h)) / a;
    return (fab - DividedExp2(a, 0, ea, 1, h)) / b;
  }
  // All three points within 0.1/h: Taylor series about their centroid c,
  // f[a, b, 0] = e^{ch} h² Σ_k h_k(α, β, γ)/(k+2)!, with α = (a − c)h, β = (b − c)h,
  // γ = −ch and h_k the complete homogeneous symmetric polynomials.
  const double c = (a + b) / 3, al = (a - c) * h, be = (b - c) * h, ga = -c * h;
  // |α|, |β|, |γ| ≤ 0.1 bound the k-th term by C(k+2, 2) 0.1^k/(k+2)!, below 1e-20 at k = 12.
  // (h_1 = α + β + γ vanishes by the choice of c, so the terms are not monotone.)
  double p1 = 1, p2 = 1, p3 = 1, fact = 2, sum = 0.5;
  for (int k = 1; k <= 12; ++k) {
    p1 *= al;
    p2 = p1 + be * p2;
    p3 = p2 + ga * p3;
    fact *= k + 2;
    sum += p3 / fact;
  }
  return std::exp(c * h) * h * h * sum;
}

// f[a, b, c] for f(x) = e^{hx}: shifted by the largest point (f[a, b, c] = e^{hc₀} f[a − c₀, b − c₀,
// c − c₀]), which puts a 0 among the points and keeps every exponential at most 1.
double DividedExp3General(double a, double b, double c, double h) {
  double x[3] = {a, b, c};
  std::sort(x, x + 3);
  const double top = x[2], p = x[0] - top, q = x[1] - top;
  return std::exp(h * top) * DividedExp3(p, q, std::exp(h * p), std::exp(h * q), h);
}

// f[a, b, c, 0]: close points (all within 0.5/h) from the exponential of the bidiagonal matrix
// whose top-right entry it is (Opitz); otherwise the recurrence on the two farthest points.
double DividedExp4(double a, double b, double c, double h) {
  const double x[4] = {a, b, c, 0.0};
  const double lo = *std::min_element(x, x + 4), hi = *std::max_element(x, x + 4);
  if ((hi - lo) * h < 0.5) {
    Eigen::Matrix4d j = Eigen::Matrix4d::Zero();
    for (int i = 0; i < 4; ++i) j(i, i) = h * x[i];
    for (int i = 0; i < 3; ++i) j(i, i + 1) = h;
    const Eigen::Matrix4d e = j.exp();  // evaluated here: exp() returns an expression of j
    return e(0, 3);
  }
  int u = 0, v = 1;
  for (int i = 0; i < 4; ++i) {
    for (int k = i + 1; k < 4; ++k) {
      if (std::fabs(x[i] - x[k]) > std::fabs(x[u] - x[v])) u = i, v = k;
    }
  }
  double without_u[3], without_v[3];
  for (int i = 0, a_at = 0, b_at = 0; i < 4; ++i) {
    if (i != u) without_u[a_at++] = x[i];
    if (i != v) without_v[b_at++] = x[i];
  }
  const double fu = DividedExp3General(without_v[0], without_v[1], without_v[2], h);  // holds x[u]
  const double fv = DividedExp3General(without_u[0], without_u[1], without_u[2], h);  // holds x[v]
  return (fu - fv) / (x[u] - x[v]);
}

// ---------------------------------------------------------------------------
// The eigendecomposition (modal_evaluator.h).

namespace modal_detail {
namespace {

// Cyclic Jacobi rotations (Eigen's JacobiRotation) for a small symmetric S = Q diag(d) Qᵀ.
template <typename M, typename V>
void Jacobi(M s, V* d, M* q) {
  const int n = static_cast<int>(s.rows());
  *q = M::Identity(n, n);
  for (int sweep = 0; sweep < 30; ++sweep) {
    bool rotated = false;
    for (int i = 0; i < n; ++i) {
      for (int k = i + 1; k < n; ++k) {
        // An entry below rounding relative to its diagonal pair changes the eigenvalues by O(ε²).
        if (std::fabs(s(i, k)) <= 2.3e-16 * std::sqrt(std::fabs(s(i, i) * s(k, k)))) continue;
        rotated = true;
        Eigen::JacobiRotation<double> rot;
        rot.makeJacobi(s, i, k);
        s.applyOnTheLeft(i, k, rot.adjoint());
        s.applyOnTheRight(i, k, rot);
        q->applyOnTheRight(i, k, rot);
        s(i, k) = s(k, i) = 0;  // zero by construction of the rotation
      }
    }
    if (!rotated) break;
  }
  *d = s.diagonal();
}

// A modal sum Σ_r v_r e^{λ_r h} (w_r·x) loses ε‖|V||W|‖_∞ ‖x‖ to rounding, whatever the
// scaling of the eigenvectors; derivatives about the square of that. 1e3 keeps them near 1e-10.
// ‖|V||W|‖_∞ = max_i Σ_j |v_ij| Σ_k |w_jk|.
template <typename M, typename V>
bool WellConditioned(const V& lambda, const M& v, const M& w) {
  const V w_rows = w.cwiseAbs().rowwise().sum();  // Σ_k |w_jk|
  const double kappa = (v.cwiseAbs() * w_rows).maxCoeff();
  return kappa <= 1e3 && w.allFinite() && lambda.allFinite();
}

// A block A = T S T⁻¹ with S symmetric (T from SymmetrizingDiagonal) as V diag(λ) W: S is
// diagonalised by Jacobi rotations (up to 4 states) or Eigen's symmetric solver, then V = T Q and
// W = Qᵀ T⁻¹. False when the solver fails.
template <typename M, typename V>
bool SymmetrisedModes(const M& a, const V& t, V* lambda, M* v, M* w) {
  const int n = static_cast<int>(a.rows());
  M sym = t.cwiseInverse().asDiagonal() * a * t.asDiagonal();
  sym = 0.5 * (sym + sym.transpose()).eval();
  M q;
  if (n <= 4) {
    Jacobi(sym, lambda, &q);
  } else {
    const Eigen::SelfAdjointEigenSolver<M> es(sym);
    if (es.info() != Eigen::Success) return false;
    *lambda = es.eigenvalues();
    q = es.eigenvectors();
  }
  *v = t.asDiagonal() * q;
  *w = q.transpose() * t.cwiseInverse().asDiagonal();
  return true;
}

template <typename M, typename V>
bool DecomposeImpl(const M& a, V* lambda, M* v, M* w) {
  const int n = static_cast<int>(a.rows());
  Eigen::Matrix<int, Eigen::Dynamic, 1, 0, M::MaxRowsAtCompileTime, 1> src(n), rest(n);
  int ns = 0, nr = 0;
  for (int i = 0; i < n; ++i) {
    bool source = true;
    for (int k = 0; k < n && source; ++k) source = k == i || a(i, k) == 0;
    if (source) {
      src(ns++) = i;
    } else {
      rest(nr++) = i;
    }
  }
  M arr(nr, nr);
  for (int i = 0; i < nr; ++i) {
    for (int k = 0; k < nr; ++k) arr(i, k) = a(rest(i), rest(k));
  }
  V lr(nr), t;
  M vr(nr, nr), wr(nr, nr);
  if (nr > 0) {
    if (SymmetrizingDiagonal(arr, &t)) {
      if (!SymmetrisedModes(arr, t, &lr, &vr, &wr)) return false;
    } else {
      const Eigen::EigenSolver<M> es(arr);
      if (es.info() != Eigen::Success) return false;
      const double scale = std::max(arr.cwiseAbs().maxCoeff(), 1e-300);
      if (es.eigenvalues().imag().cwiseAbs().maxCoeff() > 1e-12 * scale) return false;
      lr = es.eigenvalues().real();
      vr = es.eigenvectors().real();
      const Eigen::PartialPivLU<M> lu(vr);
      wr = lu.inverse();
    }
  }
  lambda->resize(n);
  *v = M::Zero(n, n);
  *w = M::Zero(n, n);
  for (int r = 0; r < nr; ++r) {
    (*lambda)(ns + r) = lr(r);
    for (int i = 0; i < nr; ++i) {
      (*v)(rest(i), ns + r) = vr(i, r);
      (*w)(ns + r, rest(i)) = wr(r, i);
    }
  }
  // A depot's mode: (A_RR − λ_s) x = −a_Rs, x = −V_R c with c = (λ_R − λ_s)⁻¹ W_R a_Rs,
  // and V⁻¹ = [[I, 0], [−W_R X, W_R]] puts c in the depot's column.
  for (int q = 0; q < ns; ++q) {
    const int sq = src(q);
    const double ls = a(sq, sq);
    (*lambda)(q) = ls;
    (*v)(sq, q) = 1;
    (*w)(q, sq) = 1;
    if (nr == 0) continue;
    V ars(nr);
    for (int i = 0; i < nr; ++i) ars(i) = a(rest(i), sq);
    if (ars.isZero(0.0)) continue;
    V c = wr * ars;
    for (int r = 0; r < nr; ++r) {
      if (lr(r) == ls) return false;
      c(r) /= lr(r) - ls;
    }
    const V x = -(vr * c);
    for (int i = 0; i < nr; ++i) (*v)(rest(i), q) = x(i);
    for (int r = 0; r < nr; ++r) (*w)(ns + r, sq) = c(r);
  }
  return WellConditioned(*lambda, *v, *w);
}

}  // namespace

bool Decompose(const SmallMat& a, SmallVec* lambda, SmallMat* v, SmallMat* w) {
  return DecomposeImpl(a, lambda, v, w);
}
bool Decompose(const Eigen::MatrixXd& a, Eigen::VectorXd* lambda, Eigen::MatrixXd* v, Eigen::MatrixXd* w) {
  return DecomposeImpl(a, lambda, v, w);
}

namespace {

// A reversible 3×3 block (3cmt) as V_R diag(λ_R) W_R, at a fixed size. False when it is not
// symmetrisable (one-way flow): the general routine takes it.
bool ReversibleBlock3(const Eigen::Matrix3d& arr, double lr[3], double vr[3][3], double wr[3][3]) {
  Eigen::Vector3d t, l;
  Eigen::Matrix3d v, w;
  if (!SymmetrizingDiagonal(arr, &t) || !SymmetrisedModes(arr, t, &l, &v, &w)) return false;
  for (int k = 0; k < 3; ++k) {
    lr[k] = l(k);
    for (int i = 0; i < 3; ++i) {
      vr[i][k] = v(i, k);
      wr[k][i] = w(k, i);
    }
  }
  return true;
}

}  // namespace

template <int N>
SmallDecomposition DecomposeSmall(const Eigen::Matrix<double, N, N>& a, Eigen::Matrix<double, N, 1>* lambda,
                                  Eigen::Matrix<double, N, N>* v, Eigen::Matrix<double, N, N>* w) {
  // Depots (no inflow) and the rest, as in DecomposeImpl.
  int src[N], rest[N], ns = 0, nr = 0;
  for (int i = 0; i < N; ++i) {
    bool source = true;
    for (int k = 0; k < N && source; ++k) source = k == i || a(i, k) == 0;
    (source ? src[ns++] : rest[nr++]) = i;
  }
  if (nr == 0 || nr > 3) return SmallDecomposition::kOther;
  // The rest block A_RR = V_R diag(λ_R) W_R.
  double lr[3], vr[3][3], wr[3][3];
  if (nr == 1) {
    lr[0] = a(rest[0], rest[0]);
    vr[0][0] = wr[0][0] = 1;
  } else if (nr == 2) {
    const double a01 = a(rest[0], rest[1]), a10 = a(rest[1], rest[0]);
    if (!(a01 * a10 > 0)) return SmallDecomposition::kOther;  // one-way flow: the general eigensolver
    // In closed form (SymmetrisedModes at 2×2 costs about 430 instructions more per evaluation):
    // S = T⁻¹ A_RR T with T = diag(1, t1) is symmetric, with off-diagonal r. One Jacobi rotation
    // P = [[c, s], [−s, c]] (tan 2φ = 2r/(q − p), the smaller angle) gives Pᵀ S P = diag(p − t r, q + t r).
    const double t1 = std::sqrt(a10 / a01);
    const double p = a(rest[0], rest[0]), q = a(rest[1], rest[1]), r = std::copysign(std::sqrt(a01 * a10), a01);
    const double tau = (q - p) / (2 * r);
    const double t = (tau >= 0 ? 1.0 : -1.0) / (std::fabs(tau) + std::sqrt(1 + tau * tau));
    const double c = 1 / std::sqrt(1 + t * t), s = t * c;
    lr[0] = p - t * r;
    lr[1] = q + t * r;
    // V_R = T P, W_R = Pᵀ T⁻¹.
    vr[0][0] = c, vr[0][1] = s, vr[1][0] = -s * t1, vr[1][1] = c * t1;
    wr[0][0] = c, wr[0][1] = -s / t1, wr[1][0] = s, wr[1][1] = c / t1;
  } else {
    Eigen::Matrix3d arr = Eigen::Matrix3d::Zero();
    if constexpr (N >= 3) {
      for (int i = 0; i < 3; ++i) {
        for (int k = 0; k < 3; ++k) arr(i, k) = a(rest[i], rest[k]);
      }
    }
    if (!ReversibleBlock3(arr, lr, vr, wr)) return SmallDecomposition::kOther;
  }
  lambda->setZero();
  v->setZero();
  w->setZero();
  for (int k = 0; k < nr; ++k) {
    (*lambda)(ns + k) = lr[k];
    for (int i = 0; i < nr; ++i) {
      (*v)(rest[i], ns + k) = vr[i][k];
      (*w)(ns + k, rest[i]) = wr[k][i];
    }
  }
  // Depot modes, as in DecomposeImpl: c = (λ_R − λ_s)⁻¹ W_R a_Rs in W's depot column, −V_R c in V's.
  for (int d = 0; d < ns; ++d) {
    const int sd = src[d];
    const double ls = a(sd, sd);
    (*lambda)(d) = ls;
    (*v)(sd, d) = 1;
    (*w)(d, sd) = 1;
    double cr[3];
    for (int k = 0; k < nr; ++k) {
      double wa = 0;
      for (int i = 0; i < nr; ++i) wa += wr[k][i] * a(rest[i], sd);
      if (wa != 0 && lr[k] == ls) return SmallDecomposition::kUnsuitable;
      cr[k] = wa == 0 ? 0.0 : wa / (lr[k] - ls);
      (*w)(ns + k, sd) = cr[k];
    }
    for (int i = 0; i < nr; ++i) {
      double x = 0;
      for (int k = 0; k < nr; ++k) x -= vr[i][k] * cr[k];
      (*v)(rest[i], d) = x;
    }
  }
  return WellConditioned(*lambda, *v, *w) ? SmallDecomposition::kDone : SmallDecomposition::kUnsuitable;
}

template SmallDecomposition DecomposeSmall<2>(const Eigen::Matrix<double, 2, 2>&, Eigen::Matrix<double, 2, 1>*,
                                              Eigen::Matrix<double, 2, 2>*, Eigen::Matrix<double, 2, 2>*);
template SmallDecomposition DecomposeSmall<3>(const Eigen::Matrix<double, 3, 3>&, Eigen::Matrix<double, 3, 1>*,
                                              Eigen::Matrix<double, 3, 3>*, Eigen::Matrix<double, 3, 3>*);
template SmallDecomposition DecomposeSmall<4>(const Eigen::Matrix<double, 4, 4>&, Eigen::Matrix<double, 4, 1>*,
                                              Eigen::Matrix<double, 4, 4>*, Eigen::Matrix<double, 4, 4>*);

}  // namespace modal_detail

std::unique_ptr<ModalEvaluator> NewModalEvaluator(const LinearModel& model) {
  using modal_detail::Modal;
  // Two to four states (most PK models): sizes known at compile time.
  if (std::unique_ptr<ModalEvaluator> fixed = NewFixedSizeModal(model)) return fixed;
  // Up to 6 states the matrices live on the stack (no allocation per step).
  if (model.num_compartments() <= 6) return std::unique_ptr<ModalEvaluator>(new Modal<Eigen::Dynamic, 6>(model));
  return std::unique_ptr<ModalEvaluator>(new Modal<Eigen::Dynamic, Eigen::Dynamic>(model));
}

}  // namespace internal
}  // namespace pk
