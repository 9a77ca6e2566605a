// 2cmt_iv (CL, V1, Q, V2) and 2cmt_oral (KA, CL, V1, Q, V2).
#include "catalogue_models.h"

namespace pk {
namespace models {
namespace {

// Central and peripheral compartments with elimination and distribution.
void Disposition(LinearModelBuilder& b, int* central_out) {
  const int cl = b.Parameter("CL", 3.0), v1 = b.Parameter("V1", 20.0);
  const int q = b.Parameter("Q", 5.0), v2 = b.Parameter("V2", 40.0);
  const int central = b.Compartment("CENTRAL", v1), peripheral = b.Compartment("PERIPHERAL", v2);
  b.ClearanceFlow(central, LinearModelBuilder::kOutside, cl);
  b.ClearanceFlow(central, peripheral, q);
  b.ClearanceFlow(peripheral, central, q);
  b.SetCentral(central);
  *central_out = central;
}

}  // namespace

std::shared_ptr<const LinearModel> TwoCmtIv() {
  LinearModelBuilder b("2cmt_iv", "two compartments, IV bolus or infusion");
  int central = 0;
  Disposition(b, &central);
  b.SetDefaultDose(central);
  b.SetInitialStructure({InitialStructure::Kind::kMammillary, 2, false, {"CL", "V1", "Q", "V2"}, "", ""});
  return b.Build();
}

std::shared_ptr<const LinearModel> TwoCmtOral() {
  LinearModelBuilder b("2cmt_oral", "two compartments, first-order absorption from a depot");
  const int ka = b.Parameter("KA", 1.5);
  const int depot = b.Compartment("DEPOT");
  int central = 0;
  Disposition(b, &central);
  b.RateFlow(depot, central, ka);
  b.SetDefaultDose(depot);
  b.SetInitialStructure({InitialStructure::Kind::kMammillary, 2, true, {"KA", "CL", "V1", "Q", "V2"}, "", ""});
  return b.Build();
}

}  // namespace models
}  // namespace pk
