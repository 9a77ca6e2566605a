#include "linear_derivatives.h"

#include <unsupported/Eigen/AutoDiff>

#include "exact_propagator.h"

namespace pk {
namespace internal {
namespace {

// A scalar with one fixed-size derivative, for ∂A/∂θ_j and ∂C/∂θ_j.
using Ad1 = Eigen::AutoDiffScalar<Eigen::Matrix<double, 1, 1>>;

}  // namespace

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
    d.a = model.SystemMatrix<double>(d.theta);
    if (!d.a.allFinite()) throw NumericalFailure("the system matrix is not finite (a volume of zero?)");
    d.disc.reset(new Discretization(d.a, n_));
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
  const Eigen::RowVectorXd value = model_.OutputRow<double>(cmt, d.theta);
  Eigen::MatrixXd dc_dp = Eigen::MatrixXd::Zero(n_, p_);
  for (int j : d.active) {
    Eigen::Matrix<Ad1, Eigen::Dynamic, 1> seeded = d.theta.cast<Ad1>();
    seeded(j).derivatives()(0) = 1;
    const Eigen::Matrix<Ad1, 1, Eigen::Dynamic> c = model_.OutputRow<Ad1>(cmt, seeded);
    for (int i = 0; i < n_; ++i) {
      const double dc = c(i).derivatives()(0);
      if (dc != 0) dc_dp.row(i) += dc * d.dtheta.row(j);
    }
  }
  return d.outputs.emplace(cmt, std::make_pair(value, dc_dp)).first->second.second;
}

const Eigen::MatrixXd& LinearDerivatives::dA(int set, int j) {
  SetData& d = sets_[set];
  if (d.da.empty()) d.da.resize(m_);
  if (d.da[j].size() == 0) {
    // Forward-mode AD, one parameter at a time with a fixed-size scalar.
    Eigen::Matrix<Ad1, Eigen::Dynamic, 1> seeded = d.theta.cast<Ad1>();
    seeded(j).derivatives()(0) = 1;
    const Eigen::Matrix<Ad1, Eigen::Dynamic, Eigen::Dynamic> a = model_.SystemMatrix<Ad1>(seeded);
    d.da[j] = a.unaryExpr([](const Ad1& x) { return x.derivatives()(0); });
  }
  return d.da[j];
}

const LinearDerivatives::StepSensitivity& LinearDerivatives::GetSensitivity(int set, double h, bool with_gamma) {
  SetData& d = sets_[set];
  if (d.active_da.size() != d.active.size()) {
    d.active_da.clear();
    for (int j : d.active) d.active_da.push_back(dA(set, j));
  }
  return d.disc->GetSensitivity(h, with_gamma, d.active_da);
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
    const Eigen::MatrixXd contraction = d.disc->FinishAdjoint();
    if (!contraction.isZero(0.0)) {
      // ∂/∂θ_j ⟨G, A(θ)⟩ = ⟨G, ∂A/∂θ_j⟩ by AD, one active parameter at a time.
      for (int j : d.active) {
        Eigen::Matrix<Ad1, Eigen::Dynamic, 1> seeded = d.theta.cast<Ad1>();
        seeded(j).derivatives()(0) = 1;
        g(j) += model_.ContractSystemMatrix<Ad1>(seeded, contraction).derivatives()(0);
      }
    }
    *grad += d.dtheta.transpose() * g;
  }
}

}  // namespace internal
}  // namespace pk
