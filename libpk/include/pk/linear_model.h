// libpk: linear compartment models, dx/dt = A(θ) x + u, y = C(θ) x.
//
// A LinearModel is a compartment graph. Each flow moves drug from one
// compartment to another, or out of the system, at a first-order rate that is
// either a rate constant parameter (k) or a clearance over the source volume
// (CL/V). The input u is the vector of infusion rates into each compartment;
// boluses are jumps of x. Because the model is linear and time-invariant
// between events, it can be propagated exactly by x ← Φ(h)x + Γ(h)u with
// Φ = exp(A h) (see pk/simulate.h and docs/exact_propagation.md).
//
//   LinearModelBuilder b("1cmt_oral", "one compartment, first-order absorption");
//   int ka = b.Parameter("KA", 1.0), cl = b.Parameter("CL", 3.0), v = b.Parameter("V", 30.0);
//   int depot = b.Compartment("DEPOT"), central = b.Compartment("CENTRAL", v);
//   b.RateFlow(depot, central, ka);
//   b.ClearanceFlow(central, LinearModelBuilder::kOutside, cl);
//   b.SetCentral(central);
//   b.SetDefaultDose(depot);
//   std::shared_ptr<const LinearModel> model = b.Build();
#ifndef PK_LINEAR_MODEL_H_
#define PK_LINEAR_MODEL_H_

#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pk/model.h"

namespace pk {

/// A first-order flow in the compartment graph (indices are 0-based).
struct LinearFlow {
  int from = 0;
  int to = -1;         ///< -1: out of the system
  int parameter = 0;   ///< rate constant, or clearance when `clearance` is set
  bool clearance = false;
};

class LinearModel final : public Model {
 public:
  bool is_linear() const override { return true; }
  double Output(int cmt, const Eigen::VectorXd& x, const Eigen::VectorXd& theta) const override;

  const std::vector<LinearFlow>& flows() const { return flows_; }
  /// Parameter index of each compartment's volume (0-based), or -1.
  const std::vector<int>& volume_parameters() const { return volumes_; }

  /// A(θ), for any scalar type (double or an automatic-differentiation scalar).
  template <typename T>
  Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> SystemMatrix(
      const Eigen::Matrix<T, Eigen::Dynamic, 1>& theta) const {
    const int n = num_compartments();
    Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> a =
        Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>::Zero(n, n);
    for (const LinearFlow& f : flows_) {
      T k = theta(f.parameter);
      if (f.clearance) k = k / theta(volumes_[f.from]);
      a(f.from, f.from) -= k;
      if (f.to >= 0) a(f.to, f.from) += k;
    }
    return a;
  }

  /// ⟨G, A(θ)⟩ = Σ_ik G_ik A_ik(θ), for any scalar type. Its derivative with
  /// respect to θ_j is ⟨G, ∂A/∂θ_j⟩, which is how the adjoint route turns one
  /// n×n matrix per parameter set into the gradient for every θ_j.
  template <typename T>
  T ContractSystemMatrix(const Eigen::Matrix<T, Eigen::Dynamic, 1>& theta, const Eigen::MatrixXd& g) const {
    T sum(0.0);
    for (const LinearFlow& f : flows_) {
      T k = theta(f.parameter);
      if (f.clearance) k = k / theta(volumes_[f.from]);
      const double w = (f.to >= 0 ? g(f.to, f.from) : 0.0) - g(f.from, f.from);
      if (w != 0) sum += k * w;
    }
    return sum;
  }

  /// The output row C(θ) for an observation in compartment `cmt` (1-based):
  /// y = C x is that compartment's concentration, or its amount if it has no volume.
  template <typename T>
  Eigen::Matrix<T, 1, Eigen::Dynamic> OutputRow(int cmt,
                                                const Eigen::Matrix<T, Eigen::Dynamic, 1>& theta) const {
    Eigen::Matrix<T, 1, Eigen::Dynamic> c =
        Eigen::Matrix<T, 1, Eigen::Dynamic>::Zero(num_compartments());
    const int i = cmt - 1;
    c(i) = volumes_[i] >= 0 ? T(1) / theta(volumes_[i]) : T(1);
    return c;
  }

 private:
  friend class LinearModelBuilder;
  LinearModel(std::string name, std::string description, std::vector<std::string> compartments,
              std::vector<std::string> parameters, Eigen::VectorXd defaults, int central,
              int default_dose, std::vector<LinearFlow> flows, std::vector<int> volumes);

  std::vector<LinearFlow> flows_;
  std::vector<int> volumes_;
};

/// Assembles a LinearModel from its compartment graph. Indices are 0-based.
class LinearModelBuilder {
 public:
  static constexpr int kOutside = -1;

  LinearModelBuilder(std::string name, std::string description);
  /// Declares a parameter with its default (a sensible initial value); returns its index.
  int Parameter(const std::string& name, double default_value);
  /// Declares a compartment, optionally with a volume parameter; returns its index.
  int Compartment(const std::string& name, int volume_parameter = -1);
  /// Flow from -> to (or kOutside) at rate constant θ[k].
  void RateFlow(int from, int to, int k);
  /// Flow from -> to (or kOutside) at rate θ[cl] / V(from); `from` must have a volume.
  void ClearanceFlow(int from, int to, int cl);
  void SetCentral(int compartment);
  void SetDefaultDose(int compartment);
  /// Validates the graph and builds the model; throws std::logic_error on a malformed graph.
  std::shared_ptr<const LinearModel> Build() const;

 private:
  std::string name_;
  std::string description_;
  std::vector<std::string> parameters_;
  std::vector<double> defaults_;
  std::vector<std::string> compartments_;
  std::vector<int> volumes_;
  std::vector<LinearFlow> flows_;
  int central_ = -1;
  int default_dose_ = -1;
};

}  // namespace pk

#endif  // PK_LINEAR_MODEL_H_
