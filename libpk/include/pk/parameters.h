// libpk: the full parameter vector of a model, with its dose modifiers.
//
// Besides the model's own parameters θ, NONMEM's PREDPP lets every dose
// compartment n carry modifiers, and libpk treats them as parameters like any
// other (they can be given with --param, read from a data column, or
// estimated):
//
//   F<n>     bioavailability: scales the bolus amount, or the infusion amount
//            (with RATE>0 the rate is kept and the duration scales)   default 1
//   ALAG<n>  absorption lag: the dose enters ALAG<n> after its time    default 0
//   R<n>     infusion rate, used by doses with RATE=-1                 no default
//   D<n>     infusion duration, used by doses with RATE=-2             no default
//   X0_<n>   initial amount in compartment n at the subject's first    default 0
//            record and after a reset record (EVID 3/4), as NONMEM's A_0(n);
//            a steady-state dose (SS=1) starts from zero
//   K0_<n>   a constant zero-order input into compartment n, always    default 0
//            on (endogenous production: amount per time, any sign), added
//            to the doses' infusion rates; a steady state (SS=1) includes it
//
// The layout is θ followed by F1..Fn, ALAG1..ALAGn, R1..Rn, D1..Dn, X0_1..X0_n, K0_1..K0_n.
// A model file's `d/dt(A) = KIN − KOUT·A` becomes a linear model with K0_1 = KIN computed.
//
// A model file may instead compute a modifier in $PK (`F1 = FPOP * (WT/70)^0.25`,
// pk::ComputedModifiers): its entry then always holds the value computed from the same vector's
// model parameters, and it cannot be given, fixed or estimated.
#ifndef PK_PARAMETERS_H_
#define PK_PARAMETERS_H_

#include <map>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pk/dual.h"
#include "pk/model.h"

namespace pk {

/// Parameter values by name, e.g. {"CL", 2.5}, {"F1", 0.8}. Names are case-insensitive.
using ParameterValues = std::map<std::string, double>;

class ParameterLayout {
 public:
  /// The layout of `model`, which must outlive it.
  explicit ParameterLayout(const Model& model);

  int size() const { return static_cast<int>(names_.size()); }
  int num_model_parameters() const { return num_model_; }
  int num_compartments() const { return n_; }
  const std::vector<std::string>& names() const { return names_; }
  const std::string& name(int i) const { return names_[i]; }
  /// Index of a name (case-insensitive) or -1.
  int Index(const std::string& name) const;

  // Indices of the modifiers of compartment `cmt` (0-based).
  int F(int cmt) const { return num_model_ + cmt; }
  int Alag(int cmt) const { return num_model_ + n_ + cmt; }
  int Rate(int cmt) const { return num_model_ + 2 * n_ + cmt; }
  int Duration(int cmt) const { return num_model_ + 3 * n_ + cmt; }
  int InitialState(int cmt) const { return num_model_ + 4 * n_ + cmt; }
  int ConstantInput(int cmt) const { return num_model_ + 5 * n_ + cmt; }

  /// Whether entry i is a modifier the model computes (ComputedModifiers).
  bool is_computed(int i) const { return i >= 0 && i < size() && computed_flag_[static_cast<size_t>(i)] != 0; }
  /// The model parameters some computed modifier reads (sorted; empty without computed modifiers).
  const std::vector<int>& computed_reads() const { return computed_reads_; }
  /// Sets the computed modifiers of a full layout vector `p` from its model parameters (nothing
  /// to do without computed modifiers). On pk::Dual, their derivatives follow the parameters'.
  void ComputeModifiers(Eigen::VectorXd* p) const;
  void ComputeModifiers(Eigen::Matrix<Dual, Eigen::Dynamic, 1>* p) const;
  /// On pk::HyperDual3: false (p unchanged) when the model has computed modifiers but no
  /// ComputedModifiers::evaluate_third.
  bool ComputeModifiers(Eigen::Matrix<HyperDual3, Eigen::Dynamic, 1>* p) const;
  /// Throws pk::InputError when `name` is a computed modifier; `what` says how it was given
  /// ("a data column", …) and completes "…, so WHAT cannot set it".
  void CheckNotComputed(const std::string& name, const std::string& what) const;

  /// Model defaults, F=1, ALAG=0, X0=0, K0=0, and NaN (unset) for R and D.
  Eigen::VectorXd Defaults() const;
  /// Defaults overridden by `values`; throws pk::InputError for an unknown name,
  /// listing the valid ones.
  Eigen::VectorXd Resolve(const ParameterValues& values) const;

 private:
  const Model* model_;
  int num_model_;
  int n_;
  std::vector<std::string> names_;
  Eigen::VectorXd defaults_;
  std::vector<int> computed_;  // layout indices of the computed modifiers, in ComputedModifiers order
  std::vector<char> computed_flag_;
  std::vector<int> computed_reads_;
};

}  // namespace pk

#endif  // PK_PARAMETERS_H_
