// libpk: starting values from the data, with no user guess (linear methods).
//
// A linear compartment model's concentration after a dose history is a sum of
// exponential kernels convolved with the input: for a unit IV bolus,
// c(t) = Σ_i a_i e^{−λ_i t}; an infusion or a first-order absorption with rate
// KA turns each kernel into a known function of λ_i (and KA). For fixed rates
// the amplitudes a_i are therefore a linear least-squares problem. libpk
// estimates the terminal rate λz by log-linear regression on the last points
// (as in non-compartmental analysis, by adjusted R²), and searches the rates on
// a log-spaced grid spanning the sampling design (from about 1/20 of the
// observed time span to about 20/first sample time) with λz added to it. It
// solves for the amplitudes at each candidate
// (weights 1/DV², so every decade of concentration counts), keeps candidates
// with positive amplitudes, and converts the best feasible one into the
// model's parameters (ExponentialsToMammillary). The fit then refines them.
#ifndef PK_INITIAL_ESTIMATES_H_
#define PK_INITIAL_ESTIMATES_H_

#include <string>
#include <vector>

#include "pk/dataset.h"
#include "pk/model.h"
#include "pk/parameters.h"

namespace pk {

struct InitialEstimate {
  bool ok = false;
  std::string method;    ///< how the values were found
  std::string message;   ///< why not, when !ok
  ParameterValues values;
};

/// Starting values for a catalogue model (1/2/3 compartments, IV or oral, or tf1..tf4) from
/// one subject's data: any number of boluses, infusions (RATE > 0) and ADDL
/// doses into the model's default dose compartment with F = 1 and no lag;
/// steady-state doses, resets and other compartments are not handled.
InitialEstimate EstimateInitialValues(const Model& model, const Dataset& data, int subject);

}  // namespace pk

#endif  // PK_INITIAL_ESTIMATES_H_
