// libpk: the units of a dataset's time, amount and concentration, and the units of the
// parameters that follow from them (CL in L/h when time is h, AMT mg and DV mg/L).
//
// Units are labels: libpk never converts values. They come from --units or from a units row
// of the dataset: a comment line right after the header, '#' followed by one field per column
// ("ID,TIME,AMT,DV" then "#,h,mg,mg/L"; in a blank-separated file "# . h mg mg/L", '.' for no
// unit); NONMEM skips it as a comment (IGNORE=#).
#ifndef PK_UNITS_H_
#define PK_UNITS_H_

#include <map>
#include <string>

#include "pk/dataset.h"
#include "pk/model.h"

namespace pk {

struct Units {
  std::string time;           ///< e.g. "h"
  std::string amount;         ///< of AMT, e.g. "mg"
  std::string concentration;  ///< of DV, e.g. "mg/L" (or "ng/mL")
  /// Units a model file gives its parameters by name (upper case), which ParameterUnit returns
  /// before deriving one (see ModelUnits).
  std::map<std::string, std::string> parameters;
  bool empty() const { return time.empty() && amount.empty() && concentration.empty(); }
};

/// `units` with the units a model file declares for its parameters and modifiers.
Units ModelUnits(const Units& units, const Model& model);

/// "time=h,amt=mg,conc=mg/L" (any subset; keys time, amt or amount, conc or dv). Throws
/// pk::InputError for another key or a missing '='.
Units ParseUnits(const std::string& text);

/// The units the dataset's units row gives TIME, AMT and DV (empty where it gives none).
Units DatasetUnits(const Dataset& data);

/// `given` where it has a unit, else `fallback`'s.
Units MergeUnits(const Units& given, const Units& fallback);

/// The unit of a volume: amount/concentration, "L" for mg and mg/L; "mg/(ng/mL)" when the two
/// mass units differ. Empty when either is unknown.
std::string VolumeUnit(const Units& units);

/// The unit of a parameter by its NONMEM name: volumes (V, V1…), clearances (CL, Q, Q2…), rate
/// constants (KA, K, K10, KE0, LAMBDA…), times (ALAG, D, MTT, THALF…), VMAX, KM, EC50, R and an
/// additive σ, and the exposure metrics (AUC concentration·time, CMAX/CMIN/CTROUGH, TMAX). Empty
/// when the name says nothing (tf coefficients, E0, EMAX) or a unit is missing;
/// "1" for the dimensionless ones (F, HILL, a proportional σ). A unit in `units.parameters` wins.
std::string ParameterUnit(const std::string& name, const Units& units);

/// "NAME (unit)", or the name alone when the unit is empty or "1".
std::string WithUnit(const std::string& name, const std::string& unit);

}  // namespace pk

#endif  // PK_UNITS_H_
