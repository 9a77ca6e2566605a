#include "exact_propagator.h"

#include <cmath>

#include <Eigen/LU>

namespace pk {
namespace internal {

ExactPropagator::ExactPropagator(const LinearModel& model, const std::vector<Eigen::VectorXd>& sets,
                                 bool track_auc)
    : n_(model.num_compartments()), track_auc_(track_auc) {
  const int big_n = n_ + (track_auc ? 1 : 0);
  cache_.resize(sets.size());
  for (size_t s = 0; s < sets.size(); ++s) {
    const Eigen::VectorXd theta = sets[s].head(model.num_parameters());
    if (!theta.allFinite()) throw NumericalFailure("a model parameter is not finite");
    Eigen::MatrixXd a = Eigen::MatrixXd::Zero(big_n, big_n);
    a.topLeftCorner(n_, n_) = model.SystemMatrix<double>(theta);
    if (track_auc) {
      // AUC' = c x + d: the row integrates c x; the offset adds d·h a step (Advance).
      a.row(n_).head(n_) = model.OutputRow<double>(model.central_compartment(), theta);
      auc_offset_.push_back(model.OutputOffset<double>(model.central_compartment(), theta));
    }
    if (!a.allFinite()) throw NumericalFailure("the system matrix is not finite (a volume of zero?)");
    cache_[s].reset(new Discretization(a, n_));
  }
  x_ = Eigen::VectorXd::Zero(big_n);
}

ExactPropagator::ExactPropagator(const std::vector<Eigen::MatrixXd>& matrices, int n_in,
                                 std::shared_ptr<const JetProducts> jet)
    : n_(matrices.empty() ? n_in : static_cast<int>(matrices.front().rows())), track_auc_(false) {
  for (const Eigen::MatrixXd& a : matrices) {
    if (!a.allFinite()) throw NumericalFailure("the system matrix is not finite (a volume of zero?)");
    cache_.emplace_back(new Discretization(a, n_in, true, jet));
  }
  x_ = Eigen::VectorXd::Zero(n_);
}

void ExactPropagator::Advance(double h, const Eigen::VectorXd& rate, int set) {
  const bool input = !rate.isZero(0.0);
  Discretization& disc = *cache_[set];
  double at = h;
  const Discretization::Step& d = disc.GetNearby(h, input, &at);
  if (at != h) {
    // A cached step a few ulps away (see GetNearby): x + δ(Ax + Bu) first, then Φ(at) and Γ(at)u.
    scratch_.noalias() = disc.A().lazyProduct(x_);
    if (input) scratch_.head(rate.size()) += rate;
    x_ += (h - at) * scratch_;
  }
  // Coefficient-wise products: Eigen's blocked kernel costs more than the arithmetic at n = 2–10.
  scratch_.noalias() = d.phi.lazyProduct(x_);
  if (input) scratch_.noalias() += d.gamma.lazyProduct(rate);
  x_.swap(scratch_);
  if (track_auc_) x_(n_) += auc_offset_[static_cast<size_t>(set)] * h;
}

void ExactPropagator::Bolus(int cmt, double amount, int /*set*/) { x_(cmt) += amount; }

void ExactPropagator::Reset() { x_.head(n_).setZero(); }

void ExactPropagator::SteadyState(const SteadyStateCycle<double>& cycle, int set, bool add) {
  std::vector<std::pair<double, Eigen::VectorXd>> period;
  for (const Segment<double>& seg : cycle.period) period.emplace_back(seg.duration, seg.rate);
  Eigen::VectorXd b = Eigen::VectorXd::Zero(n_);
  b(cycle.cmt) = cycle.bolus;
  const PeriodicSteadyState ss = SolvePeriodicSteadyState(cache_[set].get(), n_, b, period);
  // From the fixed point to the record time.
  Eigen::VectorXd z = ss.x_star + b;
  for (const Segment<double>& seg : cycle.to_record) {
    const Discretization::Step& d = Get(set, seg.duration, seg.rate);
    z = d.phi.topLeftCorner(n_, n_) * z;
    if (d.gamma.size()) z += d.gamma.topRows(n_) * seg.rate;
  }
  if (add) {
    x_.head(n_) += z;
  } else {
    x_.head(n_) = z;
  }
}

void ExactPropagator::SteadyInfusion(const Eigen::VectorXd& rate, int set, bool add) {
  // Constant rates u: 0 = A x + u.
  const Eigen::MatrixXd a = cache_[set]->A().topLeftCorner(n_, n_);
  const Eigen::PartialPivLU<Eigen::MatrixXd> lu(a);
  if (!(lu.rcond() > 1e-13)) {
    throw NumericalFailure("no steady state for a constant infusion: some compartment has no elimination");
  }
  Eigen::VectorXd u = Eigen::VectorXd::Zero(n_);  // the rates enter the first states
  u.head(rate.size()) = rate;
  const Eigen::VectorXd z = lu.solve(-u);
  if (add) {
    x_.head(n_) += z;
  } else {
    x_.head(n_) = z;
  }
}

}  // namespace internal
}  // namespace pk
