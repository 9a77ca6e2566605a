// libpk: models from text files, with exact derivatives and no compiler.
//
// A model file (.pkm) declares parameters, covariates, random effects, compartments, individual
// parameters ($PK), the right-hand side ($ODE), outputs and their residual error; the grammar
// and examples are in docs/model_language.md. For example:
//
//   $PROBLEM 1cmt_oral_mm  one compartment, first-order absorption, saturable elimination
//   $PARAM
//   KA   = 1.5  (0, 100)  1/h
//   VMAX = 20              mg/h
//   KM   = 2               mg/L
//   V    = 30              L
//   $CMT
//   DEPOT   dose
//   CENTRAL central
//   $ODE
//   C = CENTRAL / V
//   d/dt(DEPOT)   = -KA * DEPOT
//   d/dt(CENTRAL) =  KA * DEPOT - VMAX * C / (KM + C)
//   $OUTPUT
//   CP = C
//
// The text is parsed once into an expression graph that libpk evaluates on its own
// automatic-differentiation types, so f_x, f_θ, g_x and g_θ are exact. When the right-hand side is
// linear in the amounts, with coefficients c·θa/θb, and there is one output, the model is a
// pk::LinearModel and runs on the exact Φ/Γ propagator with every gradient route; otherwise it is
// a pk::OdeModel on the ODE propagator. Either way it is a pk::Model like a catalogue model.
#ifndef PK_MODEL_FILE_H_
#define PK_MODEL_FILE_H_

#include <memory>
#include <string>

#include "pk/model.h"
#include "pk/residual_error.h"

namespace pk {

/// How a model file's random effects (the η of $OMEGA) enter the model.
enum class RandomEffects {
  /// η = 0: an individual model, as pkfit and pksim use it. η's are folded away, so a file whose
  /// right-hand side is linear stays on the exact Φ/Γ propagator.
  kZero,
  /// Each η is a model parameter (DeclaredParameter::eta, 0 by default) that a
  /// pk::PopulationProblem binds to the subject's random effect, as NONMEM's ETA(n).
  kParameters,
};

/// The model in file `path`. Throws pk::InputError naming the file, line and column of the first
/// error, and what was expected there.
std::shared_ptr<const Model> LoadModelFile(const std::string& path,
                                           RandomEffects etas = RandomEffects::kZero);

/// The model in `text`; `source` names it in messages (a file name).
std::shared_ptr<const Model> ParseModel(const std::string& text, const std::string& source,
                                        RandomEffects etas = RandomEffects::kZero);

/// The residual-error model a model file's $ERROR gives, or null when it gives none: one $ERROR
/// line serves every output with one set of σ; a line per output gives each output its own model
/// and σ (pk::MakePerOutputError, σ named SIGMA_PROP_CP, …), as NONMEM's EPS per DVID.
std::shared_ptr<const ResidualErrorModel> DeclaredErrorModel(const Model& model);

/// The initial σ a model file's $ERROR gives for `in_use` (the error model a fit uses), one per
/// in_use.sigma_names(): NaN where the file gives none, or when `in_use` is not the file's model.
std::vector<double> DeclaredSigmas(const Model& model, const ResidualErrorModel& in_use);

/// Why a model file that is not linear runs on the ODE propagator ("" for a linear one or a
/// catalogue model), for a note to the user.
std::string WhyNotLinear(const Model& model);

}  // namespace pk

#endif  // PK_MODEL_FILE_H_
