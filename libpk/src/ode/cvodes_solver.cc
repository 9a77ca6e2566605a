#include "cvodes_solver.h"

#include <cmath>
#include <limits>
#include <map>
#include <sstream>
#include <string>
#include <tuple>

#include <cvodes/cvodes.h>
#include <nvector/nvector_serial.h>
#include <sunlinsol/sunlinsol_dense.h>
#include <sunmatrix/sunmatrix_dense.h>

#include "numerical_failure.h"
#include "sundials_kernels.h"

namespace pk {
namespace internal {
namespace {

using Map = Eigen::Map<Eigen::VectorXd>;

Map View(N_Vector v) { return Map(N_VGetArrayPointer(v), N_VGetLength(v)); }
Eigen::Map<Eigen::MatrixXd> View(SUNMatrix m) {
  return Eigen::Map<Eigen::MatrixXd>(SUNDenseMatrix_Data(m), SUNDenseMatrix_Rows(m), SUNDenseMatrix_Columns(m));
}

// RAII owners of SUNDIALS handles.
struct Context {
  SUNContext ctx = nullptr;
  Context() {
    if (SUNContext_Create(nullptr, &ctx) != 0) throw NumericalFailure("CVODES: cannot create a SUNDIALS context");
  }
  ~Context() { SUNContext_Free(&ctx); }
};
struct Vector {
  N_Vector v = nullptr;
  Vector(long n, SUNContext ctx) : v(N_VNew_Serial(n, ctx)) {
    if (v == nullptr) throw NumericalFailure("CVODES: out of memory");
    UseFastSerialOps(v);  // CVODES's work vectors are clones: they share the kernels
    N_VConst(0.0, v);
  }
  ~Vector() { N_VDestroy(v); }
  Vector(const Vector&) = delete;
  Vector& operator=(const Vector&) = delete;
};
struct VectorArray {
  N_Vector* v = nullptr;
  int count = 0;
  VectorArray(int k, N_Vector like) : v(N_VCloneVectorArray(k, like)), count(k) {
    for (int i = 0; i < k; ++i) N_VConst(0.0, v[i]);
  }
  ~VectorArray() { N_VDestroyVectorArray(v, count); }
  VectorArray(const VectorArray&) = delete;
  VectorArray& operator=(const VectorArray&) = delete;
};
struct LinearSolver {
  SUNMatrix a = nullptr;
  SUNLinearSolver ls = nullptr;
  LinearSolver(N_Vector y, long n, SUNContext ctx) : a(SUNDenseMatrix(n, n, ctx)), ls(SUNLinSol_Dense(y, a, ctx)) {
    if (a == nullptr || ls == nullptr) {
      if (ls) SUNLinSolFree(ls);
      if (a) SUNMatDestroy(a);
      throw NumericalFailure("CVODES: out of memory");
    }
    UseFastDenseOps(a);
    UseFastDenseSolver(ls);
  }
  ~LinearSolver() {
    SUNLinSolFree(ls);
    SUNMatDestroy(a);
  }
  LinearSolver(const LinearSolver&) = delete;
  LinearSolver& operator=(const LinearSolver&) = delete;
};
struct Memory {
  void* mem = nullptr;
  explicit Memory(SUNContext ctx) : mem(CVodeCreate(CV_BDF, ctx)) {}
  ~Memory() { CVodeFree(&mem); }
  Memory(const Memory&) = delete;
  Memory& operator=(const Memory&) = delete;
};

}  // namespace

double ContinuousLoss(const OdeSystem& sys, const SegmentInput& in, double t, const Eigen::VectorXd& x,
                      Eigen::VectorXd* dl_dy, double* lt, Eigen::VectorXd* dlt_dy) {
  double sum = 0;
  if (dl_dy) dl_dy->resize(in.continuous.size());
  if (dlt_dy) dlt_dy->resize(in.continuous.size());
  if (lt) *lt = 0;
  for (size_t i = 0; i < in.continuous.size(); ++i) {
    const ContinuousTerm& c = in.continuous[i];
    const double r = sys.Observe(c.key, x, in.theta) - (c.ym0 + c.ym_slope * t);
    const double w = c.w0 + c.w_slope * t;
    sum += 0.5 * w * r * r;
    const Eigen::Index k = static_cast<Eigen::Index>(i);
    if (dl_dy) (*dl_dy)(k) = w * r;
    if (lt) *lt += 0.5 * c.w_slope * r * r - w * r * c.ym_slope;
    if (dlt_dy) (*dlt_dy)(k) = c.w_slope * r - w * c.ym_slope;
  }
  return sum;
}

struct CvodesSolver::Impl {
  const OdeSystem& sys;
  OdeOptions opt;
  int n;
  Context context;
  OdeStatistics stats;
  std::string last_error;
  // The segment being integrated.
  const SegmentInput* in = nullptr;
  int k = 0;
  bool with_loss = false;  // state carries the continuous loss as entry n, ∫∂L/∂t as entry n+1
  bool with_auc = false;   // state carries ∫ y_auc_key dt as its last entry
  Eigen::VectorXd x_buf, f_buf;  // scratch of the right-hand sides
  Eigen::MatrixXd s_buf, df_buf;

  // Where a CVODES memory's last segment ended. A segment that starts there,
  // with the same state (and sensitivities), θ and inputs, is the same initial
  // value problem continued: a sample between them is not a discontinuity.
  // CVODES then carries on with its step size and order instead of restarting
  // at order 1 with a tiny step. Segments with continuous records or AUC carry
  // per-segment quadrature states and always restart.
  struct Continuation {
    bool at_end = false;
    double t = 0;    // the memory's time at the end
    long steps = 0;  // CVodeGetNumSteps there (it counts from the last CVodeReInit)
    Eigen::VectorXd x, theta, u;
    Eigen::MatrixXd s, du;
    SharedMatrix dtheta;

    bool Continues(const SegmentInput& in, const Eigen::VectorXd& x0, const Eigen::MatrixXd* s0) const {
      return at_end && in.continuous.empty() && x == x0 && theta == in.theta && u == in.u &&
             (s0 == nullptr || (SameMatrix(s, *s0) && dtheta.Equals(in.dtheta) && SameMatrix(du, in.du)));
    }
    void Remember(const SegmentInput& in, const Eigen::VectorXd& x1, const Eigen::MatrixXd* s1) {
      at_end = true;
      x = x1;
      theta = in.theta;
      u = in.u;
      if (s1) {
        s = *s1;
        dtheta = in.dtheta;
        du = in.du;
      }
    }
    void Restarted() {
      t = 0;
      steps = 0;
    }
    // Adds the steps taken since the last count to *total.
    void CountSteps(void* mem, long* total) {
      long now = 0;
      CVodeGetNumSteps(mem, &now);
      *total += now - steps;
      steps = now;
    }
  };

  // One CVODES instance per configuration: plain (with/without loss state),
  // forward sensitivities with k directions, and the adjoint.
  struct Forward {
    std::unique_ptr<Vector> y;
    std::unique_ptr<Memory> mem;
    std::unique_ptr<LinearSolver> ls;
    std::unique_ptr<VectorArray> ys;
    Continuation run;
  };

  std::map<std::pair<int, int>, Forward> forward;  // (k, with_loss + 2·with_auc)
  struct Adjoint {
    std::unique_ptr<Vector> y, yb, qb, atolb, atolq;
    std::unique_ptr<Memory> mem;
    std::unique_ptr<LinearSolver> ls, lsb;
    int which = -1;
    int kq = 0;
    long bytes = 0;        // CVODES's storage for this memory's trajectory
    Eigen::VectorXd xmax;  // recompute mode: max |x_i| over the segment's steps
    std::shared_ptr<Context> context;  // pooled memories carry their own context
    Continuation run;  // where the forward pass stands (ForwardStore, StoreSegment)
    int pool_kq = 0;
    // Steps per checkpoint this memory was made with: at most
    // opt.checkpoint_steps, fewer while its segments need fewer (see Grown).
    long checkpoint_steps = 0;
    bool overflowed = false;  // a checkpoint was needed below opt.checkpoint_steps
    Eigen::VectorXd x_start;  // the state its trajectory starts from
  };
  std::unique_ptr<Adjoint> adjoint;               // reused: recompute mode
  // Store mode: the memories, and the segments (pieces) of their trajectories.
  // Consecutive segments that continue the same initial value problem (a
  // sample between them) share one memory, as in CvodesSolver::Advance.
  std::vector<std::unique_ptr<Adjoint>> stored;
  struct Piece {
    int memory = -1;
    double t0 = 0, t1 = 0;  // in the memory's time
    SegmentInput segment;
    Eigen::VectorXd xmax;   // max |x_i| over the piece's steps
  };
  std::vector<Piece> pieces;
  long stored_bytes = 0;

  // CVodeAdjInit allocates Hermite data for all its steps per checkpoint at
  // once, used or not. A memory is therefore made for kInitialCheckpointSteps
  // and, when its trajectory needs a second checkpoint below
  // opt.checkpoint_steps, made again with room for all its steps and
  // integrated again from its start (Grown). While one checkpoint holds a
  // whole trajectory, CVODES's results do not depend on its size, so every
  // evaluation gives what a memory of opt.checkpoint_steps would have given,
  // whatever the pool held before. New memories of a pool start at the size
  // its memories have grown to.
  static constexpr long kInitialCheckpointSteps = 128;
  long InitialCheckpointSteps(int kq) const {
    return std::min<long>(opt.checkpoint_steps, std::max(kInitialCheckpointSteps, Pools()[Key(kq)].checkpoint_steps));
  }
  std::unique_ptr<Adjoint> Grown(const Adjoint& a, int kq) const {
    std::unique_ptr<Adjoint> b(new Adjoint);
    b->context = a.context;
    b->pool_kq = a.pool_kq;
    const long steps = a.run.steps;
    b->checkpoint_steps = std::min<long>(opt.checkpoint_steps, steps + steps / 4 + 16);
    long& hint = Pools()[Key(kq)].checkpoint_steps;
    hint = std::max(hint, b->checkpoint_steps);
    return b;
  }

  // Forward from the memory's time a.run.t over seg.h (from 0 and x0 when
  // `restart`), recording max |x_i| over the steps in *xmax.
  void ForwardStore(Adjoint& a, const SegmentInput& seg, const Eigen::VectorXd& x0, Eigen::VectorXd* x_end,
                    bool restart, Eigen::VectorXd* xmax);

  // The quadrature q = ∫λᵀf_p starts at zero on every segment, where its
  // absolute tolerance alone would govern: CVODES then starts the backward
  // solve with steps of 1e-12 and spends a dozen steps growing them after
  // every sample. Started from g/10 instead, with g the gradient accumulated
  // by the later segments, its error is controlled relative to a tenth of the
  // gradient (as forward sensitivities are relative to x_p), and the start
  // is subtracted again. The 10 keeps the adjoint as accurate as the forward
  // route at the same rtol; with 1 it was up to 7 times less accurate.
  static constexpr double kQuadratureMargin = 10.0;
  static const Eigen::VectorXd* QuadratureOffset(const AdjointScales& scales, int k) {
    return scales.gradient && scales.gradient->size() == k ? scales.gradient : nullptr;
  }
  static void SetQuadratureStart(Adjoint& a, const Eigen::VectorXd* offset) {
    if (offset) {
      View(a.qb->v) = *offset / kQuadratureMargin;
    } else {
      N_VConst(0.0, a.qb->v);
    }
  }

  // Allocating a CVODES adjoint memory (CVodeAdjInit allocates the storage
  // for checkpoint_steps steps) costs as much as integrating a short segment,
  // so the per-segment memories of the store-all mode are kept per thread and
  // reused by later evaluations with the same size and options.
  struct PoolKey {
    int n, kq, checkpoint_steps;
    double rtol, atol;
    long max_steps;
    bool operator<(const PoolKey& o) const {
      return std::tie(n, kq, checkpoint_steps, rtol, atol, max_steps) <
             std::tie(o.n, o.kq, o.checkpoint_steps, o.rtol, o.atol, o.max_steps);
    }
  };
  struct Pool {
    std::shared_ptr<Context> context = std::make_shared<Context>();
    std::vector<std::unique_ptr<Adjoint>> free;
    long checkpoint_steps = 0;  // the most any of its memories has grown to
  };
  static std::map<PoolKey, Pool>& Pools() {
    static thread_local std::map<PoolKey, Pool> pools;
    return pools;
  }
  PoolKey Key(int kq) const {
    return {n, kq, opt.checkpoint_steps, opt.relative_tolerance, opt.absolute_tolerance, opt.max_steps};
  }
  std::unique_ptr<Adjoint> Borrow(int kq) {
    Pool& pool = Pools()[Key(kq)];
    if (pool.free.empty()) {
      std::unique_ptr<Adjoint> a(new Adjoint);
      a->context = pool.context;
      return a;
    }
    std::unique_ptr<Adjoint> a = std::move(pool.free.back());
    pool.free.pop_back();
    return a;
  }
  void Return(std::unique_ptr<Adjoint> a) {
    if (!a || !a->mem) return;
    Pools()[Key(std::max(a->kq, 1))].free.push_back(std::move(a));
  }
  void Backward(Adjoint& a, const SegmentInput& seg, double t0, double t1, const Eigen::VectorXd& xmax,
                const AdjointScales& scales, const Eigen::VectorXd& lambda_end, Eigen::VectorXd* lambda_start,
                Eigen::RowVectorXd* q);

  Impl(const OdeSystem& s, const OdeOptions& o) : sys(s), opt(o), n(s.n()) {}

  static void ErrorHandler(int, const char*, const char* function, char* msg, void* data) {
    static_cast<Impl*>(data)->last_error = std::string(function) + ": " + msg;
  }

  void Check(int flag, const char* what) {
    if (flag >= 0) return;
    std::ostringstream os;
    os << "the ODE solver failed (" << what << ", flag " << flag << ")";
    if (!last_error.empty()) os << ": " << last_error;
    last_error.clear();
    throw NumericalFailure(os.str());
  }

  // The continuous loss integrand ½ w (y − y_m)² at local time t and its
  // derivative with respect to y, summed over the terms.
  // The continuous loss integrand L = Σ ½ w (y − y_m)² at local time t, its
  // derivatives ∂L/∂y per term, its explicit time derivative
  // L_t = Σ ½ w' r² − w r y_m' and ∂L_t/∂y per term (r = y − y_m).
  double LossIntegrand(double t, const Eigen::VectorXd& x, Eigen::VectorXd* dl_dy = nullptr, double* lt = nullptr,
                       Eigen::VectorXd* dlt_dy = nullptr) const {
    return ContinuousLoss(sys, *in, t, x, dl_dy, lt, dlt_dy);
  }

  static int Rhs(realtype t, N_Vector y, N_Vector ydot, void* data) {
    Impl& d = *static_cast<Impl*>(data);
    ++d.stats.rhs_evaluations;
    Eigen::VectorXd& x = d.x_buf;  // reused: no allocation per call
    x = View(y).head(d.n);
    d.sys.Rhs(x, d.in->theta, &d.f_buf);
    Map out = View(ydot);
    out.head(d.n) = d.f_buf + d.in->u;
    if (d.with_loss) {
      double lt = 0;
      out(d.n) = d.LossIntegrand(t, x, nullptr, &lt);
      out(d.n + 1) = lt;
    }
    if (d.with_auc) out(out.size() - 1) = d.sys.Observe(d.in->auc_key, x, d.in->theta);
    return out.allFinite() ? 0 : 1;
  }

  static int Jacobian(realtype t, N_Vector y, N_Vector, SUNMatrix jac, void* data, N_Vector, N_Vector, N_Vector) {
    Impl& d = *static_cast<Impl*>(data);
    ++d.stats.jacobian_evaluations;
    const Eigen::VectorXd x = View(y).head(d.n);
    auto j = View(jac);
    j.setZero();
    j.topLeftCorner(d.n, d.n) = d.sys.StateJacobian(x, d.in->theta);
    if (d.with_loss) {
      // ∂/∂x of ½ w (y − y_m)² = w (y − y_m) g_x, and likewise for L_t.
      Eigen::VectorXd dl, dlt;
      double lt;
      d.LossIntegrand(t, x, &dl, &lt, &dlt);
      for (size_t i = 0; i < d.in->continuous.size(); ++i) {
        double yv;
        Eigen::RowVectorXd gx;
        d.sys.ObserveDirectional(d.in->continuous[i].key, x, d.in->theta, Eigen::MatrixXd::Identity(d.n, d.n),
                                 Eigen::MatrixXd::Zero(d.sys.num_theta(), d.n), &yv, &gx);
        j.row(d.n).head(d.n) += dl(static_cast<Eigen::Index>(i)) * gx;
        j.row(d.n + 1).head(d.n) += dlt(static_cast<Eigen::Index>(i)) * gx;
      }
    }
    if (d.with_auc) {
      double yv;
      Eigen::RowVectorXd gx;
      d.sys.ObserveDirectional(d.in->auc_key, x, d.in->theta, Eigen::MatrixXd::Identity(d.n, d.n),
                               Eigen::MatrixXd::Zero(d.sys.num_theta(), d.n), &yv, &gx);
      j.row(j.rows() - 1).head(d.n) = gx;
    }
    return j.allFinite() ? 0 : 1;
  }

  // dS/dt = f_x S + f_θ ∂θ/∂p + ∂u/∂p for all k directions at once, from one
  // dual-number evaluation of f seeded with (S, ∂θ/∂p).
  static int SensitivityRhs(int k, realtype t, N_Vector y, N_Vector, N_Vector* ys, N_Vector* ysdot, void* data,
                            N_Vector, N_Vector) {
    Impl& d = *static_cast<Impl*>(data);
    Eigen::VectorXd& x = d.x_buf;
    x = View(y).head(d.n);
    Eigen::MatrixXd& s = d.s_buf;
    s.resize(d.n, k);
    for (int i = 0; i < k; ++i) s.col(i) = View(ys[i]).head(d.n);
    Eigen::MatrixXd& df = d.df_buf;
    d.sys.RhsDirectional(x, d.in->theta, s, d.in->dtheta, &d.f_buf, &df);
    if (d.in->du.cols() == k) df += d.in->du;
    Eigen::RowVectorXd dloss = Eigen::RowVectorXd::Zero(k);
    if (d.with_loss) {
      Eigen::VectorXd dl;
      d.LossIntegrand(t, x, &dl);
      for (size_t i = 0; i < d.in->continuous.size(); ++i) {
        double yv;
        Eigen::RowVectorXd dy;
        d.sys.ObserveDirectional(d.in->continuous[i].key, x, d.in->theta, s, d.in->dtheta, &yv, &dy);
        dloss += dl(static_cast<Eigen::Index>(i)) * dy;
      }
    }
    for (int i = 0; i < k; ++i) {
      Map out = View(ysdot[i]);
      out.head(d.n) = df.col(i);
      if (d.with_loss) {
        out(d.n) = dloss(i);
        out(d.n + 1) = 0;  // ∫L_t is needed as a value only
      }
    }
    return df.allFinite() ? 0 : 1;
  }

  // λᵀf_x and λᵀf_θ at (t, x, λ). CVODES usually calls the backward right-hand
  // side and the quadrature at the same point, so one reverse pass serves both.
  struct VjpCache {
    double t = std::numeric_limits<double>::quiet_NaN();
    Eigen::VectorXd x, lambda, wfx, wft, f;
    Eigen::RowVectorXd q;  // the quadrature's integrand (scratch)
  } vjp;
  // The nonzero entries of the segment's ∂θ/∂p (m×k), listed by Backward: (λᵀf_θ)∂θ/∂p at every backward
  // step costs their number instead of m·k. With every model parameter free, ∂θ/∂p is the identity.
  struct Entry {
    int row, col;
    double value;
  };
  std::vector<Entry> dtheta_entries, du_entries;  // the same for ∂u/∂p (n×k, usually none)
  static void ListEntries(const Eigen::MatrixXd& d, std::vector<Entry>* entries) {
    entries->clear();
    for (Eigen::Index j = 0; j < d.cols(); ++j) {
      for (Eigen::Index i = 0; i < d.rows(); ++i) {
        if (d(i, j) != 0) entries->push_back({int(i), int(j), d(i, j)});
      }
    }
  }
  void Vjp(double t, const Eigen::VectorXd& x, const Map& lambda) {
    if (t == vjp.t && x == vjp.x && lambda == vjp.lambda) return;
    vjp.lambda = lambda;  // kept storage: no allocation per call
    sys.RhsVectorJacobian(x, in->theta, vjp.lambda, &vjp.f, &vjp.wfx, &vjp.wft);
    vjp.t = t;
    vjp.x = x;
  }

  // Backward: dλ/dt = −f_xᵀλ − Σ g_xᵀ w (y − y_m).
  static int AdjointRhs(realtype t, N_Vector y, N_Vector yb, N_Vector ybdot, void* data) {
    Impl& d = *static_cast<Impl*>(data);
    ++d.stats.rhs_evaluations;
    Eigen::VectorXd& x = d.x_buf;  // reused: no allocation per call
    x = View(y);
    Map out = View(ybdot);
    d.Vjp(t, x, View(yb));
    out = -d.vjp.wfx;
    if (!d.in->continuous.empty()) {
      Eigen::VectorXd dl;
      d.LossIntegrand(t, x, &dl);
      for (size_t i = 0; i < d.in->continuous.size(); ++i) {
        double yv;
        Eigen::RowVectorXd gx;
        d.sys.ObserveDirectional(d.in->continuous[i].key, x, d.in->theta, Eigen::MatrixXd::Identity(d.n, d.n),
                                 Eigen::MatrixXd::Zero(d.sys.num_theta(), d.n), &yv, &gx);
        out -= dl(static_cast<Eigen::Index>(i)) * gx.transpose();
      }
    }
    return out.allFinite() ? 0 : 1;
  }

  static int AdjointJacobian(realtype, N_Vector y, N_Vector, N_Vector, SUNMatrix jac, void* data, N_Vector, N_Vector,
                             N_Vector) {
    Impl& d = *static_cast<Impl*>(data);
    ++d.stats.jacobian_evaluations;
    View(jac) = -d.sys.StateJacobian(View(y), d.in->theta).transpose();
    return 0;
  }

  // CVODES integrates the backward quadrature from h down to 0, so the
  // integrand enters with a minus sign: q(0) = ∫₀ʰ (…) ds.
  static int AdjointQuadrature(realtype t, N_Vector y, N_Vector yb, N_Vector qbdot, void* data) {
    Impl& d = *static_cast<Impl*>(data);
    if (d.k == 0) {
      N_VConst(0.0, qbdot);
      return 0;
    }
    Eigen::VectorXd& x = d.x_buf;
    x = View(y);
    const Map lambda = View(yb);
    // λᵀ(f_θ ∂θ/∂p + ∂u/∂p) from one reverse pass: (λᵀf_θ) ∂θ/∂p.
    d.Vjp(t, x, lambda);
    Eigen::RowVectorXd& q = d.vjp.q;
    q.setZero(d.k);
    for (const Entry& e : d.dtheta_entries) q(e.col) += d.vjp.wft(e.row) * e.value;
    for (const Entry& e : d.du_entries) q(e.col) += lambda(e.row) * e.value;
    if (!d.in->continuous.empty()) {
      Eigen::VectorXd dl;
      d.LossIntegrand(t, x, &dl);
      for (size_t i = 0; i < d.in->continuous.size(); ++i) {
        double yv;
        Eigen::RowVectorXd dy;
        d.sys.ObserveDirectional(d.in->continuous[i].key, x, d.in->theta, Eigen::MatrixXd::Zero(d.n, d.k),
                                 d.in->dtheta, &yv, &dy);
        q += dl(static_cast<Eigen::Index>(i)) * dy;
      }
    }
    View(qbdot) = -q.transpose();
    return q.allFinite() ? 0 : 1;
  }

  void Configure(void* mem, N_Vector y, LinearSolver* ls) {
    Check(CVodeInit(mem, Rhs, 0.0, y), "CVodeInit");
    Check(CVodeSetUserData(mem, this), "CVodeSetUserData");
    Check(CVodeSetErrHandlerFn(mem, ErrorHandler, this), "CVodeSetErrHandlerFn");
    Check(CVodeSStolerances(mem, opt.relative_tolerance, opt.absolute_tolerance), "CVodeSStolerances");
    Check(CVodeSetMaxNumSteps(mem, opt.max_steps), "CVodeSetMaxNumSteps");
    Check(CVodeSetLinearSolver(mem, ls->ls, ls->a), "CVodeSetLinearSolver");
    Check(CVodeSetJacFn(mem, Jacobian), "CVodeSetJacFn");
  }

  Forward& GetForward(int kk, bool loss, bool auc = false) {
    const std::pair<int, int> key(kk, int(loss) + 2 * int(auc));
    auto it = forward.find(key);
    if (it != forward.end()) return it->second;
    Forward& f = forward[key];
    const int size = n + (loss ? 2 : 0) + (auc ? 1 : 0);
    f.y.reset(new Vector(size, context.ctx));
    f.mem.reset(new Memory(context.ctx));
    if (f.mem->mem == nullptr) throw NumericalFailure("CVODES: out of memory");
    f.ls.reset(new LinearSolver(f.y->v, size, context.ctx));
    Configure(f.mem->mem, f.y->v, f.ls.get());
    if (kk > 0) {
      f.ys.reset(new VectorArray(kk, f.y->v));
      Check(CVodeSensInit(f.mem->mem, kk, CV_STAGGERED, SensitivityRhs, f.ys->v), "CVodeSensInit");
      Check(CVodeSensEEtolerances(f.mem->mem), "CVodeSensEEtolerances");
      Check(CVodeSetSensErrCon(f.mem->mem, SUNTRUE), "CVodeSetSensErrCon");
    }
    return f;
  }

  // From f.run.t (0 after CVodeReInit) to f.run.t + h.
  void Integrate(Forward& f, double h) {
    f.run.at_end = false;
    const double t_end = f.run.t + h;
    Check(CVodeSetStopTime(f.mem->mem, t_end), "CVodeSetStopTime");
    realtype t = 0;
    Check(CVode(f.mem->mem, t_end, f.y->v, &t, CV_NORMAL), "CVode");
    if (std::fabs(t - t_end) > 1e-12 * std::max(1.0, t_end)) throw NumericalFailure("the ODE solver stopped early");
    f.run.t = t_end;
    f.run.CountSteps(f.mem->mem, &stats.steps);
  }
  void Restart(Forward& f) {
    Check(CVodeReInit(f.mem->mem, 0.0, f.y->v), "CVodeReInit");
    f.run.Restarted();
  }
};

namespace {
// A segment this short is below the resolution of CVODES's time axis (II = 1e-300 made CVODES report "tstop
// is behind current t"), and x moves over it by about h·f: it is skipped like an empty one.
bool Negligible(double h) { return !(h > 1e-13); }
}  // namespace

CvodesSolver::CvodesSolver(const OdeSystem& system, const OdeOptions& options) : impl_(new Impl(system, options)) {}
CvodesSolver::~CvodesSolver() {
  // Stored adjoint memories go back to this thread's pool for the next evaluation.
  Impl& d = *impl_;
  for (auto& a : d.stored) d.Return(std::move(a));
}
const OdeStatistics& CvodesSolver::statistics() const { return impl_->stats; }

void CvodesSolver::Advance(const SegmentInput& in, Eigen::VectorXd* x, double* loss, double* auc,
                           double* loss_time) {
  Impl& d = *impl_;
  if (Negligible(in.h)) return;
  d.in = &in;
  d.k = 0;
  d.with_loss = loss != nullptr && !in.continuous.empty();
  d.with_auc = auc != nullptr;
  Impl::Forward& f = d.GetForward(0, d.with_loss, d.with_auc);
  Map y = View(f.y->v);
  const bool plain = !d.with_loss && !d.with_auc;
  if (!plain || !f.run.Continues(in, *x, nullptr)) {
    y.head(d.n) = *x;
    y.tail(y.size() - d.n).setZero();
    d.Restart(f);
  }
  d.Integrate(f, in.h);
  *x = y.head(d.n);
  if (plain) f.run.Remember(in, *x, nullptr);
  if (d.with_loss) {
    *loss += y(d.n);
    if (loss_time) *loss_time += y(d.n + 1);
  }
  if (d.with_auc) *auc += y(y.size() - 1);
  d.with_auc = false;
}

void CvodesSolver::AdvanceSensitivity(const SegmentInput& in, Eigen::VectorXd* x, Eigen::MatrixXd* s, double* loss,
                                      Eigen::RowVectorXd* dloss, double* loss_time) {
  Impl& d = *impl_;
  const int k = static_cast<int>(s->cols());
  if (Negligible(in.h)) return;
  if (k == 0) {
    Advance(in, x, loss, nullptr, loss_time);
    return;
  }
  d.in = &in;
  d.k = k;
  d.with_loss = loss != nullptr && !in.continuous.empty();
  Impl::Forward& f = d.GetForward(k, d.with_loss);
  Map y = View(f.y->v);
  if (d.with_loss || !f.run.Continues(in, *x, s)) {
    y.head(d.n) = *x;
    y.tail(y.size() - d.n).setZero();
    for (int i = 0; i < k; ++i) {
      Map si = View(f.ys->v[i]);
      si.head(d.n) = s->col(i);
      si.tail(si.size() - d.n).setZero();
    }
    d.Restart(f);
    d.Check(CVodeSensReInit(f.mem->mem, CV_STAGGERED, f.ys->v), "CVodeSensReInit");
  }
  d.Integrate(f, in.h);
  realtype t = 0;
  d.Check(CVodeGetSens(f.mem->mem, &t, f.ys->v), "CVodeGetSens");
  *x = y.head(d.n);
  for (int i = 0; i < k; ++i) s->col(i) = View(f.ys->v[i]).head(d.n);
  if (!d.with_loss) f.run.Remember(in, *x, s);
  if (d.with_loss) {
    *loss += y(d.n);
    if (loss_time) *loss_time += y(d.n + 1);
    for (int i = 0; i < k; ++i) (*dloss)(i) += View(f.ys->v[i])(d.n);
  }
}

// The forward half of the adjoint on one segment: CVodeF over h, storing the
// trajectory (Hermite data, checkpoints every checkpoint_steps steps).
void CvodesSolver::Impl::ForwardStore(Adjoint& a, const SegmentInput& seg, const Eigen::VectorXd& x0,
                                      Eigen::VectorXd* x_end, bool restart, Eigen::VectorXd* xmax) {
  in = &seg;
  k = static_cast<int>(seg.dtheta->cols());
  with_loss = false;
  with_auc = false;
  if (!a.mem) {
    SUNContext ctx = a.context ? a.context->ctx : context.ctx;
    a.y.reset(new Vector(n, ctx));
    a.mem.reset(new Memory(ctx));
    if (a.mem->mem == nullptr) throw NumericalFailure("CVODES: out of memory");
    a.ls.reset(new LinearSolver(a.y->v, n, ctx));
    View(a.y->v) = x0;
    Configure(a.mem->mem, a.y->v, a.ls.get());
    if (a.checkpoint_steps <= 0) a.checkpoint_steps = InitialCheckpointSteps(std::max(k, 1));
    Check(CVodeAdjInit(a.mem->mem, a.checkpoint_steps, CV_HERMITE), "CVodeAdjInit");
  } else {
    // A memory from the pool: point its callbacks at this solver.
    Check(CVodeSetUserData(a.mem->mem, this), "CVodeSetUserData");
    Check(CVodeSetErrHandlerFn(a.mem->mem, ErrorHandler, this), "CVodeSetErrHandlerFn");
    if (a.which >= 0) {
      Check(CVodeSetUserDataB(a.mem->mem, a.which, this), "CVodeSetUserDataB");
      CVodeSetErrHandlerFn(CVodeGetAdjCVodeBmem(a.mem->mem, a.which), ErrorHandler, this);
    }
  }
  a.run.at_end = false;
  if (restart) {
    View(a.y->v) = x0;
    Check(CVodeReInit(a.mem->mem, 0.0, a.y->v), "CVodeReInit");
    Check(CVodeAdjReInit(a.mem->mem), "CVodeAdjReInit");
    a.run.Restarted();
    a.x_start = x0;
    a.overflowed = false;
  }
  // Step by step, to record the largest |x_i| the segment reaches (it weights
  // λ's error control in Backward), without a stop time: CVODES rebuilds the
  // stored trajectory between checkpoints by integrating again from each one,
  // and only the steps it took without intermediate stop times can be
  // reproduced that way. The last step may pass t_end; x(t_end) is
  // interpolated, and the next segment of the same memory continues from there.
  const double t_end = a.run.t + seg.h;
  realtype t = 0;
  Check(CVodeGetCurrentTime(a.mem->mem, &t), "CVodeGetCurrentTime");  // past run.t after a continued segment
  int ncheck = 0;
  *xmax = x0.cwiseAbs();
  // One step per call, so CVODES's own limit of steps per call never applies.
  for (long taken = 0; t < t_end; ++taken) {
    if (taken >= opt.max_steps) {
      std::ostringstream os;
      os << "the ODE solver failed (CVodeF): at t = " << t << ", mxstep steps taken before reaching tout";
      throw NumericalFailure(os.str());
    }
    Check(CVodeF(a.mem->mem, t_end, a.y->v, &t, CV_ONE_STEP, &ncheck), "CVodeF");
    *xmax = xmax->cwiseMax(View(a.y->v).cwiseAbs());
  }
  Check(CVodeGetDky(a.mem->mem, t_end, 0, a.y->v), "CVodeGetDky");
  *xmax = xmax->cwiseMax(View(a.y->v).cwiseAbs());
  a.run.t = t_end;
  if (x_end) *x_end = View(a.y->v);
  a.run.CountSteps(a.mem->mem, &stats.steps);
  a.overflowed = ncheck > 0 && a.checkpoint_steps < opt.checkpoint_steps;
  a.bytes = (std::min<long>(a.run.steps, opt.checkpoint_steps) * 2 * n + (ncheck + 1) * 6L * n) *
            static_cast<long>(sizeof(double));
}

// The backward half: λ from λ(t1) = lambda_end to λ(t0), with the quadrature.
void CvodesSolver::Impl::Backward(Adjoint& a, const SegmentInput& seg, double t0, double t1,
                                  const Eigen::VectorXd& xmax, const AdjointScales& scales,
                                  const Eigen::VectorXd& lambda_end, Eigen::VectorXd* lambda_start,
                                  Eigen::RowVectorXd* q) {
  in = &seg;
  vjp.t = std::numeric_limits<double>::quiet_NaN();
  k = static_cast<int>(seg.dtheta->cols());
  ListEntries(seg.dtheta, &dtheta_entries);
  if (seg.du.cols() == k) {
    ListEntries(seg.du, &du_entries);
  } else {
    du_entries.clear();
  }
  with_loss = false;
  const int kq = std::max(k, 1);
  const Eigen::VectorXd* offset = QuadratureOffset(scales, k);
  if (a.which < 0) {
    SUNContext ctx = a.context ? a.context->ctx : context.ctx;
    a.yb.reset(new Vector(n, ctx));
    a.qb.reset(new Vector(kq, ctx));
    View(a.yb->v) = lambda_end;
    Check(CVodeCreateB(a.mem->mem, CV_BDF, &a.which), "CVodeCreateB");
    Check(CVodeInitB(a.mem->mem, a.which, AdjointRhs, t1, a.yb->v), "CVodeInitB");
    Check(CVodeSetUserDataB(a.mem->mem, a.which, this), "CVodeSetUserDataB");
    Check(CVodeSetMaxNumStepsB(a.mem->mem, a.which, opt.max_steps), "CVodeSetMaxNumStepsB");
    a.lsb.reset(new LinearSolver(a.yb->v, n, ctx));
    Check(CVodeSetLinearSolverB(a.mem->mem, a.which, a.lsb->ls, a.lsb->a), "CVodeSetLinearSolverB");
    Check(CVodeSetJacFnB(a.mem->mem, a.which, AdjointJacobian), "CVodeSetJacFnB");
    SetQuadratureStart(a, offset);
    Check(CVodeQuadInitB(a.mem->mem, a.which, AdjointQuadrature, a.qb->v), "CVodeQuadInitB");
    Check(CVodeQuadSStolerancesB(a.mem->mem, a.which, opt.relative_tolerance, opt.absolute_tolerance),
          "CVodeQuadSStolerancesB");
    Check(CVodeSetQuadErrConB(a.mem->mem, a.which, SUNTRUE), "CVodeSetQuadErrConB");
    CVodeSetErrHandlerFn(CVodeGetAdjCVodeBmem(a.mem->mem, a.which), ErrorHandler, this);
    a.kq = kq;
  } else {
    if (a.kq != kq) throw NumericalFailure("internal: the adjoint quadrature size changed");
    View(a.yb->v) = lambda_end;
    Check(CVodeReInitB(a.mem->mem, a.which, t1, a.yb->v), "CVodeReInitB");
    SetQuadratureStart(a, offset);
    Check(CVodeQuadReInitB(a.mem->mem, a.which, a.qb->v), "CVodeQuadReInitB");
  }
  // λ is measured in loss per amount, not in amounts, so the amounts' absolute
  // tolerance means nothing for it. Its absolute tolerance is the looser of:
  //  - rtol·‖λ(h)‖_∞ (never below the amounts' atol): once a sample's jump has
  //    decayed below that, its tail adds less than rtol of the segment's share.
  //  - rtol·S/(c·X_i), from what an error of λ_i can do to the gradient. An
  //    error δλ made at t changes the gradient by exactly δλ(t)ᵀx_p(t), because
  //    d/dt(δλᵀx_p) = δλᵀf_p along the homogeneous adjoint. |x_p,i| is of the
  //    order of X_i, the largest |x_i| on the segment (times θt for a rate
  //    constant, hence the margin c = 100), and S = Σ_k |Δλ_k|ᵀ|x(t_k)| over all
  //    samples is the scale of the gradient's terms. Where the drug is gone, X
  //    is small and λ's transients after each sample are not followed.
  // See docs/ode_routes.md.
  const double lambda_scale = lambda_end.lpNorm<Eigen::Infinity>();
  const double atol_b = std::max(opt.absolute_tolerance, opt.relative_tolerance * lambda_scale);
  if (scales.state > 0 && seg.continuous.empty() && xmax.size() == n) {
    if (!a.atolb) a.atolb.reset(new Vector(n, a.context ? a.context->ctx : context.ctx));
    constexpr double kSafety = 100.0;  // c: |x_p,i| may exceed X_i (a factor θt for elimination)
    constexpr double kRelativeFloor = 1e-3;  // X_i ≥ 1e-3 ‖X‖_∞, for a state near 0 whose x_p is not
    const double floor = kRelativeFloor * xmax.lpNorm<Eigen::Infinity>();
    const double cap = 1e100 * std::max(1.0, lambda_scale);
    Map atol = View(a.atolb->v);
    for (int i = 0; i < n; ++i) {
      const double x = std::max(xmax(i), floor);
      const double bound = x > 0 ? opt.relative_tolerance * scales.state / (kSafety * x) : cap;
      atol(i) = std::max(atol_b, std::min(bound, cap));
    }
    Check(CVodeSVtolerancesB(a.mem->mem, a.which, opt.relative_tolerance, a.atolb->v), "CVodeSVtolerancesB");
  } else {
    Check(CVodeSStolerancesB(a.mem->mem, a.which, opt.relative_tolerance, atol_b), "CVodeSStolerancesB");
  }
  // The quadrature q_j = ∫λᵀf_θ e_j ds is a gradient component, of the order of S/|θ_j| (S in units of the loss,
  // as above; e_j is column j of ∂θ/∂p). Its absolute tolerance is rtol·S/(c·|θ|ᵀ|e_j|). With the amounts' atol
  // instead, a quadrature that starts at 0 (the first backward segment, before any gradient has accumulated to
  // start it from) made CVODES's first step 1e-12 and the segment about 20% longer.
  if (k > 0 && scales.state > 0) {
    if (!a.atolq) a.atolq.reset(new Vector(kq, a.context ? a.context->ctx : context.ctx));
    constexpr double kSafety = 100.0;
    Map atol = View(a.atolq->v);
    const Eigen::RowVectorXd scale = seg.theta.cwiseAbs().transpose() * seg.dtheta->cwiseAbs();
    for (int j = 0; j < k; ++j) {
      const double bound = scale(j) > 0 ? opt.relative_tolerance * scales.state / (kSafety * scale(j)) : 0.0;
      atol(j) = std::max(opt.absolute_tolerance, std::isfinite(bound) ? bound : 0.0);
    }
    Check(CVodeQuadSVtolerancesB(a.mem->mem, a.which, opt.relative_tolerance, a.atolq->v), "CVodeQuadSVtolerancesB");
  } else {
    Check(CVodeQuadSStolerancesB(a.mem->mem, a.which, opt.relative_tolerance, opt.absolute_tolerance),
          "CVodeQuadSStolerancesB");
  }
  realtype t = 0;
  Check(CVodeB(a.mem->mem, t0, CV_NORMAL), "CVodeB");
  Check(CVodeGetB(a.mem->mem, a.which, &t, a.yb->v), "CVodeGetB");
  *lambda_start = View(a.yb->v);
  if (k > 0) {
    Check(CVodeGetQuadB(a.mem->mem, a.which, &t, a.qb->v), "CVodeGetQuadB");
    *q = View(a.qb->v).transpose();
    if (offset) *q -= offset->transpose() / kQuadratureMargin;
  }
  long bsteps = 0;
  CVodeGetNumSteps(CVodeGetAdjCVodeBmem(a.mem->mem, a.which), &bsteps);
  stats.backward_steps += bsteps;
}

void CvodesSolver::AdjointSegment(const SegmentInput& in, const Eigen::VectorXd& x0, const AdjointScales& scales,
                                  const Eigen::VectorXd& lambda_end, Eigen::VectorXd* lambda_start,
                                  Eigen::RowVectorXd* q) {
  Impl& d = *impl_;
  *lambda_start = lambda_end;
  q->setZero(in.dtheta->cols());
  if (Negligible(in.h)) return;
  if (!d.adjoint) d.adjoint.reset(new Impl::Adjoint);
  // Forward over this segment only: checkpoints never straddle a jump.
  d.ForwardStore(*d.adjoint, in, x0, nullptr, true, &d.adjoint->xmax);
  if (d.adjoint->overflowed) {
    d.adjoint = d.Grown(*d.adjoint, std::max<int>(static_cast<int>(in.dtheta->cols()), 1));
    d.ForwardStore(*d.adjoint, in, x0, nullptr, true, &d.adjoint->xmax);
  }
  Impl::Adjoint& a = *d.adjoint;
  d.stats.peak_adjoint_bytes = std::max(d.stats.peak_adjoint_bytes, d.stored_bytes + a.bytes);
  d.Backward(a, in, 0.0, in.h, a.xmax, scales, lambda_end, lambda_start, q);
}

int CvodesSolver::StoreSegment(const SegmentInput& in, Eigen::VectorXd* x) {
  Impl& d = *impl_;
  if (Negligible(in.h)) return -1;
  const int kq = std::max<int>(static_cast<int>(in.dtheta->cols()), 1);
  const Impl::Adjoint* last = d.stored.empty() ? nullptr : d.stored.back().get();
  // The same initial value problem continued (see Advance): one trajectory.
  const bool continues = last && last->pool_kq == kq && last->run.Continues(in, *x, nullptr);
  if (!continues) {
    d.stored.push_back(d.Borrow(kq));
    d.stored.back()->pool_kq = kq;
  }
  const int memory = static_cast<int>(d.stored.size()) - 1;
  Impl::Adjoint& a = *d.stored.back();
  Impl::Piece piece;
  piece.memory = memory;
  piece.t0 = continues ? a.run.t : 0.0;
  piece.segment = in;
  d.stored_bytes -= continues ? a.bytes : 0;
  d.ForwardStore(a, piece.segment, *x, x, !continues, &piece.xmax);
  piece.t1 = a.run.t;
  a.run.Remember(in, *x, nullptr);
  d.pieces.push_back(std::move(piece));
  if (a.overflowed) {
    // Too small: a memory with room for every step, through the same pieces again.
    Eigen::VectorXd xb = a.x_start;
    d.stored.back() = d.Grown(a, kq);
    Impl::Adjoint& b = *d.stored.back();
    bool first = true;
    for (Impl::Piece& p : d.pieces) {
      if (p.memory != memory) continue;
      p.t0 = b.run.t;
      d.ForwardStore(b, p.segment, xb, &xb, first, &p.xmax);
      p.t1 = b.run.t;
      b.run.Remember(p.segment, xb, nullptr);
      first = false;
    }
    *x = xb;
  }
  d.stored_bytes += d.stored.back()->bytes;
  d.stats.peak_adjoint_bytes = std::max(d.stats.peak_adjoint_bytes, d.stored_bytes);
  return static_cast<int>(d.pieces.size()) - 1;
}

void CvodesSolver::BackwardStored(int handle, const AdjointScales& scales, const Eigen::VectorXd& lambda_end,
                                  Eigen::VectorXd* lambda_start, Eigen::RowVectorXd* q) {
  Impl& d = *impl_;
  const Impl::Piece& piece = d.pieces.at(handle);
  d.Backward(*d.stored.at(piece.memory), piece.segment, piece.t0, piece.t1, piece.xmax, scales, lambda_end,
             lambda_start, q);
}

}  // namespace internal
}  // namespace pk
