#include "companion_route.h"

#include <Eigen/LU>

#include "discretization.h"
#include "exact_routes.h"
#include "numerical_failure.h"

namespace pk {
namespace internal {
namespace {

class CompanionVisitor {
 public:
  CompanionVisitor(const LinearModel& model, const ParameterLayout& layout, const PreparedSubject& s,
                   Eigen::VectorXd* yhat, Eigen::MatrixXd* jac)
      : n_(model.num_compartments()), yhat_(yhat), jac_(jac) {
    for (int c = 0; c < n_; ++c) {
      if (s.sets[0](layout.InitialState(c)) != 0) {
        throw NumericalFailure("the companion route assumes a zero initial state; use forward or adjoint with X0_<n>");
      }
    }
    const Eigen::VectorXd theta = s.sets[0].head(model.num_parameters());
    for (size_t k = 1; k < s.sets.size(); ++k) {
      if (!(s.sets[k].head(model.num_parameters()).array() == theta.array()).all()) {
        throw NumericalFailure("the companion route needs time-invariant coefficients (one value of each a_i, b_i)");
      }
    }
    b_ = model.OutputRow<double>(1, theta);
    Eigen::MatrixXd m = Eigen::MatrixXd::Zero(2 * n_, 2 * n_);
    const Eigen::MatrixXd a = model.SystemMatrix<double>(theta);
    m.topLeftCorner(n_, n_) = a;
    m.bottomRightCorner(n_, n_) = a;
    m.block(n_, 0, 1, n_) = -b_;  // ω₁' gets −y
    disc_.reset(new Discretization(m, n_));
    int count = 0;
    sample_ = SampleIndex(s, &count);
    yhat->setZero(count);
    jac->setZero(count, 2 * n_);
    z_ = Eigen::VectorXd::Zero(2 * n_);
  }

  void Advance(double h, const Eigen::VectorXd& u, int) {
    const bool input = !u.isZero(0.0);
    const Discretization::Step& st = disc_->Get(h, input);
    z_ = st.phi * z_;
    if (input) z_ += st.gamma * u;
  }
  void Bolus(int cmt, double amount, int) { z_(cmt) += amount; }
  void Reset() { z_.setZero(); }
  void DoseEntered(double, int) {}

  void SteadyState(const SteadyStateCycle<double>& cycle, int, bool add) {
    std::vector<std::pair<double, Eigen::VectorXd>> period;
    for (const Segment<double>& seg : cycle.period) period.emplace_back(seg.duration, seg.rate);
    Eigen::VectorXd b = Eigen::VectorXd::Zero(2 * n_);
    b(cycle.cmt) = cycle.bolus;
    const PeriodicSteadyState ss = SolvePeriodicSteadyState(disc_.get(), 2 * n_, b, period);
    Eigen::VectorXd z = ss.x_star + b;
    for (const Segment<double>& seg : cycle.to_record) {
      const bool input = !seg.rate.isZero(0.0);
      const Discretization::Step& st = disc_->Get(seg.duration, input);
      z = st.phi * z;
      if (input) z += st.gamma * seg.rate;
    }
    z_ = add ? Eigen::VectorXd(z_ + z) : z;
  }

  void SteadyInfusion(const Eigen::VectorXd& u, int, bool add) {
    const Eigen::PartialPivLU<Eigen::MatrixXd> lu(disc_->A());
    if (!(lu.rcond() > 1e-13)) throw NumericalFailure("no steady state for a constant infusion");
    Eigen::VectorXd rhs = Eigen::VectorXd::Zero(2 * n_);
    rhs.head(n_) = -u;
    const Eigen::VectorXd z = lu.solve(rhs);
    z_ = add ? Eigen::VectorXd(z_ + z) : z;
  }

  void RecordDone(int r, int) {
    const int k = sample_[r];
    if (k < 0) return;
    (*yhat_)(k) = b_ * z_.head(n_);
    jac_->row(k).head(n_) = z_.tail(n_).transpose();  // ∂y/∂a_i = ω_i
    jac_->row(k).tail(n_) = z_.head(n_).transpose();  // ∂y/∂b_i = x_i
  }

 private:
  int n_;
  Eigen::VectorXd* yhat_;
  Eigen::MatrixXd* jac_;
  Eigen::RowVectorXd b_;
  std::unique_ptr<Discretization> disc_;
  std::vector<int> sample_;
  Eigen::VectorXd z_;
};

}  // namespace

void CompanionJacobian(const LinearModel& model, const ParameterLayout& layout, const PreparedSubject& subject,
                       Eigen::VectorXd* yhat, Eigen::MatrixXd* jacobian) {
  CompanionVisitor visitor(model, layout, subject, yhat, jacobian);
  EventEngine<double, CompanionVisitor> engine(subject, layout, subject.sets, &visitor);
  engine.Run();
}

}  // namespace internal
}  // namespace pk
