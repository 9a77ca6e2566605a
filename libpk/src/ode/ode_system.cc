#include "ode_system.h"

#include <cmath>
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
  if (linear_) return linear_->SystemMatrix<double>(theta);
  Eigen::VectorXd f;
  Eigen::MatrixXd df;
  ode_->RhsDirectional(x, theta, Eigen::MatrixXd::Identity(n_, n_), Eigen::MatrixXd::Zero(m_, n_), &f, &df);
  return df;
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
  return linear_->OutputRow<double>(key, theta).dot(x);
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
  const Eigen::Matrix<Dual, 1, Eigen::Dynamic> cd = linear_->OutputRow<Dual>(key, Seeded(theta, dtheta));
  for (int j = 0; j < n_; ++j) {
    if (x(j) != 0 && cd(j).derivatives().size()) *dy += x(j) * cd(j).derivatives().transpose();
  }
}

int OdeSystem::central_key() const { return ode_ ? 1 : model_.central_compartment(); }

}  // namespace internal
}  // namespace pk
