// 1cmt_iv (CL, V) and 1cmt_oral (KA, CL, V).
#include "catalogue_models.h"

namespace pk {
namespace models {

std::shared_ptr<const LinearModel> OneCmtIv() {
  LinearModelBuilder b("1cmt_iv", "one compartment, IV bolus or infusion");
  const int cl = b.Parameter("CL", 3.0), v = b.Parameter("V", 30.0);
  const int central = b.Compartment("CENTRAL", v);
  b.ClearanceFlow(central, LinearModelBuilder::kOutside, cl);
  b.SetCentral(central);
  b.SetDefaultDose(central);
  b.SetInitialStructure({InitialStructure::Kind::kMammillary, 1, false, {"CL", "V"}, "", ""});
  return b.Build();
}

std::shared_ptr<const LinearModel> OneCmtOral() {
  LinearModelBuilder b("1cmt_oral", "one compartment, first-order absorption from a depot");
  const int ka = b.Parameter("KA", 1.5), cl = b.Parameter("CL", 3.0), v = b.Parameter("V", 30.0);
  const int depot = b.Compartment("DEPOT"), central = b.Compartment("CENTRAL", v);
  b.RateFlow(depot, central, ka);
  b.ClearanceFlow(central, LinearModelBuilder::kOutside, cl);
  b.SetCentral(central);
  b.SetDefaultDose(depot);
  b.SetInitialStructure({InitialStructure::Kind::kMammillary, 1, true, {"KA", "CL", "V"}, "", ""});
  return b.Build();
}

}  // namespace models
}  // namespace pk
