// OdeModel: names and defaults from the spec, and f's derivatives from a per-thread recording
// of f on the tape (pk/tape_scalar.h).
#include "pk/ode_model.h"

#include <algorithm>
#include <atomic>
#include <stdexcept>
#include <vector>

#include "internal_text.h"

namespace pk {
namespace {

std::vector<std::string> Names(const OdeModelSpec& spec) {
  std::vector<std::string> names;
  for (const auto& p : spec.parameters) names.push_back(internal::ToUpper(p.first));
  return names;
}

Eigen::VectorXd Defaults(const OdeModelSpec& spec) {
  Eigen::VectorXd v(spec.parameters.size());
  for (size_t i = 0; i < spec.parameters.size(); ++i) v(static_cast<Eigen::Index>(i)) = spec.parameters[i].second;
  return v;
}

unsigned long NextModelId() {
  static std::atomic<unsigned long> next{1};
  return next++;
}

// A recording of f at (x, θ): nodes 0…n−1 are x, n…n+m−1 are θ, and f_i is node fi[i] (−1 for a
// constant). The backward solve asks at one (x, θ) several times with different w (each Newton
// iteration, then the quadrature), and the forward routes ask for f_x and f_θ there too, so the
// last recording is kept per thread and swept again.
struct Recording {
  unsigned long model = 0;
  Eigen::VectorXd x, theta, f;
  Tape tape;
  std::vector<int> fi;
  std::vector<double> adj;
};

}  // namespace

OdeModel::OdeModel(const OdeModelSpec& spec)
    : Model(spec.name, spec.description, spec.compartments, Names(spec), Defaults(spec), spec.central,
            spec.default_dose),
      id_(NextModelId()) {
  set_output_names(spec.outputs);
  set_initial_structure(spec.initial_structure);
  set_signed_parameters(spec.signed_parameters);
  set_declarations(spec.declarations);
}

OdeModel::~OdeModel() = default;

double OdeModel::Output(int cmt, const Eigen::VectorXd& x, const Eigen::VectorXd& theta) const {
  return cmt == central_compartment() ? OutputValue(1, x, theta) : x(cmt - 1);
}

namespace {

Recording& ThreadRecording() {
  static thread_local Recording rec;
  return rec;
}

// The calling thread's recording of model `id`'s f, made at (x, θ) by `record` unless it is there.
template <typename RecordFn>
Recording& Recorded(unsigned long id, int n, const Eigen::VectorXd& x, const Eigen::VectorXd& theta,
                    const RecordFn& record) {
  Recording& rec = ThreadRecording();
  if (rec.model == id && rec.x.size() == x.size() && rec.theta.size() == theta.size() && rec.x == x &&
      rec.theta == theta) {
    return rec;
  }
  const Eigen::Index m = theta.size();
  rec.model = 0;  // invalid until complete (the model may throw)
  Tape& tape = Tape::Active();
  tape.Clear();
  static thread_local std::vector<TapeScalar> xt, tt, ft;
  xt.resize(n);
  tt.resize(m);
  ft.assign(n, TapeScalar());
  for (int i = 0; i < n; ++i) xt[i] = TapeScalar::Variable(x(i));
  for (Eigen::Index j = 0; j < m; ++j) tt[j] = TapeScalar::Variable(theta(j));
  record(xt.data(), tt.data(), ft.data());
  rec.f.resize(n);
  rec.fi.resize(n);
  for (int i = 0; i < n; ++i) {
    rec.f(i) = ft[i].value();
    rec.fi[i] = ft[i].index();
  }
  rec.tape.Swap(tape);
  tape.Clear();
  rec.x = x;
  rec.theta = theta;
  rec.model = id;
  return rec;
}

}  // namespace

// Direction j in lane j of each input (lanes past k stay 0), f once: its values are f's in double,
// bit for bit, and lane j of f_i is (f_x dx + f_θ dtheta)_ij. Nothing is recorded or allocated; for a
// few directions this is several times quicker than recording f and sweeping the tangents forward
// (the forward sensitivities' right-hand side: docs/performance.md §9). dx and df are n×k, column-major.
template <int W>
bool OdeModel::DirectionalOnLanes(const double* x, const double* dx, int k, const Eigen::VectorXd& theta,
                                  const Eigen::MatrixXd& dtheta, double* f, double* df) const {
  static thread_local std::vector<FixedDual<W>> lanes;  // x, θ, then f
  const int n = num_compartments();
  const int m = static_cast<int>(theta.size());
  lanes.resize(static_cast<size_t>(2 * n + m));
  FixedDual<W>* const xs = lanes.data();
  FixedDual<W>* const ts = xs + n;
  FixedDual<W>* const fs = ts + m;
  for (int i = 0; i < n; ++i) {
    xs[i] = FixedDual<W>(x[i]);
    for (int j = 0; j < k; ++j) xs[i].derivative(j) = dx[i + j * n];
  }
  for (int r = 0; r < m; ++r) {
    ts[r] = FixedDual<W>(theta(r));
    for (int j = 0; j < k; ++j) ts[r].derivative(j) = dtheta(r, j);
  }
  std::fill(fs, fs + n, FixedDual<W>(0.0));
  if (!ColouredRhs(xs, ts, fs)) return false;
  for (int i = 0; i < n; ++i) {
    f[i] = fs[i].value();
    for (int j = 0; j < k; ++j) df[i + j * n] = fs[i].derivative(j);
  }
  return true;
}

bool OdeModel::DirectionalOnLanes(const double* x, const double* dx, int k, const Eigen::VectorXd& theta,
                                  const Eigen::MatrixXd& dtheta, double* f, double* df) const {
  if (k <= 4) return DirectionalOnLanes<4>(x, dx, k, theta, dtheta, f, df);
  if (k <= 6) return DirectionalOnLanes<6>(x, dx, k, theta, dtheta, f, df);
  if (k <= 8) return DirectionalOnLanes<8>(x, dx, k, theta, dtheta, f, df);
  return false;
}

void OdeModel::RhsDirectional(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, const Eigen::MatrixXd& dx,
                              const Eigen::MatrixXd& dtheta, Eigen::VectorXd* f, Eigen::MatrixXd* df) const {
  const Eigen::Index k = dx.cols();
  if (dtheta.cols() != k) throw std::invalid_argument("RhsDirectional: dx and dtheta differ in columns");
  f->resize(num_compartments());
  df->resize(num_compartments(), k);
  if (DirectionalOnLanes(x.data(), dx.data(), static_cast<int>(k), theta, dtheta, f->data(), df->data())) return;
  // Forward mode over the recording: each node's tangents are its parents' times its recorded
  // partials. Unlike Dual, nothing is allocated per operation.
  const int n = num_compartments();
  Recording& rec = Recorded(id_, n, x, theta, [this](auto... a) { RecordRhs(a...); });
  const Eigen::Index m = theta.size();
  static thread_local std::vector<double> tangents;
  tangents.resize(static_cast<size_t>(rec.tape.size()) * static_cast<size_t>(k));
  for (int i = 0; i < n; ++i) {
    for (Eigen::Index j = 0; j < k; ++j) tangents[i * k + j] = dx(i, j);
  }
  for (Eigen::Index r = 0; r < m; ++r) {
    for (Eigen::Index j = 0; j < k; ++j) tangents[(n + r) * k + j] = dtheta(r, j);
  }
  rec.tape.Tangents(static_cast<int>(k), &tangents);
  *f = rec.f;
  df->setZero(n, k);
  for (int i = 0; i < n; ++i) {
    if (rec.fi[i] < 0) continue;
    for (Eigen::Index j = 0; j < k; ++j) (*df)(i, j) = tangents[rec.fi[i] * k + j];
  }
}

void OdeModel::RhsVectorJacobian(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, const Eigen::VectorXd& w,
                                 Eigen::VectorXd* f, Eigen::VectorXd* wfx, Eigen::VectorXd* wftheta) const {
  const int n = num_compartments();
  Recording& rec = Recorded(id_, n, x, theta, [this](auto... a) { RecordRhs(a...); });
  const Eigen::Index m = theta.size();
  rec.adj.assign(rec.tape.size(), 0.0);
  for (int i = 0; i < n; ++i) {
    if (rec.fi[i] >= 0) rec.adj[rec.fi[i]] += w(i);
  }
  rec.tape.Sweep(&rec.adj, n + static_cast<int>(m));  // x and θ are nodes 0…n+m−1
  *f = rec.f;
  wfx->resize(n);
  wftheta->resize(m);
  for (int i = 0; i < n; ++i) (*wfx)(i) = rec.adj[i];
  for (Eigen::Index j = 0; j < m; ++j) (*wftheta)(j) = rec.adj[n + j];
}

double OdeModel::OutputGradient(int output, const Eigen::VectorXd& x, const Eigen::VectorXd& theta,
                                Eigen::VectorXd* gx, Eigen::VectorXd* gtheta) const {
  const int n = num_compartments();
  const Eigen::Index m = theta.size();
  Tape& tape = Tape::Active();
  tape.Clear();
  thread_local std::vector<TapeScalar> xt, tt;
  xt.resize(static_cast<size_t>(n));
  tt.resize(static_cast<size_t>(m));
  for (int i = 0; i < n; ++i) xt[static_cast<size_t>(i)] = TapeScalar::Variable(x(i));
  for (Eigen::Index j = 0; j < m; ++j) tt[static_cast<size_t>(j)] = TapeScalar::Variable(theta(j));
  const TapeScalar y = RecordOutput(output, xt.data(), tt.data());
  thread_local std::vector<double> adj;
  adj.assign(static_cast<size_t>(tape.size()), 0.0);
  if (y.index() >= 0) adj[static_cast<size_t>(y.index())] = 1;
  tape.Sweep(&adj, n + static_cast<int>(m));  // x and θ are nodes 0…n+m−1
  gx->resize(n);
  gtheta->resize(m);
  for (int i = 0; i < n; ++i) (*gx)(i) = adj[static_cast<size_t>(i)];
  for (Eigen::Index j = 0; j < m; ++j) (*gtheta)(j) = adj[static_cast<size_t>(n + j)];
  tape.Clear();
  return y.value();
}

}  // namespace pk
