#include "linear_derivatives.h"

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
    std::vector<Eigen::MatrixXd> active_da;
    for (int j : d.active) active_da.push_back(d.da[j]);
    d.disc.reset(new Discretization(d.a, n_, std::move(active_da)));
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

long LinearDerivatives::exponentials() const {
  long n = 0;
  for (const SetData& d : sets_) n += d.disc->exponentials();
  return n;
}

void LinearDerivatives::AccumulateFrechet(int set, double h, const Eigen::VectorXd& lambda_after,
                                          const Eigen::VectorXd& x_before, const Eigen::VectorXd& u) {
  sets_[set].disc->AccumulateAdjoint(h, lambda_after, x_before, u);
}

void LinearDerivatives::FinishAdjoint(const std::vector<Eigen::VectorXd>& theta_grad, Eigen::VectorXd* grad) {
  for (size_t s = 0; s < sets_.size(); ++s) {
    SetData& d = sets_[s];
    Eigen::VectorXd g = theta_grad[s];
    const Eigen::VectorXd g_active = d.disc->FinishAdjoint();
    for (size_t a = 0; a < d.active.size(); ++a) g(d.active[a]) += g_active(static_cast<Eigen::Index>(a));
    *grad += d.dtheta.transpose() * g;
  }
}

}  // namespace internal
}  // namespace pk
