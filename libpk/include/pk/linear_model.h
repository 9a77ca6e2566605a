// libpk: linear compartment models, dx/dt = A(θ) x + u, y = C(θ) x + d(θ).
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

#include <functional>
#include <memory>
#include <type_traits>
#include <utility>
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

/// One term of A(θ) or of an output row C(θ): sign · θ[numerator] / θ[denominator]
/// at (row, col); an index of -1 stands for the constant 1.
struct LinearTerm {
  int row = 0;
  int col = 0;
  double sign = 1;
  int numerator = -1;
  int denominator = -1;
};

/// Coefficients ψ(θ) that A(θ) and C(θ) read beside θ, for entries that are not c·θa/θb: a model
/// file's −CL/V with CL = TVCL·WT·exp(η_CL), for example. In a LinearTerm, a numerator or
/// denominator m + k (m: the number of parameters) stands for ψ_k. The derivatives of ψ come from
/// automatic differentiation of the model file's expressions, so A's and C's stay exact.
struct DerivedCoefficients {
  int count = 0;
  /// ψ(θ), and ∂ψ/∂θ (count × m) when `jacobian` is not null.
  std::function<void(const Eigen::VectorXd& theta, Eigen::VectorXd* psi, Eigen::MatrixXd* jacobian)> evaluate;
  /// The parameters each ψ_k reads, whatever θ is (a derivative that vanishes at one θ may not at another).
  std::vector<std::vector<int>> reads;
  /// Along two directions u and v of θ: ψ, ∂ψ·u, ∂ψ·v and ∂²ψ[u, v] (the second-order
  /// sensitivities need the last). Every output is resized here.
  std::function<void(const Eigen::VectorXd& theta, const Eigen::VectorXd& u, const Eigen::VectorXd& v,
                     Eigen::VectorXd* psi, Eigen::VectorXd* psi_u, Eigen::VectorXd* psi_v, Eigen::VectorXd* psi_uv)>
      evaluate_second;
  /// Along three directions of θ (the columns of `directions`, m × 3): (*parts)[S] is ψ's part S
  /// of pk::HyperDual3, its mixed derivative along the directions in the bit mask S (0: ψ itself,
  /// 7: ∂³ψ[u, v, w]); eight vectors. Optional: without it a model has no third-order
  /// sensitivities (the Laplace gradient then differences the OFV).
  std::function<void(const Eigen::VectorXd& theta, const Eigen::MatrixXd& directions,
                     std::vector<Eigen::VectorXd>* parts)>
      evaluate_third;
};

class LinearModel final : public Model {
 public:
  bool is_linear() const override { return true; }
  double Output(int cmt, const Eigen::VectorXd& x, const Eigen::VectorXd& theta) const override;

  /// A model from its terms: A(θ) = Σ system terms; the output of an observation
  /// in compartment c (1-based) is C_c(θ) x with C_c = Σ output_terms[c-1] (their
  /// `row` is ignored). `transfer_function_order` is n for a companion-form tf<n>
  /// model (see pk/catalogue.h), 0 otherwise. With named `outputs` (K of them, chosen by
  /// DVID: Model::output_names), output_terms holds n + K rows, row n + k being output k's.
  static std::shared_ptr<const LinearModel> FromTerms(std::string name, std::string description,
                                                      std::vector<std::string> compartments,
                                                      std::vector<std::string> parameters, Eigen::VectorXd defaults,
                                                      int central, int default_dose,
                                                      std::vector<LinearTerm> system_terms,
                                                      std::vector<std::vector<LinearTerm>> output_terms,
                                                      int transfer_function_order = 0,
                                                      InitialStructure initial_structure = {},
                                                      ModelDeclarations declarations = {},
                                                      std::vector<std::string> signed_parameters = {},
                                                      DerivedCoefficients derived = {},
                                                      std::vector<std::string> outputs = {},
                                                      std::vector<std::vector<LinearTerm>> output_offsets = {});

  const std::vector<LinearTerm>& system_terms() const { return a_terms_; }
  /// ψ(θ) when terms read derived coefficients (count 0 otherwise).
  const DerivedCoefficients& derived_coefficients() const { return derived_; }
  /// [θ; ψ(θ)], what the terms index, for any scalar type: ψ's derivatives follow θ's by the chain
  /// rule. θ itself when the model has no derived coefficients.
  template <typename T>
  Eigen::Matrix<T, Eigen::Dynamic, 1> ExtendedParameters(const Eigen::Matrix<T, Eigen::Dynamic, 1>& theta) const;
  /// The terms of the output row C_c(θ) of compartment `cmt` (1-based), or of named output k
  /// for `cmt` = n + k.
  const std::vector<LinearTerm>& output_terms(int cmt) const { return c_terms_[cmt - 1]; }
  /// The terms of the offset d_c(θ) of the same row (their `row` and `col` are ignored): an
  /// output's part that reads no amount, such as a baseline (E = E0 + SLOPE·CE). Empty for
  /// every catalogue model; `output_offsets` of FromTerms, indexed as `output_terms`.
  const std::vector<LinearTerm>& output_offset_terms(int cmt) const {
    static const std::vector<LinearTerm> kNone;
    return d_terms_.empty() ? kNone : d_terms_[cmt - 1];
  }
  /// Whether some output row has an offset d(θ).
  bool has_output_offsets() const { return !d_terms_.empty(); }

  /// The value of one term, sign · θ[numerator] / θ[denominator], for any
  /// scalar type; `theta(i)` gives θ_i as that type.
  template <typename T, typename Theta>
  static T TermValue(const LinearTerm& t, const Theta& theta) {
    T v(t.sign);
    if (t.numerator >= 0) v = v * theta(t.numerator);
    if (t.denominator >= 0) v = v / theta(t.denominator);
    return v;
  }
  /// n for the companion-form transfer-function models tf<n>, else 0.
  int transfer_function_order() const { return tf_order_; }

  /// A(θ), for any scalar type (double or an automatic-differentiation scalar).
  template <typename T>
  Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> SystemMatrix(
      const Eigen::Matrix<T, Eigen::Dynamic, 1>& theta) const {
    if (derived_.count > 0) return SystemMatrixOf<T>(ExtendedParameters<T>(theta));
    return SystemMatrixOf<T>(theta);
  }

  /// ⟨G, A(θ)⟩ = Σ_ik G_ik A_ik(θ), for any scalar type. Its derivative with
  /// respect to θ_j is ⟨G, ∂A/∂θ_j⟩, which is how the adjoint route turns one
  /// n×n matrix per parameter set into the gradient for every θ_j.
  template <typename T>
  T ContractSystemMatrix(const Eigen::Matrix<T, Eigen::Dynamic, 1>& theta, const Eigen::MatrixXd& g) const {
    if (derived_.count > 0) return ContractOf<T>(ExtendedParameters<T>(theta), g);
    return ContractOf<T>(theta, g);
  }

  /// The output row C(θ) for an observation in compartment `cmt` (1-based). For
  /// a compartment model y = C x is that compartment's concentration, or its
  /// amount if it has no volume; for a tf<n> model it is the output B(s)/A(s)·u.
  /// `cmt` = n + k (k ≥ 1) is named output k's row (Model::output_names).
  template <typename T>
  Eigen::Matrix<T, 1, Eigen::Dynamic> OutputRow(int cmt,
                                                const Eigen::Matrix<T, Eigen::Dynamic, 1>& theta) const {
    if (derived_.count > 0) return OutputRowOf<T>(cmt, ExtendedParameters<T>(theta));
    return OutputRowOf<T>(cmt, theta);
  }

  /// The offset d_c(θ) of output row `cmt` (0 when it has none), for any scalar type: the
  /// output is y = C_c(θ) x + d_c(θ) (Output()). The propagators and routes compute C x; the
  /// objective adds d and its derivatives by AD (libpk/src/objective/output_offsets.h).
  template <typename T>
  T OutputOffset(int cmt, const Eigen::Matrix<T, Eigen::Dynamic, 1>& theta) const {
    if (output_offset_terms(cmt).empty()) return T(0.0);
    if (derived_.count > 0) return OutputOffsetOf<T>(cmt, ExtendedParameters<T>(theta));
    return OutputOffsetOf<T>(cmt, theta);
  }

 private:
  friend class LinearModelBuilder;
  LinearModel(std::string name, std::string description, std::vector<std::string> compartments,
              std::vector<std::string> parameters, Eigen::VectorXd defaults, int central, int default_dose,
              std::vector<LinearTerm> a_terms, std::vector<std::vector<LinearTerm>> c_terms, int tf_order);

  static double ScalarValue(double x) { return x; }
  template <typename T>
  static double ScalarValue(const T& x) {
    return x.value();
  }

  // The three above on what the terms index: [θ; ψ], or θ.
  template <typename T>
  Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> SystemMatrixOf(const Eigen::Matrix<T, Eigen::Dynamic, 1>& theta) const {
    const int n = num_compartments();
    Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> a =
        Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>::Zero(n, n);
    for (const LinearTerm& t : a_terms_) a(t.row, t.col) += TermValue<T>(t, theta);
    return a;
  }
  template <typename T>
  T ContractOf(const Eigen::Matrix<T, Eigen::Dynamic, 1>& theta, const Eigen::MatrixXd& g) const {
    T sum(0.0);
    for (const LinearTerm& t : a_terms_) {
      if (g(t.row, t.col) != 0) sum += TermValue<T>(t, theta) * g(t.row, t.col);
    }
    return sum;
  }
  template <typename T>
  Eigen::Matrix<T, 1, Eigen::Dynamic> OutputRowOf(int cmt, const Eigen::Matrix<T, Eigen::Dynamic, 1>& theta) const {
    Eigen::Matrix<T, 1, Eigen::Dynamic> c = Eigen::Matrix<T, 1, Eigen::Dynamic>::Zero(num_compartments());
    for (const LinearTerm& t : c_terms_[cmt - 1]) c(t.col) += TermValue<T>(t, theta);
    return c;
  }

  template <typename T>
  T OutputOffsetOf(int cmt, const Eigen::Matrix<T, Eigen::Dynamic, 1>& theta) const {
    T d(0.0);
    for (const LinearTerm& t : d_terms_[cmt - 1]) d += TermValue<T>(t, theta);
    return d;
  }

  std::vector<LinearTerm> a_terms_;
  std::vector<std::vector<LinearTerm>> c_terms_;
  std::vector<std::vector<LinearTerm>> d_terms_;  // empty, or one offset per row of c_terms_
  int tf_order_ = 0;
  DerivedCoefficients derived_;
};

template <typename T>
Eigen::Matrix<T, Eigen::Dynamic, 1> LinearModel::ExtendedParameters(
    const Eigen::Matrix<T, Eigen::Dynamic, 1>& theta) const {
  if (derived_.count == 0) return theta;
  const Eigen::Index m = num_parameters();
  Eigen::VectorXd values(m);
  for (Eigen::Index i = 0; i < m; ++i) values(i) = ScalarValue(theta(i));
  Eigen::VectorXd psi;
  Eigen::MatrixXd jacobian;
  derived_.evaluate(values, &psi, std::is_same<T, double>::value ? nullptr : &jacobian);
  Eigen::Matrix<T, Eigen::Dynamic, 1> extended(m + derived_.count);
  extended.head(m) = theta.head(m);
  for (int k = 0; k < derived_.count; ++k) {
    T v(psi(k));
    if constexpr (!std::is_same<T, double>::value) {
      // ψ_k + Σ_j ∂ψ_k/∂θ_j (θ_j − value(θ_j)): ψ_k's value with θ's derivatives chained through.
      for (const int j : derived_.reads[static_cast<size_t>(k)]) {
        if (jacobian(k, j) != 0) v += jacobian(k, j) * (theta(j) - T(values(j)));
      }
    }
    extended(m + k) = v;
  }
  return extended;
}

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
  /// Declares the structure data-driven starting values may assume (pk/model.h).
  void SetInitialStructure(InitialStructure structure) { initial_structure_ = std::move(structure); }
  /// Names the parameters had in earlier versions and no parameter has now, with the note that
  /// says what they are called today (Model::UnknownParameter quotes it).
  void SetFormerNames(std::vector<std::string> names, std::string note) {
    former_names_ = std::move(names);
    former_names_note_ = std::move(note);
  }
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
  InitialStructure initial_structure_;
  std::vector<std::string> former_names_;
  std::string former_names_note_;
};

}  // namespace pk

#endif  // PK_LINEAR_MODEL_H_
