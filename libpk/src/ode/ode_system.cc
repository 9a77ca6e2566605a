#include "ode_system.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include "../autodiff.h"
#include "pk/error.h"

namespace pk {
namespace internal {
namespace {

DualVector Seeded(const Eigen::VectorXd& v, const Eigen::MatrixXd& d) {
  DualVector out(v.size());
  for (Eigen::Index i = 0; i < v.size(); ++i) out(i) = Dual(v(i), d.row(i).transpose());
  return out;
}

}  // namespace

OdeSystem::OdeSystem(const Model& model)
    : model_(model),
      linear_(dynamic_cast<const LinearModel*>(&model)),
      ode_(dynamic_cast<const OdeModel*>(&model)),
      n_(model.num_compartments()),
      m_(model.num_parameters()) {
  if (linear_ == nullptr && ode_ == nullptr) {
    throw InputError("model " + model.name() + " is neither linear nor an OdeModel");
  }
}

void OdeSystem::Rhs(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, Eigen::VectorXd* f) const {
  if (ode_) {
    ode_->Rhs(x, theta, f);
  } else {
    *f = linear_->SystemMatrix<double>(theta) * x;
  }
}

void OdeSystem::RhsDirectional(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, const Eigen::MatrixXd& dx,
                               const Eigen::MatrixXd& dtheta, Eigen::VectorXd* f, Eigen::MatrixXd* df) const {
  if (ode_) {
    ode_->RhsDirectional(x, theta, dx, dtheta, f, df);
    return;
  }
  // f = A(θ)x: df = A dx + (∂A/∂θ · dθ) x, with ∂A/∂θ·dθ from A evaluated on duals.
  const Eigen::MatrixXd a = linear_->SystemMatrix<double>(theta);
  *f = a * x;
  *df = a * dx;
  if (dtheta.size() == 0 || dtheta.isZero(0.0)) return;
  const Eigen::Matrix<Dual, Eigen::Dynamic, Eigen::Dynamic> ad = linear_->SystemMatrix<Dual>(Seeded(theta, dtheta));
  for (int i = 0; i < n_; ++i) {
    for (int j = 0; j < n_; ++j) {
      if (x(j) != 0 && ad(i, j).derivatives().size()) df->row(i) += x(j) * ad(i, j).derivatives().transpose();
    }
  }
}

void OdeSystem::RhsVectorJacobian(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, const Eigen::VectorXd& w,
                                  Eigen::VectorXd* f, Eigen::VectorXd* wfx, Eigen::VectorXd* wftheta) const {
  if (ode_) {
    ode_->RhsVectorJacobian(x, theta, w, f, wfx, wftheta);
    return;
  }
  // wᵀA(θ)x = ⟨w xᵀ, A(θ)⟩, differentiated in θ by duals.
  const Eigen::MatrixXd a = linear_->SystemMatrix<double>(theta);
  *f = a * x;
  *wfx = a.transpose() * w;
  const Dual c = linear_->ContractSystemMatrix<Dual>(Seeded(theta, Eigen::MatrixXd::Identity(m_, m_)), w * x.transpose());
  *wftheta = c.derivatives().size() ? Eigen::VectorXd(c.derivatives()) : Eigen::VectorXd::Zero(m_);
}

Eigen::MatrixXd OdeSystem::StateJacobian(const Eigen::VectorXd& x, const Eigen::VectorXd& theta) const {
  Eigen::MatrixXd fx;
  StateJacobian(x, theta, &fx);
  return fx;
}

void OdeSystem::StateJacobian(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, Eigen::MatrixXd* fx) const {
  if (linear_) {
    *fx = linear_->SystemMatrix<double>(theta);
    return;
  }
  // The n unit directions, kept per thread: made at each call (the rk route's stiffness checks, every
  // 5 steps, where f has no compressed Jacobian) they and f_x churned the heap, which glibc trimmed
  // and faulted in again (about 300 brk calls an evaluation of the 32-chain's recorded adjoint).
  thread_local Eigen::MatrixXd unit, zero;
  thread_local Eigen::VectorXd f;
  if (unit.rows() != n_) unit = Eigen::MatrixXd::Identity(n_, n_);
  if (zero.rows() != m_ || zero.cols() != n_) zero = Eigen::MatrixXd::Zero(m_, n_);
  ode_->RhsDirectional(x, theta, unit, zero, &f, fx);
}

void OdeSystem::SensitivityJacobians(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, const Eigen::MatrixXd& s,
                                     const Eigen::MatrixXd& dtheta, std::vector<Eigen::MatrixXd>* b) const {
  const auto k = static_cast<size_t>(s.cols());
  b->resize(k);
  if (linear_) {
    // f = A(θ)x: f_xx = 0, so B_a = ∂A/∂θ · dtheta_a, every a from one evaluation on duals.
    const Eigen::Matrix<Dual, Eigen::Dynamic, Eigen::Dynamic> ad = linear_->SystemMatrix<Dual>(Seeded(theta, dtheta));
    for (size_t a = 0; a < k; ++a) {
      Eigen::MatrixXd& m = (*b)[a];
      m.setZero(n_, n_);
      for (int i = 0; i < n_; ++i) {
        for (int j = 0; j < n_; ++j) {
          if (ad(i, j).derivatives().size()) m(i, j) = ad(i, j).derivatives()(static_cast<Eigen::Index>(a));
        }
      }
    }
    return;
  }
  // Column j of B_a is f''[(e_j, 0), (s_a, θ_a)]: one evaluation on pk::HyperDual.
  const Eigen::VectorXd zero_theta = Eigen::VectorXd::Zero(m_);
  Eigen::MatrixXd unit = Eigen::MatrixXd::Identity(n_, n_);
  Eigen::VectorXd column;
  for (size_t a = 0; a < k; ++a) {
    Eigen::MatrixXd& m = (*b)[a];
    m.resize(n_, n_);
    SecondDirections d;
    d.dtheta1 = zero_theta.data();
    d.dx2 = s.col(static_cast<Eigen::Index>(a)).data();
    d.dtheta2 = dtheta.col(static_cast<Eigen::Index>(a)).data();
    for (int j = 0; j < n_; ++j) {
      d.dx1 = unit.col(j).data();
      ode_->RhsSecondDirectional(x, theta, d, &column);
      m.col(j) = column;
    }
  }
}

double OdeSystem::Observe(int key, const Eigen::VectorXd& x, const Eigen::VectorXd& theta) const {
  if (ode_) return ode_->OutputValue(key, x, theta);
  return linear_->OutputRow<double>(key, theta).dot(x) + linear_->OutputOffset<double>(key, theta);
}

void OdeSystem::ObserveDirectional(int key, const Eigen::VectorXd& x, const Eigen::VectorXd& theta,
                                   const Eigen::MatrixXd& dx, const Eigen::MatrixXd& dtheta, double* y,
                                   Eigen::RowVectorXd* dy) const {
  if (ode_) {
    ode_->OutputDirectional(key, x, theta, dx, dtheta, y, dy);
    return;
  }
  const Eigen::RowVectorXd c = linear_->OutputRow<double>(key, theta);
  *y = c.dot(x);
  *dy = c * dx;
  const DualVector seeded = Seeded(theta, dtheta);
  const Eigen::Matrix<Dual, 1, Eigen::Dynamic> cd = linear_->OutputRow<Dual>(key, seeded);
  for (int j = 0; j < n_; ++j) {
    if (x(j) != 0 && cd(j).derivatives().size()) *dy += x(j) * cd(j).derivatives().transpose();
  }
  if (linear_->output_offset_terms(key).empty()) return;
  const Dual offset = linear_->OutputOffset<Dual>(key, seeded);  // y = c(θ)ᵀx + d(θ)
  *y += offset.value();
  if (offset.derivatives().size()) *dy += offset.derivatives().transpose();
}

double OdeSystem::ObserveGradient(int key, const Eigen::VectorXd& x, const Eigen::VectorXd& theta, Eigen::VectorXd* gx,
                                  Eigen::VectorXd* gtheta) const {
  if (ode_) return ode_->OutputGradient(key, x, theta, gx, gtheta);
  // y = c(θ)ᵀx: g_x = c, and g_θ as the directional derivatives along each parameter.
  *gx = linear_->OutputRow<double>(key, theta).transpose();
  double y = 0;
  Eigen::RowVectorXd dy;
  ObserveDirectional(key, x, theta, Eigen::MatrixXd::Zero(n_, m_), Eigen::MatrixXd::Identity(m_, m_), &y, &dy);
  *gtheta = dy.transpose();
  return y;
}

int OdeSystem::central_key() const { return ode_ ? 1 : model_.central_compartment(); }

StageTape::StageTape(const OdeSystem& system, const Eigen::VectorXd& theta, bool compressed)
    : sys_(system), theta_(theta), n_(system.n()), m_(static_cast<int>(theta.size())) {
  if (sys_.is_linear()) {
    a_ = sys_.linear()->SystemMatrix<double>(theta);
    contraction_ = Eigen::MatrixXd::Zero(n_, n_);
    return;
  }
  if (compressed) coloured_ = ColouredJacobian::For(*sys_.nonlinear(), theta);
  if (coloured_) return;
  Tape& tape = Tape::Active();
  tape.Clear();
  theta_vars_.reserve(static_cast<size_t>(m_));
  for (int j = 0; j < m_; ++j) theta_vars_.push_back(TapeScalar::Variable(theta(j)));  // nodes 0…m−1
  for (int i = 0; i < n_; ++i) TapeScalar::Variable(0.0);  // x: nodes m…m+n−1, shared by the stages
  adj_.assign(static_cast<size_t>(m_ + n_), 0.0);
  NewStep();
}

StageTape::~StageTape() {
  if (!sys_.is_linear() && !coloured_) Tape::Active().Clear();
}

void StageTape::NewStep() {
  if (coloured_) return coloured_->NewStep();
  start_.assign(1, m_ + n_);
  f_node_.clear();
  points_.clear();
  zeroed_ = m_ + n_;
  if (!sys_.is_linear()) Tape::Active().Truncate(m_ + n_);
}

void StageTape::Record(const Eigen::VectorXd& x, Eigen::VectorXd* f) {
  f->resize(n_);
  Record(x, f->data());
}

void StageTape::Record(const Eigen::VectorXd& x, double* f) {
  if (sys_.is_linear()) {
    Eigen::Map<Eigen::VectorXd>(f, n_).noalias() = a_ * x;
    points_.push_back(x);
    return;
  }
  if (coloured_) return coloured_->Record(x, f);
  xs_.resize(static_cast<size_t>(n_));
  for (int i = 0; i < n_; ++i) xs_[static_cast<size_t>(i)] = TapeScalar::OnTape(x(i), m_ + i);
  fs_.assign(static_cast<size_t>(n_), TapeScalar());
  sys_.nonlinear()->RecordRhs(xs_.data(), theta_vars_.data(), fs_.data());
  const size_t first = f_node_.size();
  f_node_.resize(first + static_cast<size_t>(n_));
  for (int i = 0; i < n_; ++i) {
    f[i] = fs_[static_cast<size_t>(i)].value();
    f_node_[first + static_cast<size_t>(i)] = fs_[static_cast<size_t>(i)].index();
  }
  start_.push_back(Tape::Active().size());
}

void StageTape::Sweep(int stage, const Eigen::VectorXd& w, Eigen::VectorXd* wfx) {
  wfx->resize(n_);
  Sweep(stage, w, wfx->data());
}

void StageTape::Sweep(int stage, const Eigen::VectorXd& w, double* wfx) {
  const size_t s = static_cast<size_t>(stage);
  if (sys_.is_linear()) {
    Eigen::Map<Eigen::VectorXd>(wfx, n_).noalias() = a_.transpose() * w;
    contraction_.noalias() += w * points_.at(s).transpose();
    return;
  }
  if (coloured_) return coloured_->Sweep(stage, w, wfx);
  const Tape& tape = Tape::Active();
  if (tape.size() != start_.back()) throw std::logic_error("StageTape: the thread's tape was recorded on meanwhile");
  if (zeroed_ < tape.size()) {  // this step's nodes, once a step
    adj_.resize(static_cast<size_t>(tape.size()));
    std::fill(adj_.begin() + zeroed_, adj_.end(), 0.0);
    zeroed_ = tape.size();
  }
  double* x_adj = adj_.data() + m_;  // the shared x nodes: this stage's products only
  std::fill(x_adj, x_adj + n_, 0.0);
  for (int i = 0; i < n_; ++i) {
    const int node = f_node_[s * static_cast<size_t>(n_) + static_cast<size_t>(i)];
    if (node >= 0) adj_[static_cast<size_t>(node)] += w(i);
  }
  tape.Sweep(&adj_, start_.at(s), start_.at(s + 1));
  std::copy(x_adj, x_adj + n_, wfx);
}

Eigen::VectorXd StageTape::ThetaProduct() const {
  if (sys_.is_linear()) {
    const Dual c = sys_.linear()->ContractSystemMatrix<Dual>(Seeded(theta_, Eigen::MatrixXd::Identity(m_, m_)),
                                                            contraction_);
    return c.derivatives().size() ? Eigen::VectorXd(c.derivatives()) : Eigen::VectorXd::Zero(m_);
  }
  if (coloured_) return coloured_->ThetaProduct();
  return Eigen::Map<const Eigen::VectorXd>(adj_.data(), m_);
}

}  // namespace internal
}  // namespace pk
