// A fit on the optimiser's scale (not installed): each estimated parameter θ is reached from
// an unbounded φ (log, logit between bounds, or itself), and the objective is evaluated there
// with the chain rule D = diag(dθ/dφ).
#ifndef PK_SRC_ESTIMATION_PROBLEM_H_
#define PK_SRC_ESTIMATION_PROBLEM_H_

#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "pk/fit.h"
#include "pk/objective.h"

namespace pk {
namespace internal {

/// Maps an unbounded φ to θ: first to the scale s (log θ or θ), bounded by the bounds'
/// images, then θ = exp(s) or s.
struct Transform {
  bool log = true;
  double sl = -INFINITY, su = INFINITY;

  double S(double phi) const;
  double DsDphi(double phi) const;
  double Theta(double phi) const { return log ? std::exp(S(phi)) : S(phi); }
  double DthetaDphi(double phi) const { return (log ? Theta(phi) : 1.0) * DsDphi(phi); }
  double Phi(double theta) const;
};

class Problem {
 public:
  Problem(const Objective& obj, std::vector<int> free, std::vector<Transform> tr, Eigen::VectorXd base)
      : obj_(obj), free_(std::move(free)), tr_(std::move(tr)), base_(std::move(base)) {}

  int n() const { return static_cast<int>(free_.size()); }
  const std::vector<int>& free() const { return free_; }
  const Objective& objective() const { return obj_; }
  const Transform& transform(int k) const { return tr_[static_cast<size_t>(k)]; }
  /// The full parameter vector at the start (the estimated ones at their initial values).
  const Eigen::VectorXd& base() const { return base_; }

  Eigen::VectorXd Values(const Eigen::VectorXd& phi) const;
  /// dθ/dφ per estimated parameter.
  Eigen::VectorXd Dtheta(const Eigen::VectorXd& phi) const;
  Eigen::VectorXd PhiOf(const Eigen::VectorXd& values) const;

  /// Evaluates on the φ scale. The last two evaluations are remembered: Fit asks again for the
  /// start and for the optimiser's final point, where the optimiser has usually just evaluated.
  /// The reference stays valid until Eval has computed two more evaluations.
  const Objective::Evaluation& Eval(const Eigen::VectorXd& phi, Objective::Need need);

  /// Whether φ_k is a log or logit of the parameter (else the parameter itself).
  bool LogLike(int k) const {
    return tr_[k].log || std::isfinite(tr_[k].sl) || std::isfinite(tr_[k].su);
  }
  const std::string& Name(int k) const { return obj_.parameter_names()[free_[k]]; }

  int evaluations() const { return evaluations_; }
  const std::string& route() const { return route_; }
  const std::string& propagator() const { return propagator_; }

 private:
  const Objective& obj_;
  std::vector<int> free_;
  std::vector<Transform> tr_;
  Eigen::VectorXd base_;
  int evaluations_ = 0;
  struct Memo {
    Eigen::VectorXd phi;  // empty: unused
    Objective::Need need = Objective::Need::kValue;
    Objective::Evaluation ev;
  };
  Memo memo_[2];
  std::string propagator_ = ToString(obj_.propagator());
  std::string route_ = "none";
};

/// What one run of a minimiser from one start gives.
struct RunResult {
  Eigen::VectorXd phi;
  double value = NAN;
  int iterations = 0;
  TerminationType termination = TerminationType::kFailure;
  std::string message;
  std::vector<int> held;  // LM: coordinates held at their start (levenberg_marquardt.cc)
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_ESTIMATION_PROBLEM_H_
