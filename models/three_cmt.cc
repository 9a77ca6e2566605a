// 3cmt_iv (CL, V1, Q2, V2, Q3, V3) and 3cmt_oral (KA, CL, V1, Q2, V2, Q3, V3).
#include "catalogue_models.h"

namespace pk {
namespace models {
namespace {

// Mammillary disposition: a central compartment exchanging with two peripherals.
int Disposition(LinearModelBuilder& b) {
  const int cl = b.Parameter("CL", 3.0), v1 = b.Parameter("V1", 10.0);
  const int q2 = b.Parameter("Q2", 8.0), v2 = b.Parameter("V2", 20.0);
  const int q3 = b.Parameter("Q3", 1.0), v3 = b.Parameter("V3", 60.0);
  const int central = b.Compartment("CENTRAL", v1);
  const int shallow = b.Compartment("PERIPHERAL1", v2), deep = b.Compartment("PERIPHERAL2", v3);
  b.ClearanceFlow(central, LinearModelBuilder::kOutside, cl);
  b.ClearanceFlow(central, shallow, q2);
  b.ClearanceFlow(shallow, central, q2);
  b.ClearanceFlow(central, deep, q3);
  b.ClearanceFlow(deep, central, q3);
  b.SetCentral(central);
  return central;
}

}  // namespace

std::shared_ptr<const LinearModel> ThreeCmtIv() {
  LinearModelBuilder b("3cmt_iv", "three compartments (mammillary), IV bolus or infusion");
  b.SetDefaultDose(Disposition(b));
  b.SetInitialStructure({InitialStructure::Kind::kMammillary, 3, false, {"CL", "V1", "Q2", "V2", "Q3", "V3"}, "", ""});
  return b.Build();
}

std::shared_ptr<const LinearModel> ThreeCmtOral() {
  LinearModelBuilder b("3cmt_oral", "three compartments (mammillary), first-order absorption from a depot");
  const int ka = b.Parameter("KA", 1.5);
  const int depot = b.Compartment("DEPOT");
  const int central = Disposition(b);
  b.RateFlow(depot, central, ka);
  b.SetDefaultDose(depot);
  b.SetInitialStructure({InitialStructure::Kind::kMammillary, 3, true, {"KA", "CL", "V1", "Q2", "V2", "Q3", "V3"}, "", ""});
  return b.Build();
}

}  // namespace models
}  // namespace pk
