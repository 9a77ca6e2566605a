// Boost.Odeint is sealed in this file.
#include "rk_solver.h"

#include <algorithm>
#include <cmath>
#include <exception>
#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <type_traits>

#include <unistd.h>

#include <boost/numeric/odeint.hpp>
#include <boost/numeric/odeint/external/eigen/eigen.hpp>

#include "cvodes_solver.h"
#include "ode/coloured_jacobian.h"
#include "rosenbrock.h"
#include "numerical_failure.h"

namespace pk {
namespace internal {
namespace {

namespace odeint = boost::numeric::odeint;
using State = Eigen::VectorXd;
// always_resizer: the state's size changes between calls (values alone, with S, with quadratures), and
// Odeint's default sizes its buffers once.
using Stepper = odeint::runge_kutta_dopri5<State, double, State, double, odeint::vector_space_algebra,
                                           odeint::default_operations, odeint::always_resizer>;
using Rhs = std::function<void(const State& z, State& dz, double t)>;

// Odeint's default error norm, max_i |e_i| / (atol + rtol (|x_i| + |h| |x'_i|)), in one loop over the
// state: on Eigen vectors Odeint's expression for it allocated four temporaries a step, a tenth of a
// small model's fit. The same operations in the same order, so the same steps; a NaN in any entry
// rejects the step (Odeint accepts a NaN norm, and Eigen's maxCoeff had left NaN to the SIMD
// instruction's whim), so a trial step that left f's domain is retried five times shorter.
class ErrorNorm {
 public:
  typedef double value_type;
  typedef odeint::vector_space_algebra algebra_type;
  typedef odeint::default_operations operations_type;

  ErrorNorm(double atol, double rtol) : atol_(atol), rtol_(rtol) {}
  template <class Time>
  double error(const State& x, const State& dxdt, State& err, Time dt) const {
    algebra_type algebra;
    return error(algebra, x, dxdt, err, dt);
  }
  template <class Time>
  double error(algebra_type&, const State& x, const State& dxdt, State& err, Time dt) const {
    const double a_dxdt = 1.0 * std::abs(dt);  // Odeint's a_dxdt = 1 times |dt|
    double norm = 0;
    bool nan = false;
    for (Eigen::Index i = 0; i < err.size(); ++i) {
      err(i) = std::abs(err(i)) / (atol_ + rtol_ * (1.0 * std::abs(x(i)) + a_dxdt * std::abs(dxdt(i))));
      nan = nan || std::isnan(err(i));
      norm = std::max(norm, err(i));
    }
    return nan ? std::numeric_limits<double>::infinity() : norm;  // rejected: the control retries smaller
  }

 private:
  double atol_, rtol_;
};
using Controlled = odeint::controlled_runge_kutta<Stepper, ErrorNorm>;
using Dense = odeint::dense_output_runge_kutta<Controlled>;

Dense MakeDense(double atol, double rtol) {
  return Dense(Controlled(ErrorNorm(atol, rtol), Controlled::step_adjuster_type(), Stepper()));
}

// Dormand–Prince 5(4), the tableau Odeint's runge_kutta_dopri5 steps with: the stages of a step are
// recomputed from its start for the discrete adjoint (Odeint does not expose them). b₇ = 0, so the
// seventh stage (the next step's first, FSAL) does not enter x_{n+1}.
constexpr int kStages = 6;
// A segment no longer than this is empty, as CVODES's solver takes it.
constexpr double kEmptySegment = 1e-13;
constexpr double kA[kStages][kStages] = {
    {0, 0, 0, 0, 0, 0},
    {1.0 / 5, 0, 0, 0, 0, 0},
    {3.0 / 40, 9.0 / 40, 0, 0, 0, 0},
    {44.0 / 45, -56.0 / 15, 32.0 / 9, 0, 0, 0},
    {19372.0 / 6561, -25360.0 / 2187, 64448.0 / 6561, -212.0 / 729, 0, 0},
    {9017.0 / 3168, -355.0 / 33, 46732.0 / 5247, 49.0 / 176, -5103.0 / 18656, 0}};
constexpr double kB[kStages] = {35.0 / 384, 0, 500.0 / 1113, 125.0 / 192, -2187.0 / 6784, 11.0 / 84};

// X_i = x + h Σ_{j<i} a_ij K_j and κ_i = h (b_i λ + Σ_{j>i} a_ji ξ_j), entry by entry in one pass over the
// state: the backward pass forms six of each a step, and a pass per term was a tenth of its time. Each
// entry's terms are added left to right, the coefficients h·a taken first, as Eigen's sum of the
// columns did (the same bits), in loops the AVX2 clone runs four entries an instruction (Eigen in the
// x86-64 baseline takes two).
template <int I>
void StagePointOf(Eigen::Index n, double h, const double* __restrict x, const double* __restrict k,
                  double* __restrict point) {
  double c[kStages];
  for (int j = 0; j < I; ++j) c[j] = h * kA[I][j];
  for (Eigen::Index r = 0; r < n; ++r) {
    double sum = x[r];
    for (int j = 0; j < I; ++j) sum += c[j] * k[j * n + r];
    point[r] = sum;
  }
}

template <int I>
void StageAdjointOf(Eigen::Index n, double h, const double* __restrict lambda, const double* __restrict xi,
                    double* __restrict kappa) {
  const double own = h * kB[I];
  double c[kStages];
  for (int j = I + 1; j < kStages; ++j) c[j] = h * kA[j][I];
  for (Eigen::Index r = 0; r < n; ++r) {
    double sum = own * lambda[r];
    for (int j = I + 1; j < kStages; ++j) sum += c[j] * xi[j * n + r];
    kappa[r] = sum;
  }
}

// f(std::integral_constant<int, i>()) for a stage 0 ≤ i < kStages known at run time (the loops above
// take it as a constant).
template <typename F>
void ForStage(int i, const F& f) {
  switch (i) {
    case 0: return f(std::integral_constant<int, 0>());
    case 1: return f(std::integral_constant<int, 1>());
    case 2: return f(std::integral_constant<int, 2>());
    case 3: return f(std::integral_constant<int, 3>());
    case 4: return f(std::integral_constant<int, 4>());
    default: return f(std::integral_constant<int, 5>());
  }
}

void StagePoint(int i, double h, const Eigen::VectorXd& x, const Eigen::MatrixXd& k, Eigen::VectorXd* point) {
  const Eigen::Index n = x.size();
  eigen_assert(k.rows() == n && k.cols() >= kStages - 1);  // what Eigen's sums checked
  point->resize(n);
  const double *const xs = x.data(), *const ks = k.data();
  double* const out = point->data();
  CallOnLanes([&] { ForStage(i, [&](auto stage) { StagePointOf<decltype(stage)::value>(n, h, xs, ks, out); }); });
}

void StageAdjoint(int i, double h, const Eigen::VectorXd& lambda, const Eigen::MatrixXd& xi, Eigen::VectorXd* kappa) {
  const Eigen::Index n = lambda.size();
  eigen_assert(xi.rows() == n && xi.cols() == kStages);
  kappa->resize(n);
  const double *const ls = lambda.data(), *const xs = xi.data();
  double* const out = kappa->data();
  CallOnLanes([&] { ForStage(i, [&](auto stage) { StageAdjointOf<decltype(stage)::value>(n, h, ls, xs, out); }); });
}

// The reverse of one step of length h, from λ_{n+1} to λ_n (Impl::Backward's recursion): κ_i, then
// ξ_i = sweep(i, κ_i) (f_x(X_i)ᵀκ_i written into column i of xi), λ += Σ ξ_i, and Σκ kept when ∂u/∂p
// enters. The recomputing and the kept-stages passes differ only in how they sweep a stage.
struct StepReverse {
  StepReverse(Eigen::Index n, bool with_du)
      : xi(n, kStages), kappa(n), lambda_next(n), kappa_sum(Eigen::VectorXd::Zero(n)), with_du(with_du) {}
  template <typename Sweep>
  void Step(double h, Eigen::VectorXd* lambda, const Sweep& sweep) {
    lambda_next = *lambda;
    for (int i = kStages - 1; i >= 0; --i) {
      StageAdjoint(i, h, lambda_next, xi, &kappa);
      sweep(i, kappa, xi.col(i).data());
      if (with_du) kappa_sum += kappa;
      *lambda += xi.col(i);
    }
  }
  // The segment's q = (Σ wᵀf_θ) ∂θ/∂p + (Σκ)ᵀ ∂u/∂p.
  Eigen::RowVectorXd Parameters(const Eigen::VectorXd& theta_product, const Eigen::MatrixXd& dtheta,
                                const Eigen::MatrixXd& du) const {
    Eigen::RowVectorXd q = theta_product.transpose() * dtheta;
    if (with_du) q += kappa_sum.transpose() * du;
    return q;
  }

  Eigen::MatrixXd xi;
  Eigen::VectorXd kappa, lambda_next, kappa_sum;
  const bool with_du;
};

// A segment's steps' stages evaluated again from each step's start for the backward pass, each recorded
// by `stages` (a StageTape or a ColouredJacobian) as it is formed: X_0 = x_n, X_i = x_n + h Σ_{j<i} a_ij k_j,
// with k_i = f(X_i) + u; the slopes go straight into their columns.
struct StagesAgain {
  explicit StagesAgain(const Eigen::VectorXd& u)
      : u(u), with_u(!u.isZero(0.0)), k(u.size(), kStages), start(u.size()), point(u.size()) {}
  template <typename Stages>
  void Record(Stages* stages, const Eigen::Ref<const Eigen::VectorXd>& x, double h, OdeStatistics* stats) {
    stages->NewStep();
    start = x;
    for (int i = 0; i < kStages; ++i) {
      if (i > 0) StagePoint(i, h, start, k, &point);
      stages->Record(i > 0 ? point : start, k.col(i).data());
      if (with_u) k.col(i) += u;
      ++stats->rhs_evaluations;
    }
  }
  const Eigen::VectorXd& u;
  const bool with_u;  // without input rates, k_i = f(X_i)
  Eigen::MatrixXd k;
  Eigen::VectorXd start, point;
};

// One segment's accepted steps, for the discrete adjoint: the state at each step's start and its length.
// The starts are `count` columns of n numbers in the solver's arena (RkSolver::Impl::Starts), from `first`.
struct StoredSteps {
  SegmentInput in;
  size_t first = 0;
  Eigen::Index count = 0;
  std::vector<double> h;
  bool stiff = false;  // a stiff segment: Rosenbrock's, from its one column (its start) in the backward pass
  // With kept stages (OdeOptions::adjoint_keeps_stages): the lanes that evaluated them, and their slots
  // in the solver's StageSlots, step s's stage i at first_slot + kStages·s + i, for the first
  // `kept_steps` steps; the budget of kept stages ran out at the later ones, whose stages the backward
  // pass evaluates again on the same lanes.
  std::unique_ptr<ColouredJacobian> lanes;
  size_t first_slot = 0;
  Eigen::Index kept_steps = 0;
  int shares = -1;     // ≥ 0: in.dtheta and in.du are left empty, and are stored segment `shares`'s
};

// The step starts of an adjoint's stored segments, one array whose capacity stays with the thread between
// evaluations. Each evaluation's solver held them in arrays of its own, some hundreds of kB on a 32-state
// chain: freed at the heap's top, glibc gave the pages back to the kernel (brk) and the next evaluation
// took them again, page faults and all, 3000 times in pkbench's run of the chains (the adjoint's cost
// at n = 32 went from 5.7 solves to 7.3–8.5 after the smaller chains had shaped the heap).
std::vector<double>& KeptArena() {
  static thread_local std::vector<double> arena;
  return arena;
}
// The kept stages' lanes (OdeOptions::adjoint_keeps_stages), held the same way and for the same reason.
StageSlots& KeptSlots() {
  static thread_local StageSlots slots;
  return slots;
}

// Kept stages an evaluation may hold (OdeOptions::adjoint_kept_stage_bytes), in slots of n numbers
// with `width` lanes each. The budget keeps the earliest steps, which the backward pass sweeps last:
// the later steps' forward pass touches only their starts, and their backward pass a step's stages at a
// time, so stages within half the L2 are still there when their turn comes; which steps are the latest
// is known only when the forward pass ends. Budgets from 0.5 to 3 MB cost the same on the 32-chain.
size_t KeptSlotLimit(const OdeOptions& opt, int n, int width) {
  long bytes = opt.adjoint_kept_stage_bytes;
  if (bytes == 0) {
    static const long half_l2 = [] {
      const long l2 = sysconf(_SC_LEVEL2_CACHE_SIZE);
      return l2 > 0 ? l2 / 2 : 512L * 1024;
    }();
    bytes = half_l2;
  }
  const size_t slot = static_cast<size_t>(n) * static_cast<size_t>(width + 1) * sizeof(double);
  return static_cast<size_t>(bytes) / slot;
}

// h·‖f_x‖∞ above which a segment is stiff for an explicit method: Dormand–Prince's stability region
// reaches about 3.3 along the negative axis, so stability alone would take some 300 steps, however
// smooth the solution; RODAS4 takes the segment in tens. (‖f_x‖∞ bounds the spectral radius.)
constexpr double kStiffness = 1000;
// Steps a segment may take before it counts as stiff after all (the test above reads the segment's
// start only; a Michaelis–Menten system stiffens as the drug clears): it is then done again from its
// start by RODAS4. Non-stiff PK segments take tens of steps.
constexpr long kStiffBudget = 1000;
// And every so many steps the step itself is tested, after Hairer & Wanner's stiffness test for DOPRI5
// (II §IV.2): when h·‖f_x(x)‖∞ exceeds this, the step is near Dormand–Prince's stability boundary
// (about 3.3 on the negative axis). Like Hairer's test, which asks for 15 such steps in a row, it
// must hold at kStiffChecksInARow consecutive checks before the segment goes to RODAS4 from its start:
// the row-sum norm bounds the spectral radius from above, by a factor of about 2 on a transit chain,
// whose Jacobian is bidiagonal, so one check alone judged such a chain stiff wherever its steps came
// within half of the stability limit. There RODAS4's Jacobian and LU each step cost more than the
// explicit steps it saves (a 32-compartment saturable chain in pkbench: solve 2.4 times, adjoint 5
// times slower). A Michaelis–Menten segment that stiffens as the drug clears wastes about a hundred
// explicit steps, not the whole budget.
constexpr long kStiffnessCheckEvery = 25;
// The adjoint's forward pass keeps each step within h·‖f_x‖∞ ≤ kStableStep (Dormand–Prince's stability
// boundary on the negative axis), ‖f_x‖∞ taken every kStableStepEvery steps. Without it the error
// control lets steps grow past the boundary where the modes it would amplify are below the absolute
// tolerance: the values stay within the tolerance, but the map of the frozen steps, whose derivative
// the discrete adjoint is, amplifies them (λ reached 1e21 on pkbench's 16-compartment chain), and the
// gradient was 5e-5 off at rtol 1e-8 (1.5e-6 at 1e-10), converging as rtol only when atol was made
// negligible. With the cap it agrees with the forward route to 1e-7 at 1e-8 and 9e-10 at 1e-10, for
// 6% more steps there (tests/test_coloured_jacobian.cc).
// A binding cap counts as stability-limited in CheckStiffening (it is given the control's proposal,
// and kStableStep > kStabilityLimited), deliberately: steps the accuracy would allow but stability
// forbids are what stiffness means, and the segment goes to RODAS4 as it would without the cap, where
// the control's steps would hover at the boundary. The cap changes the steps, not that decision.
constexpr double kStableStep = 3.3;
constexpr long kStableStepEvery = 5;
constexpr double kStabilityLimited = 2.5;
constexpr int kStiffChecksInARow = 4;
struct StiffSegment {};  // thrown by the stepping loops when the budget is spent

}  // namespace

struct RkSolver::Impl {
  const OdeSystem& sys;
  OdeOptions opt;
  int n;
  OdeStatistics stats;
  Eigen::MatrixXd s_buf, df_buf;  // scratch of the right-hand sides
  Eigen::VectorXd x_buf, f_buf, start_buf;
  std::vector<double> arena;  // StoredSteps' starts (see KeptArena)
  StageSlots slots;       // kept stages' lanes (see KeptSlots), [0, slots_used) in use
  size_t slots_used = 0;
  Eigen::Map<const Eigen::MatrixXd> Starts(const StoredSteps& s) const {
    return Eigen::Map<const Eigen::MatrixXd>(arena.data() + s.first, n, s.count);
  }
  // A stored segment's input, its ∂θ/∂p (m×k) and ∂u/∂p (n×k) held once for the segments that follow
  // with the same ones: on the 32-state chain with 64 free parameters they were 48 kB copied a segment,
  // whose release at the end of each evaluation had glibc trim the heap (see KeptArena). It copies
  // every field of SegmentInput but those two by name: a field added there must be added here.
  void KeepInput(const SegmentInput& in, StoredSteps* steps) const {
    SegmentInput& kept = steps->in;
    kept.h = in.h;
    kept.u = in.u;
    kept.theta = in.theta;
    kept.continuous = in.continuous;
    kept.auc_key = in.auc_key;
    steps->shares = -1;
    if (!stored.empty()) {
      const int last = stored.back().shares >= 0 ? stored.back().shares : static_cast<int>(stored.size()) - 1;
      const SegmentInput& o = stored[static_cast<size_t>(last)].in;
      // One parameter set's ∂θ/∂p is one shared matrix: known the same without comparing m×k numbers.
      if (o.dtheta.Equals(in.dtheta) && SameMatrix(o.du, in.du)) {
        steps->shares = last;
        kept.dtheta = SharedMatrix();
        kept.du.resize(0, 0);
        return;
      }
    }
    kept.dtheta = in.dtheta;
    kept.du = in.du;
  }
  const SegmentInput& Owner(const StoredSteps& s) const {
    return s.shares >= 0 ? stored[static_cast<size_t>(s.shares)].in : s.in;
  }
  // The segment's whole input (a copy when it shares).
  SegmentInput WholeInput(const StoredSteps& s) const {
    SegmentInput in = s.in;
    in.dtheta = Owner(s).dtheta;
    in.du = Owner(s).du;
    return in;
  }

  // The problem the stepper is on, for a segment that continues it (see rk_solver.h).
  Dense dense = MakeDense(1e-10, 1e-8);
  struct Continuation {
    bool at_end = false;
    double t = 0;  // the stepper's time at the end of the last segment
    int k = -1;    // sensitivity directions (-1: values only)
    Eigen::VectorXd z, theta, u;
    Eigen::MatrixXd du;
    SharedMatrix dtheta;
    bool Continues(const SegmentInput& s, const Eigen::VectorXd& z0, int directions) const {
      return at_end && s.continuous.empty() && s.auc_key == 0 && k == directions && z == z0 && theta == s.theta &&
             u == s.u && (k < 0 || (dtheta.Equals(s.dtheta) && SameMatrix(du, s.du)));
    }
  } last;

  // With an adjoint tape: steps that end exactly at each segment's end, recorded or replayable, and no
  // continuation through samples (a replay from the segment's start must take the same steps).
  bool replay = false;
  std::vector<StoredSteps> stored;
  struct Carry {  // the last stored segment's end and its last step proposal (0: none to carry)
    double step = 0;
    Eigen::VectorXd theta, u, x;
  } carry;
  long stored_bytes = 0;

  Impl(const OdeSystem& s, const OdeOptions& o, bool tape) : sys(s), opt(o), n(s.n()), replay(tape) {
    dense = MakeDense(opt.absolute_tolerance, opt.relative_tolerance);
    arena.swap(KeptArena());  // the thread's (a second solver alive at once starts its own)
    arena.clear();
    if (replay) std::swap(slots, KeptSlots());  // likewise, for a solver that keeps stages at all
    slots_used = 0;
  }
  ~Impl() {
    std::vector<double>& kept = KeptArena();
    if (arena.capacity() > kept.capacity()) {
      arena.clear();
      kept.swap(arena);
    }
    StageSlots& kept_slots = KeptSlots();
    if (replay && slots.doubles() > kept_slots.doubles()) std::swap(slots, kept_slots);
  }

  // Stiff segments go to RODAS4 (rosenbrock.h): whether one is stiff is decided from the segment
  // alone (θ, u, its start and length), so a replay decides the same. Those that also integrate a
  // quadrature (a continuous record's loss, an AUC) go to CVODES's BDF (created on the first).
  Rosenbrock rosenbrock{sys, opt, &stats};
  std::unique_ptr<CvodesSolver> bdf;
  mutable OdeStatistics combined;  // stats plus the fallback's, for statistics()
  bool Stiff(const SegmentInput& in, const Eigen::VectorXd& x0) { return in.h * RowSumNorm(in, x0) > kStiffness; }
  // ‖f_x(x)‖∞, 0 when not finite (Dormand–Prince may still pass).
  double RowSumNorm(const SegmentInput& in, const Eigen::VectorXd& x) { return FiniteOrZero(StateRowSumNorm(in, x)); }
  // ‖f_x(x)‖∞ as it is, NaN or ∞ included: from one evaluation of f on the lanes of a compressed
  // Jacobian where the model has one (the stiffness checks' f_x in n tangent directions were a tenth
  // of a solve of a 16-compartment chain), else from f_x. Every check of every route takes it here,
  // so a replay decides as its forward pass did.
  double StateRowSumNorm(const SegmentInput& in, const Eigen::VectorXd& x) {
    if (ColouredJacobian* lanes = NormLanes(in.theta)) return lanes->StateRowSumNorm(x);
    sys.StateJacobian(x, in.theta, &fx_buf);
    return fx_buf.cwiseAbs().rowwise().sum().maxCoeff<Eigen::PropagateNaN>();
  }
  Eigen::MatrixXd fx_buf;  // StateRowSumNorm's f_x, kept
  // The lanes for θ (null without them), made again when θ changes.
  ColouredJacobian* NormLanes(const Eigen::VectorXd& theta) {
    if (!opt.compressed_jacobians || sys.is_linear()) return nullptr;
    if (!norm_lanes_made || norm_theta.size() != theta.size() || norm_theta != theta) {
      norm_lanes = ColouredJacobian::For(*sys.nonlinear(), theta);
      norm_theta = theta;
      norm_lanes_made = true;
    }
    return norm_lanes.get();
  }
  std::unique_ptr<ColouredJacobian> norm_lanes;
  Eigen::VectorXd norm_theta;
  bool norm_lanes_made = false;
  static double FiniteOrZero(double norm) { return std::isfinite(norm) ? norm : 0.0; }
  // The periodic test above, after `count` steps of the segment, the last proposal `dt`, at x;
  // *in_a_row counts the segment's consecutive checks that found the step stability-limited.
  // With `kept`, ‖f_x(x)‖∞ comes from kept slot `slot`, evaluated at x.
  void CheckStiffening(const SegmentInput& in, long count, double dt, const Eigen::VectorXd& x, int* in_a_row,
                       ColouredJacobian* kept = nullptr, size_t slot = 0) {
    if (count > kStiffBudget) throw StiffSegment();
    if (count % kStiffnessCheckEvery != 0) return;
    const double norm = kept ? FiniteOrZero(kept->StateRowSumNormAt(slots, slot)) : RowSumNorm(in, x);
    *in_a_row = dt * norm > kStabilityLimited ? *in_a_row + 1 : 0;
    if (*in_a_row >= kStiffChecksInARow) throw StiffSegment();
  }
  CvodesSolver& Bdf() {
    if (!bdf) bdf.reset(new CvodesSolver(sys, opt));
    last.at_end = false;
    return *bdf;
  }
  Rosenbrock& Rodas() {
    last.at_end = false;
    return rosenbrock;
  }
  // A stiff segment's values: RODAS4, or BDF when it also integrates a quadrature.
  void StiffAdvance(const SegmentInput& in, Eigen::VectorXd* x, bool quadrature, double* loss, double* auc,
                    double* loss_time) {
    if (quadrature) {
      Bdf().Advance(in, x, loss, auc, loss_time);
    } else {
      Rodas().Advance(in, x);
    }
  }
  // Its sensitivities: the same choice.
  void StiffSensitivity(const SegmentInput& in, Eigen::VectorXd* x, Eigen::MatrixXd* s, bool with_loss, double* loss,
                        Eigen::RowVectorXd* dloss, double* loss_time) {
    if (with_loss) {
      Bdf().AdvanceSensitivity(in, x, s, loss, dloss, loss_time);
    } else {
      Rodas().AdvanceSensitivity(in, x, s);
    }
  }

  // Replay mode's stepping of a values-only segment (into *steps when given): false, with x as it
  // was, when the segment is stiff at its start or spends the step budget, and RODAS4 must take it.
  // Without a carried step (FixedEndSteps) the same segment always gives the same answer, so a segment
  // and its replay agree; with one, the steps are stored and never replayed.
  // *carry: see FixedEndSteps.
  bool ReplaySteps(const SegmentInput& in, Eigen::VectorXd* x, StoredSteps* steps, double* carry = nullptr) {
    if (Stiff(in, *x)) return false;
    start_of_segment = *x;
    try {
      FixedEndSteps(in, x, steps, carry);
    } catch (const StiffSegment&) {
      *x = start_of_segment;
      if (steps) {
        arena.resize(steps->first);
        *steps = StoredSteps();  // its kept stages, if any, were never counted in slots_used
      }
      return false;
    }
    return true;
  }
  Eigen::VectorXd start_of_segment;  // ReplaySteps's copy of x
  std::unique_ptr<Controlled> replay_stepper;  // FixedEndSteps's

  // Values only, replay mode: x ← x(h) by controlled steps whose last one ends at h, each accepted
  // step's start and length into *steps when given. The same x and `in` give the same steps, unless
  // `carry` is given: a segment that continues the last one (a sample between them) then tries
  // *carry > 0 first, the step the control proposed there, instead of restarting from a small step
  // (what stepping through the sample would do), and *carry is left with this segment's last
  // proposal. Only a stored segment may carry a step over: its steps are kept, never replayed. Steps
  // stay within kStableStep / ‖f_x‖∞ (see there: the adjoint differentiates these steps' map).
  // The segment's right-hand side on the state alone: f straight into the slope, u added where there is
  // one (copies of the state and of f through scratch vectors were a sixth of a plain segment's time).
  Rhs StateRhs(const SegmentInput& in) {
    const bool with_u = !in.u.isZero(0.0);
    return [this, &in, with_u](const State& z, State& dz, double) {
      ++stats.rhs_evaluations;
      sys.Rhs(z, in.theta, &dz);
      if (with_u) dz += in.u;
    };
  }
  void FixedEndSteps(const SegmentInput& in, Eigen::VectorXd* x, StoredSteps* steps, double* carry = nullptr) {
    const bool with_u = !in.u.isZero(0.0);  // as StateRhs and StagesAgain add u
    const Rhs rhs = StateRhs(in);
    // Kept stages: f on the lanes at every stage the stepper evaluates, the step's stage i into slot
    // base + i. Odeint's FSAL stepper evaluates stage 0 once, at its first step; then each try evaluates
    // stages 1…5 and the next step's stage 0 (slots base + 1 … base + 6), and a rejected try is
    // written over by the next. Steps are kept while their slots stay within the budget; after it
    // runs out, f is evaluated in double again (the same values: the lanes' are f's to the bit).
    std::unique_ptr<ColouredJacobian> lanes;
    size_t base = slots_used, limit = 0;
    if (steps && opt.adjoint_keeps_stages && opt.compressed_jacobians && !sys.is_linear()) {
      const int width = ColouredJacobian::ColouringOf(*sys.nonlinear())->width;
      if (width > 0) limit = KeptSlotLimit(opt, n, width);
      if (base + 1 + kStages <= limit) lanes = ColouredJacobian::For(*sys.nonlinear(), in.theta);  // a step fits
    }
    bool keeping = lanes != nullptr;
    Eigen::Index kept_steps = 0;
    // Whether slot `base` holds f at *x on the lanes: the last step's final evaluation was kept.
    const auto end_kept = [&](long count) { return lanes != nullptr && count > 0 && kept_steps == count; };
    bool first_evaluated = false;
    int call = 0;  // stages evaluated in this try
    const Rhs kept_rhs = [&](const State& z, State& dz, double) {
      ++stats.rhs_evaluations;
      const size_t slot = first_evaluated ? base + 1 + static_cast<size_t>(call++) : base;
      first_evaluated = true;
      dz.resize(n);
      lanes->RecordSlot(&slots, slot, limit, z, dz.data());
      if (with_u) dz += in.u;  // as rhs adds it
    };
    // One stepper for every segment, reset to evaluate its first slope again: a new one a segment
    // allocated its ten work vectors each time.
    if (!replay_stepper) replay_stepper.reset(new Controlled(ErrorNorm(opt.absolute_tolerance, opt.relative_tolerance)));
    Controlled& stepper = *replay_stepper;
    stepper.reset();
    double t = 0, dt = carry != nullptr && *carry > 0 ? std::min(*carry, in.h) : InitialStep(*x, rhs, in.h);
    long count = 0, tries = 0;
    int limited = 0;  // CheckStiffening's consecutive stability-limited checks
    if (steps) {
      steps->first = arena.size();  // the steps' starts follow, n numbers each
      steps->count = 0;
      steps->h.clear();
    }
    double stable_step = 0;  // kStableStep / ‖f_x‖∞ (0: no bound)
    while (t < in.h) {
      if (count % kStableStepEvery == 0) {
        // A norm that is not finite (f_x undefined at this x) leaves the last bound in place. With kept
        // stages, the last step's final evaluation was on the lanes at this very x.
        const double norm = end_kept(count) ? lanes->StateRowSumNormAt(slots, base) : StateRowSumNorm(in, *x);
        if (std::isfinite(norm)) stable_step = norm > 0 ? kStableStep / norm : 0;
      }
      if (stable_step > 0) dt = std::min(dt, stable_step);
      const bool last = dt >= in.h - t;
      double step = last ? in.h - t : dt;
      const double length = step;  // Odeint's step, not fl(t + step) − t
      start_buf = *x;
      double tt = t;
      call = 0;
      if (stepper.try_step(std::cref(keeping ? kept_rhs : rhs), *x, tt, step) == odeint::fail) {
        dt = step;  // the control's smaller proposal
        if (++tries > 1000) throw NumericalFailure("the Dormand–Prince step size control failed");
        continue;
      }
      tries = 0;  // consecutive rejections, as Odeint's own checker counts them
      if (!x->allFinite()) throw NumericalFailure("the ODE solution is not finite at t = " + std::to_string(tt));
      if (steps) {
        arena.insert(arena.end(), start_buf.data(), start_buf.data() + n);
        steps->h.push_back(length);
      }
      if (keeping) {
        base += kStages;  // the next step's stage 0 is this one's last evaluation
        kept_steps = static_cast<Eigen::Index>(steps->h.size());
        keeping = base + 1 + kStages <= limit;  // room for the next step's
      }
      t = last ? in.h : tt;
      dt = step;
      if (carry != nullptr) *carry = last ? std::max(*carry, step) : step;
      ++stats.steps;
      if (++count > opt.max_steps) {
        throw NumericalFailure("too much work: more than " + std::to_string(opt.max_steps) +
                               " Dormand–Prince steps between two events");
      }
      // A norm from a kept slot and one from an evaluation at x are the same bits.
      CheckStiffening(in, count, dt, *x, &limited, end_kept(count) ? lanes.get() : nullptr, base);
    }
    if (steps) {
      KeepInput(in, steps);
      steps->count = static_cast<Eigen::Index>(steps->h.size());
      if (lanes && kept_steps > 0) {
        steps->first_slot = slots_used;
        steps->kept_steps = kept_steps;
        slots_used = base + 1;
        steps->lanes = std::move(lanes);
      }
    }
  }

  // The discrete adjoint of `steps` (the seed's §4 done on the method's own steps): for each step,
  // backward, with stages X_i = x_n + h Σ_j a_ij k_j, k_i = f(X_i) + u, x_{n+1} = x_n + h Σ b_i k_i,
  //   κ_i = h (b_i λ_{n+1} + Σ_{j>i} a_ji ξ_j),   ξ_i = f_x(X_i)ᵀ κ_i,   λ_n = λ_{n+1} + Σ_i ξ_i,
  //   q += Σ_i κ_iᵀ (f_θ(X_i) ∂θ/∂p + ∂u/∂p).
  // The stages are recomputed from the step's start and recorded as they are (StageTape), then swept
  // backward: one recording and one sweep a stage, whatever the number of parameters.
  void Backward(const StoredSteps& steps, const Eigen::VectorXd& lambda_end, Eigen::VectorXd* lambda_start,
                Eigen::RowVectorXd* q) {
    if (steps.lanes) return BackwardKept(steps, lambda_end, lambda_start, q);
    const Eigen::MatrixXd& dtheta = Owner(steps).dtheta;
    const Eigen::MatrixXd& du = Owner(steps).du;
    const int k = static_cast<int>(dtheta.cols());
    const SegmentInput& in = steps.in;
    StageTape stages(sys, in.theta, opt.compressed_jacobians);
    StepReverse reverse(n, du.cols() == k);
    Eigen::VectorXd lambda = lambda_end;
    StagesAgain again(in.u);
    for (Eigen::Index step = steps.count - 1; step >= 0; --step) {
      const double h = steps.h[static_cast<size_t>(step)];
      again.Record(&stages, Starts(steps).col(step), h, &stats);
      reverse.Step(h, &lambda, [&](int i, const Eigen::VectorXd& w, double* wfx) { stages.Sweep(i, w, wfx); });
      ++stats.backward_steps;
    }
    *lambda_start = lambda;
    *q = reverse.Parameters(stages.ThetaProduct(), dtheta, du);
  }

  // Backward as above, on the stages the forward pass kept (OdeOptions::adjoint_keeps_stages): the
  // same sweeps in the same order, at the very points the forward pass evaluated. Steps past the kept
  // ones (the budget ran out) have their stages evaluated again on the same lanes, which a StageTape on
  // compressed Jacobians would do too: one running sum of θ's products, in the same order either way.
  void BackwardKept(const StoredSteps& steps, const Eigen::VectorXd& lambda_end, Eigen::VectorXd* lambda_start,
                    Eigen::RowVectorXd* q) {
    const Eigen::MatrixXd& dtheta = Owner(steps).dtheta;
    const Eigen::MatrixXd& du = Owner(steps).du;
    ColouredJacobian& lanes = *steps.lanes;
    lanes.ResetProducts();  // a stored segment may be swept again (another seed of the same forward pass)
    StepReverse reverse(n, du.cols() == dtheta.cols());
    Eigen::VectorXd lambda = lambda_end;
    StagesAgain again(steps.in.u);
    for (Eigen::Index step = steps.count - 1; step >= 0; --step) {
      const double h = steps.h[static_cast<size_t>(step)];
      if (step >= steps.kept_steps) {
        again.Record(&lanes, Starts(steps).col(step), h, &stats);
        reverse.Step(h, &lambda, [&](int i, const Eigen::VectorXd& w, double* wfx) { lanes.Sweep(i, w, wfx); });
      } else {
        const size_t base = steps.first_slot + static_cast<size_t>(kStages) * static_cast<size_t>(step);
        reverse.Step(h, &lambda, [&](int i, const Eigen::VectorXd& w, double* wfx) {
          lanes.SweepSlot(slots, base + static_cast<size_t>(i), w, wfx);
        });
      }
      ++stats.backward_steps;
    }
    *lambda_start = lambda;
    *q = reverse.Parameters(lanes.ThetaProduct(), dtheta, du);
  }

  // Hairer, Nørsett and Wanner's first step: 1% of the state's scale over its rate's, at most h.
  double InitialStep(const State& z, const Rhs& rhs, double h) {
    State f(z.size());
    rhs(z, f, 0.0);
    const Eigen::ArrayXd scale = opt.absolute_tolerance + opt.relative_tolerance * z.array().abs();
    const double d0 = (z.array() / scale).matrix().norm(), d1 = (f.array() / scale).matrix().norm();
    const double h0 = d0 < 1e-5 || d1 < 1e-5 ? 1e-6 : 0.01 * d0 / d1;
    return std::min(h0, h);
  }

  // z ← z(h) under `rhs`, continuing the stepper's problem when `continues`.
  void Integrate(const SegmentInput& in, const Rhs& rhs, double h, bool continues, State* z) {
    double target = h;
    if (continues) {
      target = last.t + h;
    } else {
      dense.initialize(*z, 0.0, InitialStep(*z, rhs, h));
    }
    long steps = 0;
    int limited = 0;  // CheckStiffening's consecutive stability-limited checks
    try {
      while (dense.current_time() < target) {
        dense.do_step(std::cref(rhs));
        ++stats.steps;
        if (!dense.current_state().allFinite()) {
          throw NumericalFailure("the ODE solution is not finite at t = " + std::to_string(dense.current_time()));
        }
        if (++steps > opt.max_steps) {
          throw NumericalFailure("too much work: more than " + std::to_string(opt.max_steps) +
                                 " Dormand–Prince steps between two events");
        }
        if (steps > kStiffBudget || steps % kStiffnessCheckEvery == 0) {
          CheckStiffening(in, steps, dense.current_time_step(), dense.current_state().head(n), &limited);
        }
      }
    } catch (const StiffSegment&) {
      last.at_end = false;
      throw;
    } catch (const NumericalFailure&) {
      last.at_end = false;
      throw;
    } catch (const std::exception& e) {  // Odeint's step-size failure
      last.at_end = false;
      throw NumericalFailure(std::string("the Dormand–Prince step size control failed: ") + e.what());
    }
    dense.calc_state(target, *z);
    last.t = target;
  }

  void Remember(const SegmentInput& s, const State& z, int k) {
    last.at_end = true;
    last.k = k;
    last.z = z;
    last.theta = s.theta;
    last.u = s.u;
    if (k >= 0) {
      last.dtheta = s.dtheta;
      last.du = s.du;
    }
  }
};

void DormandPrinceTo(const std::function<void(const Eigen::VectorXd&, Eigen::VectorXd*)>& f, double h, double atol,
                     double rtol, long max_steps, Eigen::VectorXd* z, double* first_step) {
  const Rhs rhs = [&](const State& zz, State& dz, double) { f(zz, &dz); };
  Controlled stepper(ErrorNorm(atol, rtol));
  double t = 0, dt = *first_step > 0 ? std::min(h, *first_step) : h;
  long steps = 0;
  while (t < h) {
    const bool last = dt >= h - t;
    double step = last ? h - t : dt;
    double tt = t;
    if (stepper.try_step(std::cref(rhs), *z, tt, step) == odeint::fail) {
      dt = step;  // the control's smaller proposal
    } else {
      if (!z->allFinite()) throw NumericalFailure("the solution is not finite at t = " + std::to_string(tt));
      t = last ? h : tt;
      dt = step;
      if (!last) *first_step = step;
    }
    if (++steps > max_steps) {
      throw NumericalFailure("too much work: more than " + std::to_string(max_steps) + " Dormand–Prince steps");
    }
  }
}

RkSolver::RkSolver(const OdeSystem& system, const OdeOptions& options, bool tape)
    : impl_(new Impl(system, options, tape)) {}

int RkSolver::StoreSegment(const SegmentInput& in, Eigen::VectorXd* x) {
  Impl& d = *impl_;
  StoredSteps steps;
  // A segment that continues the last stored one (same θ and inputs, from its end) carries its step.
  Impl::Carry& c = d.carry;
  if (!(c.step > 0 && in.theta == c.theta && in.u == c.u && *x == c.x)) c.step = 0;
  if (!(in.h > kEmptySegment)) {
    d.KeepInput(in, &steps);  // no steps: the backward pass passes λ through
  } else if (!d.ReplaySteps(in, x, &steps, &c.step)) {
    d.KeepInput(in, &steps);
    steps.stiff = true;
    steps.first = d.arena.size();  // the start and RODAS4's steps, for the backward pass
    steps.count = 1;
    d.arena.insert(d.arena.end(), x->data(), x->data() + d.n);
    d.Rodas().Advance(in, x, &steps.h);
    c.step = 0;
  }
  if (c.step > 0) {
    c.theta = in.theta;
    c.u = in.u;
    c.x = *x;
  }
  d.stored_bytes += static_cast<long>(sizeof(double)) * (steps.count * d.n + static_cast<long>(steps.h.size()));
  if (steps.lanes) {  // the kept stages: kStages a step and the last one's FSAL stage, W + 1 numbers a state
    const long slots = static_cast<long>(kStages) * steps.kept_steps + 1;
    d.stored_bytes += static_cast<long>(sizeof(double)) * slots * d.n * (steps.lanes->width() + 1);
  }
  d.stored.push_back(std::move(steps));
  d.stats.peak_adjoint_bytes = std::max(d.stats.peak_adjoint_bytes, d.stored_bytes);
  return static_cast<int>(d.stored.size()) - 1;
}

// `scales` serve CVODES's backward tolerances; RODAS4's and Dormand–Prince's adjoints need none.
void RkSolver::BackwardStored(int handle, const AdjointScales& /*scales*/, const Eigen::VectorXd& lambda_end,
                              Eigen::VectorXd* lambda_start, Eigen::RowVectorXd* q) {
  const StoredSteps& steps = impl_->stored.at(static_cast<size_t>(handle));
  if (steps.stiff) {
    const Eigen::VectorXd start = impl_->Starts(steps).col(0);
    impl_->Rodas().AdjointSegment(impl_->WholeInput(steps), start, steps.h, lambda_end, lambda_start, q);
    return;
  }
  impl_->Backward(steps, lambda_end, lambda_start, q);
}

void RkSolver::AdjointSegment(const SegmentInput& in, const Eigen::VectorXd& x0, const AdjointScales& /*scales*/,
                              const Eigen::VectorXd& lambda_end, Eigen::VectorXd* lambda_start, Eigen::RowVectorXd* q) {
  if (!(in.h > kEmptySegment)) {
    *lambda_start = lambda_end;
    *q = Eigen::RowVectorXd::Zero(in.dtheta->cols());
    return;
  }
  // The forward steps again from the segment's start (replay mode took these very steps), then back.
  StoredSteps steps;
  Eigen::VectorXd x = x0;
  if (!impl_->ReplaySteps(in, &x, &steps)) {  // a stiff segment, as the forward pass found it: its steps again
    x = x0;
    impl_->Rodas().Advance(in, &x, &steps.h);
    impl_->Rodas().AdjointSegment(in, x0, steps.h, lambda_end, lambda_start, q);
    return;
  }
  impl_->Backward(steps, lambda_end, lambda_start, q);
  impl_->arena.resize(steps.first);  // this segment's starts were needed for its backward pass only
  if (steps.lanes) impl_->slots_used = steps.first_slot;  // and its stages likewise
}
RkSolver::~RkSolver() = default;

const OdeStatistics& RkSolver::statistics() const {
  const Impl& d = *impl_;
  d.combined = d.stats;
  if (d.bdf) {
    const OdeStatistics& b = d.bdf->statistics();
    d.combined.steps += b.steps;
    d.combined.rhs_evaluations += b.rhs_evaluations;
    d.combined.jacobian_evaluations += b.jacobian_evaluations;
    d.combined.backward_steps += b.backward_steps;
    d.combined.peak_adjoint_bytes += b.peak_adjoint_bytes;  // both tapes are held together
  }
  return d.combined;
}

void RkSolver::Advance(const SegmentInput& in, Eigen::VectorXd* x, double* loss, double* auc, double* loss_time) {
  Impl& d = *impl_;
  if (!(in.h > kEmptySegment)) return;  // a zero lag that carries a derivative: no time passes
  const int n = d.n;
  const bool with_loss = loss != nullptr && !in.continuous.empty();
  const bool with_auc = auc != nullptr && in.auc_key != 0;
  if (d.replay && !with_loss && !with_auc) {  // the steps an adjoint replays (see Impl::replay)
    if (!d.ReplaySteps(in, x, nullptr)) d.Rodas().Advance(in, x);
    return;
  }
  if (d.Stiff(in, *x)) {
    d.StiffAdvance(in, x, with_loss || with_auc, loss, auc, loss_time);
    return;
  }
  // The state: x, then the continuous loss and ∫∂L/∂t, then ∫ y_auc dt.
  State z = State::Zero(n + (with_loss ? 2 : 0) + (with_auc ? 1 : 0));
  z.head(n) = *x;
  const Rhs rhs = [&](const State& zz, State& dz, double t) {
    ++d.stats.rhs_evaluations;
    Eigen::VectorXd& xs = d.x_buf;
    xs = zz.head(n);
    d.sys.Rhs(xs, in.theta, &d.f_buf);
    dz.resize(zz.size());
    dz.head(n) = d.f_buf + in.u;
    if (with_loss) {
      double lt = 0;
      dz(n) = ContinuousLoss(d.sys, in, t, xs, nullptr, &lt);
      dz(n + 1) = lt;
    }
    if (with_auc) dz(dz.size() - 1) = d.sys.Observe(in.auc_key, xs, in.theta);
  };
  const bool continues = !with_loss && !with_auc && d.last.Continues(in, z, -1);
  try {
    if (with_loss || with_auc) {
      d.Integrate(in, rhs, in.h, continues, &z);
    } else {
      d.Integrate(in, d.StateRhs(in), in.h, continues, &z);
    }
  } catch (const StiffSegment&) {  // x is as it was: Integrate writes z only at its end
    d.StiffAdvance(in, x, with_loss || with_auc, loss, auc, loss_time);
    return;
  }
  *x = z.head(n);
  if (with_loss) {
    *loss += z(n);
    if (loss_time) *loss_time += z(n + 1);
  }
  if (with_auc) *auc += z(z.size() - 1);
  if (with_loss || with_auc) {
    d.last.at_end = false;
  } else {
    d.Remember(in, z, -1);
  }
}

void RkSolver::AdvanceSensitivity(const SegmentInput& in, Eigen::VectorXd* x, Eigen::MatrixXd* s, double* loss,
                                  Eigen::RowVectorXd* dloss, double* loss_time) {
  Impl& d = *impl_;
  if (!(in.h > kEmptySegment)) return;
  const bool with_loss = loss != nullptr && !in.continuous.empty();
  if (d.Stiff(in, *x)) {
    d.StiffSensitivity(in, x, s, with_loss, loss, dloss, loss_time);
    return;
  }
  const int n = d.n;
  const int k = static_cast<int>(s->cols());
  // The state: x, vec S (column by column), then the loss, its k derivatives and ∫∂L/∂t.
  const Eigen::Index nk = static_cast<Eigen::Index>(n) * k;
  State z = State::Zero(n + nk + (with_loss ? k + 2 : 0));
  z.head(n) = *x;
  z.segment(n, nk) = Eigen::Map<const Eigen::VectorXd>(s->data(), nk);
  const Rhs rhs = [&](const State& zz, State& dz, double t) {
    ++d.stats.rhs_evaluations;
    dz.resize(zz.size());
    Eigen::VectorXd& xs = d.x_buf;
    // On lanes straight from z into dz where the model has them (a small model's right-hand side is
    // mostly copies otherwise); x and S are copied out for the recording's route and the loss.
    const bool in_place =
        d.sys.RhsDirectionalInPlace(zz.data(), zz.data() + n, k, in.theta, in.dtheta, dz.data(), dz.data() + n);
    if (!in_place || with_loss) {
      xs = zz.head(n);
      d.s_buf = Eigen::Map<const Eigen::MatrixXd>(zz.data() + n, n, k);
    }
    if (!in_place) {
      d.sys.RhsDirectional(xs, in.theta, d.s_buf, in.dtheta, &d.f_buf, &d.df_buf);
      dz.head(n) = d.f_buf;
      dz.segment(n, nk) = Eigen::Map<const Eigen::VectorXd>(d.df_buf.data(), nk);
    }
    dz.head(n) += in.u;
    if (in.du.cols() == k) dz.segment(n, nk) += Eigen::Map<const Eigen::VectorXd>(in.du.data(), nk);
    if (with_loss) {
      Eigen::VectorXd dl;
      double lt = 0;
      dz(n + nk) = ContinuousLoss(d.sys, in, t, xs, &dl, &lt);
      Eigen::RowVectorXd grad = Eigen::RowVectorXd::Zero(k);
      for (size_t i = 0; i < in.continuous.size(); ++i) {
        double y;
        Eigen::RowVectorXd dy;
        d.sys.ObserveDirectional(in.continuous[i].key, xs, in.theta, d.s_buf, in.dtheta, &y, &dy);
        grad += dl(static_cast<Eigen::Index>(i)) * dy;
      }
      dz.segment(n + nk + 1, k) = grad.transpose();
      dz(dz.size() - 1) = lt;
    }
  };
  const bool continues = !with_loss && d.last.Continues(in, z, k);
  try {
    d.Integrate(in, rhs, in.h, continues, &z);
  } catch (const StiffSegment&) {
    *x = z.head(n);  // unchanged: Integrate writes z only at the end
    d.StiffSensitivity(in, x, s, with_loss, loss, dloss, loss_time);
    return;
  }
  *x = z.head(n);
  *s = Eigen::Map<const Eigen::MatrixXd>(z.data() + n, n, k);
  if (with_loss) {
    *loss += z(n + nk);
    if (dloss) *dloss += z.segment(n + nk + 1, k).transpose();
    if (loss_time) *loss_time += z(z.size() - 1);
    d.last.at_end = false;
  } else {
    d.Remember(in, z, k);
  }
}

}  // namespace internal
}  // namespace pk
