// 3cmt_iv (CL, V1, Q2, V2, Q3, V3: NONMEM's ADVAN11 TRANS4) and 3cmt_oral (KA, CL, V2, Q3, V3, Q4,
// V4: ADVAN12 TRANS4).
#include "catalogue_models.h"

namespace pk {
namespace models {
namespace {

// NONMEM numbers volumes and intercompartmental clearances by compartment, one higher behind a depot.
struct Names {
  const char *central, *q_shallow, *shallow, *q_deep, *deep;
};

// Mammillary disposition: a central compartment exchanging with two peripherals.
int Disposition(LinearModelBuilder& b, const Names& n) {
  const int cl = b.Parameter("CL", 3.0), vc = b.Parameter(n.central, 10.0);
  const int q2 = b.Parameter(n.q_shallow, 8.0), v2 = b.Parameter(n.shallow, 20.0);
  const int q3 = b.Parameter(n.q_deep, 1.0), v3 = b.Parameter(n.deep, 60.0);
  const int central = b.Compartment("CENTRAL", vc);
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
  b.SetDefaultDose(Disposition(b, {"V1", "Q2", "V2", "Q3", "V3"}));
  b.SetInitialStructure({InitialStructure::Kind::kMammillary, 3, false, {"CL", "V1", "Q2", "V2", "Q3", "V3"}, "", ""});
  return b.Build();
}

std::shared_ptr<const LinearModel> ThreeCmtOral() {
  LinearModelBuilder b("3cmt_oral", "three compartments (mammillary), first-order absorption from a depot");
  const int ka = b.Parameter("KA", 1.5);
  const int depot = b.Compartment("DEPOT");
  const int central = Disposition(b, {"V2", "Q3", "V3", "Q4", "V4"});
  b.RateFlow(depot, central, ka);
  b.SetDefaultDose(depot);
  b.SetInitialStructure({InitialStructure::Kind::kMammillary, 3, true, {"KA", "CL", "V2", "Q3", "V3", "Q4", "V4"}, "", ""});
  b.SetFormerNames({"V1", "Q2"}, "its parameters have NONMEM's ADVAN12 TRANS4 names: V2, Q3, V3, Q4 and V4 are "
                                 "what were V1, Q2, V2, Q3 and V3 (central volume, then each peripheral's clearance "
                                 "and volume)");
  return b.Build();
}

}  // namespace models
}  // namespace pk
