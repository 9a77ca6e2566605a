// libpk: the runtime interface every compartment model implements.
//
// A model has n compartments (states), numbered 1..n as in NONMEM's CMT, and
// a vector θ of named parameters. Its prediction for an observation in
// compartment c is the amount in c divided by c's volume when the compartment
// has one (the central compartment always does), and the amount otherwise.
#ifndef PK_MODEL_H_
#define PK_MODEL_H_

#include <cmath>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "pk/dual.h"
#include "pk/hyper_dual.h"

namespace pk {

/// The structure that the data-driven starting values (pk/initial_estimates.h) rely on, as a
/// model declares it. A model that declares none starts from its defaults, and says so.
struct InitialStructure {
  enum class Kind {
    kNone,              ///< no method: the catalogue defaults
    kMammillary,        ///< a mammillary block of `order` compartments (1–3), optionally behind a depot
    kTransferFunction,  ///< tf<order>: y = B(s)/A(s)·u, every observation the output
  };
  Kind kind = Kind::kNone;
  int order = 0;
  /// Doses enter a depot with first-order absorption into the central compartment.
  bool depot = false;
  /// The model's names for the method's values, in the method's order: [KA,] CL, V1[, Q2, V2[,
  /// Q3, V3]] (ExponentialsToMammillary, pk/conversion.h), or A1..An, B1..Bn.
  std::vector<std::string> names;
  /// Saturable (Michaelis–Menten) elimination in place of a clearance: `names` then holds the
  /// linear block's CL, which becomes KM = C̃ and VMAX = CL·(KM + C̃), C̃ the median
  /// concentration, under these names.
  std::string vmax, km;
};

/// A parameter as a model file declares it: a starting value, bounds and a unit.
struct DeclaredParameter {
  std::string name;
  double initial = 0;
  double lower = -HUGE_VAL, upper = HUGE_VAL;
  std::string unit;  ///< "" when not given
  /// A covariate: read from the dataset column of its name and never estimated.
  bool covariate = false;
  /// A random effect η of a model file's $OMEGA, made a parameter by pk::RandomEffects::kParameters:
  /// 0 by default (`initial`), of either sign, never estimated by an individual fit; a population
  /// fit binds it to the subject's η. `variance` is its ω² from $OMEGA (NaN for other parameters).
  bool eta = false;
  double variance = NAN;
};

/// What a model file (pk/model_file.h) declares beyond names and defaults. Catalogue models
/// declare nothing: every vector is empty.
/// One block of a model file's $OMEGA (a single η is a block of one): its η in order, Ω's
/// initial values over them, and whether the block is fixed (FIX).
struct OmegaBlockDeclaration {
  std::vector<std::string> etas;
  Eigen::MatrixXd omega;
  bool fixed = false;
  /// `~ SAME` (NONMEM's BLOCK(n) SAME): the block declared before this one, repeated over these η;
  /// a population fit ties its values to that block's.
  bool same = false;
};

/// Dose modifiers a model computes from its parameters: a model file's `F1 = …` or
/// `ALAG1 = TLAG * exp(ETA_LAG)` in $PK, so that a modifier follows covariates and random effects
/// like any individual parameter. Each record's modifiers come from that record's model parameters
/// (covariates included); on pk::Dual their derivatives follow θ's by the chain rule. A computed
/// modifier cannot be given (--param, a data column), fixed or estimated.
struct ComputedModifiers {
  std::vector<std::string> names;       ///< F1, ALAG2, X0_1, … (pk/parameters.h), in order
  std::vector<std::vector<int>> reads;  ///< the model parameters each reads
  /// Their values from a full model parameter vector θ (one record's set), into `values`.
  std::function<void(const double* theta, double* values)> evaluate;
  std::function<void(const Dual* theta, Dual* values)> evaluate_dual;
  /// On pk::HyperDual3, whose mixed parts the exact higher derivatives need when a modifier moves
  /// with the parameters. Optional: without it those derivatives are refused (and differenced).
  std::function<void(const HyperDual3* theta, HyperDual3* values)> evaluate_third;
  bool empty() const { return names.empty(); }
};

struct ModelDeclarations {
  std::string source;  ///< the model file
  /// Per model parameter, in order: its bounds, unit and whether it is a covariate (the initial
  /// value is the default).
  std::vector<DeclaredParameter> parameters;
  /// Dose modifiers the file estimates (F1, ALAG2, …: names of pk/parameters.h), with their starts.
  std::vector<DeclaredParameter> modifiers;
  /// Dose modifiers the file computes in $PK (empty for the catalogue).
  ComputedModifiers computed_modifiers;
  /// The residual-error model the file gives its outputs ("" when none), and initial σ values
  /// (empty when not given). With an error model per output (pk::DeclaredErrorModel), "per-output",
  /// and the σ of every output in order when each gives them.
  std::string error_model;
  std::vector<double> sigma;
  /// Per output, when the file gives each output its own error model: its name and σ (empty
  /// when not given). Empty when one model serves every output.
  std::vector<std::string> output_error_models;
  std::vector<std::vector<double>> output_sigma;
  /// Why a model file that is not a LinearModel runs on the ODE propagator ("" otherwise).
  std::string why_not_linear;
  /// What the file's $PK defines (CL, V, FAPG, …: the individual parameters), in file order, and
  /// their values from a full model parameter vector (covariates and bound η included, as one
  /// record's parameter set holds them). Empty, and pk_values empty, for the catalogue.
  std::vector<std::string> pk_definitions;
  std::function<Eigen::VectorXd(const Eigen::VectorXd& parameters)> pk_values;
  /// The file's $OMEGA, block by block in η order (empty for the catalogue). pkpop estimates each
  /// block of more than one η with its covariances, and keeps a FIX block at its values.
  std::vector<OmegaBlockDeclaration> omega_blocks;
};

class Model {
 public:
  virtual ~Model() = default;

  const std::string& name() const { return name_; }
  const std::string& description() const { return description_; }
  int num_compartments() const { return static_cast<int>(compartment_names_.size()); }
  const std::vector<std::string>& compartment_names() const { return compartment_names_; }
  int num_parameters() const { return static_cast<int>(parameter_names_.size()); }
  const std::vector<std::string>& parameter_names() const { return parameter_names_; }
  /// Sensible starting values for the catalogue (also the values pksim uses
  /// when neither --param nor the data supplies one).
  const Eigen::VectorXd& default_parameters() const { return default_parameters_; }
  /// 1-based compartment whose concentration is the default output (CP).
  int central_compartment() const { return central_; }
  /// 1-based compartment that receives a dose with CMT=0 or absent.
  int default_dose_compartment() const { return default_dose_; }
  /// Index of a parameter by name (case-insensitive), or -1.
  int ParameterIndex(const std::string& name) const;
  /// What the data-driven starting values may assume of this model (InitialStructure::kNone
  /// unless the model declares it).
  const InitialStructure& initial_structure() const { return initial_structure_; }
  /// Whether parameter i must be positive (a clearance, volume, rate constant, ...: the default),
  /// or may take any sign (a transfer function's coefficients; a baseline or an Emax).
  bool must_be_positive(int i) const { return signed_.empty() || !signed_[static_cast<size_t>(i)]; }

  /// What a model file declares (bounds, units, covariates, estimated modifiers, the error
  /// model); empty for the catalogue.
  const ModelDeclarations& declarations() const { return declarations_; }
  /// Whether parameter i is a covariate: a dataset column, never estimated (false for an index
  /// that is not a model parameter's).
  bool is_covariate(int i) const { return Declared(i) && declarations_.parameters[static_cast<size_t>(i)].covariate; }
  /// Whether parameter i is a model file's random effect η (DeclaredParameter::eta).
  bool is_eta(int i) const { return Declared(i) && declarations_.parameters[static_cast<size_t>(i)].eta; }

  /// Text for an error about a parameter name this model does not have, given the names it
  /// accepts (its parameters, with F1, ALAG1, ... or an error model's σ where they apply):
  /// "'V1' is no longer a parameter of 2cmt_oral: …" when `name` is one of the model's former
  /// names (see set_former_names), else the closest accepted name and the whole list.
  std::string UnknownParameter(const std::string& name, const std::vector<std::string>& names) const;
  /// Whether `name` is a name this model's parameters had in earlier versions of libpk and no
  /// parameter has now (UnknownParameter explains it).
  bool IsFormerName(const std::string& name) const;

  /// True when dx/dt = A(θ)x + u; such a model can use the exact propagator.
  virtual bool is_linear() const = 0;

  /// Named outputs y_1 … y_K; an observation's DVID chooses one (none given: y_1). A nonlinear
  /// model has at least one. A linear model read from a model file has its file's outputs (with
  /// K > 1 it still runs on the exact propagator); a catalogue linear model has none, and an
  /// observation measures the concentration, or amount, of its compartment (CMT).
  int num_outputs() const { return static_cast<int>(output_names_.size()); }
  const std::vector<std::string>& output_names() const { return output_names_; }

  /// Prediction for an observation in compartment `cmt` (1-based) given the
  /// amounts x and parameters θ.
  virtual double Output(int cmt, const Eigen::VectorXd& x, const Eigen::VectorXd& theta) const = 0;

 protected:
  Model(std::string name, std::string description, std::vector<std::string> compartment_names,
        std::vector<std::string> parameter_names, Eigen::VectorXd default_parameters, int central,
        int default_dose);
  /// Sets what data-driven starting values may assume; the names are taken as upper case.
  void set_initial_structure(InitialStructure s);
  /// Declares parameters that may be zero or negative (by name; the others must be positive).
  void set_signed_parameters(const std::vector<std::string>& names);
  /// Declares names the model's parameters had before and no parameter has now, with a note
  /// saying what they are called today (for example NONMEM's TRANS4 names of 2cmt_oral).
  void set_former_names(std::vector<std::string> names, std::string note);
  /// Sets what a model file declares (see declarations()).
  void set_declarations(ModelDeclarations d) { declarations_ = std::move(d); }
  /// Names the outputs (see output_names()).
  void set_output_names(std::vector<std::string> names) { output_names_ = std::move(names); }

 private:
  bool Declared(int i) const { return i >= 0 && static_cast<size_t>(i) < declarations_.parameters.size(); }

  std::string name_;
  std::string description_;
  std::vector<std::string> compartment_names_;
  std::vector<std::string> parameter_names_;
  Eigen::VectorXd default_parameters_;
  int central_;
  int default_dose_;
  InitialStructure initial_structure_;
  std::vector<bool> signed_;  // per parameter; empty: none
  std::vector<std::string> former_names_;
  std::string former_names_note_;
  ModelDeclarations declarations_;
  std::vector<std::string> output_names_;
};

}  // namespace pk

#endif  // PK_MODEL_H_
