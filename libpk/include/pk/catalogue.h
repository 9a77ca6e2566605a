// libpk: the model catalogue.
//
// Catalogue names and parameter names are part of the interface:
//
//   1cmt_iv    (CL, V)                    1cmt_oral  (KA, CL, V)
//   2cmt_iv    (CL, V1, Q, V2)            2cmt_oral  (KA, CL, V2, Q, V3)
//   3cmt_iv    (CL, V1, Q2, V2, Q3, V3)   3cmt_oral  (KA, CL, V2, Q3, V3, Q4, V4)
//
// The names are NONMEM's (ADVAN1-4/11/12 with TRANS2/TRANS4): behind a depot the central
// compartment is 2, so its volume is V2 (docs/models.md).
//   tf1 … tf4  (A1..An, B1..Bn)           y = B(s)/A(s)·u in companion form
//   1cmt_oral_transit (MTT, KA, CL, V)    NTR transit compartments (option
//                                         "1cmt_oral_transit:NTR=5", default 3)
//
// Nonlinear models (pk/ode_model.h; the ODE propagator only):
//
//   1cmt_iv_mm   (VMAX, KM, V)            Michaelis–Menten elimination
//   1cmt_oral_mm (KA, VMAX, KM, V)        VMAX·C/(KM + C), C = A/V
//   2cmt_iv_mm   (VMAX, KM, V1, Q, V2)
//   1cmt_iv_emax (CL, V, KE0, E0, EMAX, EC50, HILL)   effect compartment and
//                                         sigmoid Emax; DVID 1 = C, 2 = effect
//
// Oral models number the depot 1 and the central compartment 2; IV models
// number the central compartment 1; peripherals follow. The default output is
// the central concentration A_central / V_central. A tf<n> model has states
// X1..Xn; doses enter X1 (CMT 1) and every observation is the output y.
#ifndef PK_CATALOGUE_H_
#define PK_CATALOGUE_H_

#include <memory>
#include <string>
#include <vector>

#include "pk/model.h"
#include "pk/model_file.h"

namespace pk {

/// Names of every catalogue model, in catalogue order.
std::vector<std::string> CatalogueModelNames();

/// The catalogue model with this name (case-insensitive), optionally followed by
/// a model option (":NTR=5"), or the model in a file when `name` ends in .pkm or holds a '/'
/// (pk/model_file.h), whose random effects enter as `etas` says. Throws
/// pk::InputError listing the catalogue when there is none.
std::shared_ptr<const Model> MakeModel(const std::string& name, RandomEffects etas = RandomEffects::kZero);

}  // namespace pk

#endif  // PK_CATALOGUE_H_
