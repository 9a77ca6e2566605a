#include "estimation/problem.h"

#include <utility>

namespace pk {
namespace internal {

double Transform::S(double phi) const {
  const bool lo = std::isfinite(sl), hi = std::isfinite(su);
  if (lo && hi) return sl + (su - sl) / (1 + std::exp(-phi));
  if (lo) return sl + std::exp(phi);
  if (hi) return su - std::exp(phi);
  return phi;
}

double Transform::DsDphi(double phi) const {
  const bool lo = std::isfinite(sl), hi = std::isfinite(su);
  if (lo && hi) {
    const double sig = 1 / (1 + std::exp(-phi));
    return (su - sl) * sig * (1 - sig);
  }
  if (lo) return std::exp(phi);
  if (hi) return -std::exp(phi);
  return 1;
}

double Transform::Phi(double theta) const {
  const double s = log ? std::log(theta) : theta;
  const bool lo = std::isfinite(sl), hi = std::isfinite(su);
  if (lo && hi) {
    const double f = (s - sl) / (su - sl);
    return std::log(f / (1 - f));
  }
  if (lo) return std::log(s - sl);
  if (hi) return std::log(su - s);
  return s;
}

Eigen::VectorXd Problem::Values(const Eigen::VectorXd& phi) const {
  Eigen::VectorXd v = base_;
  for (int k = 0; k < n(); ++k) v(free_[k]) = tr_[k].Theta(phi(k));
  return v;
}

Eigen::VectorXd Problem::Dtheta(const Eigen::VectorXd& phi) const {
  Eigen::VectorXd d(n());
  for (int k = 0; k < n(); ++k) d(k) = tr_[k].DthetaDphi(phi(k));
  return d;
}

Eigen::VectorXd Problem::PhiOf(const Eigen::VectorXd& values) const {
  Eigen::VectorXd phi(n());
  for (int k = 0; k < n(); ++k) phi(k) = tr_[k].Phi(values(free_[k]));
  return phi;
}

const Objective::Evaluation& Problem::Eval(const Eigen::VectorXd& phi, Objective::Need need) {
  using Need = Objective::Need;
  for (const Memo& m : memo_) {
    // A failed evaluation answers only what it was asked: a value may exist without its Jacobian.
    if ((m.need == need || (m.need > need && m.ev.ok)) && m.phi.size() == phi.size() && m.phi == phi) return m.ev;
  }
  ++evaluations_;
  std::swap(memo_[0], memo_[1]);
  Objective::Evaluation& ev = memo_[0].ev;
  ev = obj_.Evaluate(Values(phi), free_, need);
  if (ev.ok && need != Need::kValue) {
    const Eigen::VectorXd d = Dtheta(phi);
    route_ = ev.route;
    propagator_ = ev.propagator;
    ev.gradient = ev.gradient.cwiseProduct(d);
    if (need == Need::kJacobian) {
      if (ev.jacobian.size()) ev.jacobian = ev.jacobian * d.asDiagonal();
      ev.information = d.asDiagonal() * ev.information * d.asDiagonal();
    }
  }
  memo_[0].phi = phi;
  memo_[0].need = need;
  return ev;
}

}  // namespace internal
}  // namespace pk
