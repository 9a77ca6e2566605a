// Second-order sensitivities on the ODE propagator: the stacked system of second_order.h, stepped
// by Dormand–Prince 5(4) (rk_solver.h's DormandPrinceTo) between the event engine's events.
#include "second_order.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <string>

#include "../numerical_failure.h"
#include "rk_solver.h"

namespace pk {
namespace internal {
namespace {

using State = Eigen::VectorXd;

constexpr long kMaxSteps = 1000000;  // per segment: a stiff segment takes many explicit steps, not this many

// The event engine's visitor: z = [x; s_1 … s_p; w_1 … w_P] (each block n long) through the events,
// and ∂²ŷ at the samples.
class SecondOrderVisitor {
 public:
  SecondOrderVisitor(const OdeSubject& o, const std::vector<DualVector>& sets, int num_free,
                     const std::vector<std::pair<int, int>>& pairs, std::vector<Eigen::VectorXd>* out)
      : o_(o),
        model_(*o.system->nonlinear()),
        n_(o.system->n()),
        m_(o.system->num_theta()),
        p_(num_free),
        pairs_(pairs),
        out_(out),
        z_(State::Zero(n_ * (1 + p_ + static_cast<int>(pairs.size())))) {
    for (const DualVector& set : sets) {
      theta_.push_back(Values(set, m_));
      dtheta_.push_back(DerivativeMatrix(set, p_, m_));
    }
    out->assign(pairs.size(), Eigen::VectorXd::Zero(o.num_samples));
  }

  void Advance(double h, const Eigen::VectorXd& u, int set) {
    if (h <= 0) return;
    const Eigen::VectorXd& theta = theta_[static_cast<size_t>(set)];
    const Eigen::MatrixXd& dtheta = dtheta_[static_cast<size_t>(set)];
    const auto rhs = [&](const Eigen::VectorXd& z, Eigen::VectorXd* dz) { Derivative(z, theta, dtheta, u, dz); };
    DormandPrinceTo(rhs, h, o_.options.absolute_tolerance, o_.options.relative_tolerance, kMaxSteps, &z_,
                    &last_step_);
  }
  void Bolus(int cmt, double amount, int) { z_(cmt) += amount; }  // s and w do not jump: amounts are free of p
  void Reset() { z_.setZero(); }
  void SteadyState(const SteadyStateCycle<double>&, int, bool) { NoSteadyState(); }
  void SteadyInfusion(const Eigen::VectorXd&, int, bool) { NoSteadyState(); }
  void DoseEntered(double, int) {}
  void RecordDone(int r, int set) {
    const int k = o_.sample_of_record[static_cast<size_t>(r)];
    if (k < 0) return;
    const int key = o_.key_of_record[static_cast<size_t>(r)];
    const Eigen::VectorXd& theta = theta_[static_cast<size_t>(set)];
    const Eigen::MatrixXd& dtheta = dtheta_[static_cast<size_t>(set)];
    const Eigen::VectorXd x = z_.head(n_);
    for (size_t i = 0; i < pairs_.size(); ++i) {
      (*out_)[i](k) = model_.OutputSecondDirectional(key, x, theta, Directions(z_, dtheta, i));
    }
  }

 private:
  [[noreturn]] static void NoSteadyState() {
    throw NumericalFailure("second-order sensitivities on the ODE propagator do not cover steady states");
  }

  // The pair i's directions, read from the stacked state z.
  SecondDirections Directions(const State& z, const Eigen::MatrixXd& dtheta, size_t i) const {
    const auto [k, l] = pairs_[i];
    SecondDirections d;
    d.dx1 = z.data() + n_ * (1 + k);
    d.dx2 = z.data() + n_ * (1 + l);
    d.dtheta1 = dtheta.col(k).data();
    d.dtheta2 = dtheta.col(l).data();
    d.dx12 = z.data() + n_ * (1 + p_ + static_cast<int>(i));
    return d;
  }

  // dz/dt: x' = f + u, s' = f_x s + f_θ θ_p (one tape sweep), w_kl' = f_x w_kl + f''[d_k, d_l].
  void Derivative(const State& z, const Eigen::VectorXd& theta, const Eigen::MatrixXd& dtheta,
                  const Eigen::VectorXd& u, State* dz) const {
    dz->resize(z.size());
    x_ = z.head(n_);
    s_ = Eigen::Map<const Eigen::MatrixXd>(z.data() + n_, n_, p_);
    model_.RhsDirectional(x_, theta, s_, dtheta, &f_, &df_);
    dz->head(n_) = f_ + u;
    Eigen::Map<Eigen::MatrixXd>(dz->data() + n_, n_, p_) = df_;
    for (size_t i = 0; i < pairs_.size(); ++i) {
      model_.RhsSecondDirectional(x_, theta, Directions(z, dtheta, i), &f12_);
      dz->segment(n_ * (1 + p_ + static_cast<int>(i)), n_) = f12_;
    }
  }

  const OdeSubject& o_;
  const OdeModel& model_;
  const int n_, m_, p_;
  const std::vector<std::pair<int, int>>& pairs_;
  std::vector<Eigen::VectorXd>* out_;
  State z_;
  double last_step_ = 0;  // the last proposal of a step not cut short by a segment's end (0: none yet)
  std::vector<Eigen::VectorXd> theta_;   // per parameter set
  std::vector<Eigen::MatrixXd> dtheta_;  // ∂θ/∂p per set (m×p)
  mutable Eigen::VectorXd x_, f_, f12_;  // scratch of Derivative
  mutable Eigen::MatrixXd s_, df_;
};

}  // namespace

void OdeSecondOrderSensitivities(const OdeSubject& o, const PreparedSubject& s, const std::vector<DualVector>& sets,
                                 int num_free, const std::vector<std::pair<int, int>>& pairs,
                                 std::vector<Eigen::VectorXd>* out) {
  if (o.system->nonlinear() == nullptr) {
    throw NumericalFailure("second-order sensitivities on the ODE propagator serve nonlinear models");
  }
  if (!o.continuous.series.empty()) {
    throw NumericalFailure("second-order sensitivities do not cover continuous records (CONT=1)");
  }
  for (const auto& [k, l] : pairs) {
    if (k < 0 || k >= num_free || l < 0 || l >= num_free) throw NumericalFailure("a pair names no free parameter");
  }
  SecondOrderVisitor visitor(o, sets, num_free, pairs, out);
  EventEngine<double, SecondOrderVisitor> engine(s, *o.layout, s.sets, &visitor);
  engine.Run();
}

}  // namespace internal
}  // namespace pk
