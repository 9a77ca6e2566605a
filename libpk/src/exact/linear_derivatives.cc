#include "linear_derivatives.h"

#include <unsupported/Eigen/MatrixFunctions>

#include "exact_propagator.h"

namespace pk {
namespace internal {

LinearDerivatives::LinearDerivatives(const LinearModel& model, const std::vector<DualVector>& sets, int num_free)
    : model_(model), n_(model.num_compartments()), m_(model.num_parameters()), p_(num_free) {
  sets_.resize(sets.size());
  for (size_t s = 0; s < sets.size(); ++s) {
    SetData& d = sets_[s];
    d.theta.resize(m_);
    d.dtheta = Eigen::MatrixXd::Zero(m_, p_);
    for (int j = 0; j < m_; ++j) {
      d.theta(j) = sets[s](j).value();
      d.dtheta.row(j) = Derivatives(sets[s](j), p_).transpose();
      if (!d.dtheta.row(j).isZero(0.0)) d.active.push_back(j);
    }
    if (!d.theta.allFinite()) throw NumericalFailure("a model parameter is not finite");
    // A and ∂A/∂θ_j by forward-mode AD over the m model parameters.
    DualVector seeded(m_);
    for (int j = 0; j < m_; ++j) seeded(j) = Dual(d.theta(j), m_, j);
    const Eigen::Matrix<Dual, Eigen::Dynamic, Eigen::Dynamic> a = model.SystemMatrix<Dual>(seeded);
    d.a.resize(n_, n_);
    d.da.assign(m_, Eigen::MatrixXd::Zero(n_, n_));
    for (int r = 0; r < n_; ++r) {
      for (int c = 0; c < n_; ++c) {
        d.a(r, c) = a(r, c).value();
        const Eigen::VectorXd g = Derivatives(a(r, c), m_);
        for (int j = 0; j < m_; ++j) d.da[j](r, c) = g(j);
      }
    }
    if (!d.a.allFinite()) throw NumericalFailure("the system matrix is not finite (a volume of zero?)");
  }
}

const Eigen::RowVectorXd& LinearDerivatives::C(int set, int cmt) {
  dCdp(set, cmt);
  return sets_[set].outputs[cmt].first;
}

const Eigen::MatrixXd& LinearDerivatives::dCdp(int set, int cmt) {
  SetData& d = sets_[set];
  auto it = d.outputs.find(cmt);
  if (it != d.outputs.end()) return it->second.second;
  DualVector seeded(m_);
  for (int j = 0; j < m_; ++j) seeded(j) = Dual(d.theta(j), m_, j);
  const Eigen::Matrix<Dual, 1, Eigen::Dynamic> c = model_.OutputRow<Dual>(cmt, seeded);
  Eigen::RowVectorXd value(n_);
  Eigen::MatrixXd dc_dtheta(n_, m_);
  for (int i = 0; i < n_; ++i) {
    value(i) = c(i).value();
    dc_dtheta.row(i) = Derivatives(c(i), m_).transpose();
  }
  Eigen::MatrixXd dc_dp = dc_dtheta * d.dtheta;
  return d.outputs.emplace(cmt, std::make_pair(value, dc_dp)).first->second.second;
}

const LinearDerivatives::Step& LinearDerivatives::Get(int set, double h) {
  SetData& d = sets_[set];
  auto it = d.steps.find(h);
  if (it != d.steps.end()) return it->second;
  Eigen::MatrixXd m = Eigen::MatrixXd::Zero(2 * n_, 2 * n_);
  m.topLeftCorner(n_, n_) = d.a * h;
  m.topRightCorner(n_, n_).setIdentity();
  m.topRightCorner(n_, n_) *= h;
  const Eigen::MatrixXd e = m.exp();
  ++exponentials_;
  if (!e.allFinite()) throw NumericalFailure("the matrix exponential overflowed");
  return d.steps.emplace(h, Step{e.topLeftCorner(n_, n_), e.topRightCorner(n_, n_)}).first->second;
}

const LinearDerivatives::StepSensitivity& LinearDerivatives::GetSensitivity(int set, double h) {
  SetData& d = sets_[set];
  auto it = d.sens.find(h);
  if (it != d.sens.end()) return it->second;
  // exp([[Mh, 0],[M_j h, Mh]]): the lower-left block is ∂exp(Mh)/∂θ_j (seed 5.4/5.7).
  const int k = 2 * n_;
  Eigen::MatrixXd big = Eigen::MatrixXd::Zero(2 * k, 2 * k);
  big.topLeftCorner(n_, n_) = d.a * h;
  big.block(0, n_, n_, n_) = Eigen::MatrixXd::Identity(n_, n_) * h;
  big.bottomRightCorner(k, k) = big.topLeftCorner(k, k);
  StepSensitivity s;
  for (int j : d.active) {
    big.block(k, 0, n_, n_) = d.da[j] * h;
    const Eigen::MatrixXd e = big.exp();
    ++exponentials_;
    s.dphi.push_back(e.block(k, 0, n_, n_));
    s.dgamma.push_back(e.block(k, n_, n_, n_));
  }
  return d.sens.emplace(h, std::move(s)).first->second;
}

void LinearDerivatives::AccumulateFrechet(int set, double h, const Eigen::VectorXd& lambda_after,
                                          const Eigen::VectorXd& x_before, const Eigen::VectorXd& u) {
  SetData& d = sets_[set];
  if (d.active.empty()) return;
  auto it = d.frechet.find(h);
  if (it == d.frechet.end()) it = d.frechet.emplace(h, Eigen::MatrixXd::Zero(2 * n_, 2 * n_)).first;
  // Only the top block rows of λ̃ = [λ; 0] are non-zero.
  it->second.topLeftCorner(n_, n_).noalias() += lambda_after * x_before.transpose();
  it->second.topRightCorner(n_, n_).noalias() += lambda_after * u.transpose();
}

void LinearDerivatives::FinishAdjoint(const std::vector<Eigen::VectorXd>& theta_grad, Eigen::VectorXd* grad) {
  for (size_t s = 0; s < sets_.size(); ++s) {
    SetData& d = sets_[s];
    Eigen::VectorXd g = theta_grad[s];
    const int k = 2 * n_;
    for (const auto& entry : d.frechet) {
      const double h = entry.first;
      // L(hMᵀ, W) is the upper-right block of exp([[hMᵀ, W],[0, hMᵀ]]).
      Eigen::MatrixXd mt = Eigen::MatrixXd::Zero(k, k);
      mt.topLeftCorner(n_, n_) = d.a.transpose() * h;
      mt.bottomLeftCorner(n_, n_) = Eigen::MatrixXd::Identity(n_, n_) * h;
      Eigen::MatrixXd big = Eigen::MatrixXd::Zero(2 * k, 2 * k);
      big.topLeftCorner(k, k) = mt;
      big.bottomRightCorner(k, k) = mt;
      big.topRightCorner(k, k) = entry.second;
      const Eigen::MatrixXd e = big.exp();
      ++exponentials_;
      const Eigen::MatrixXd l11 = e.topRightCorner(k, k).topLeftCorner(n_, n_);
      for (int j : d.active) g(j) += h * (l11.cwiseProduct(d.da[j])).sum();
    }
    d.frechet.clear();
    *grad += d.dtheta.transpose() * g;
  }
}

}  // namespace internal
}  // namespace pk
