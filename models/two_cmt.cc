// 2cmt_iv (CL, V1, Q, V2: NONMEM's ADVAN3 TRANS4) and 2cmt_oral (KA, CL, V2, Q, V3: ADVAN4 TRANS4).
#include "catalogue_models.h"

namespace pk {
namespace models {
namespace {

// NONMEM numbers a volume by its compartment: V1 and V2 without a depot, V2 and V3 behind one.
struct VolumeNames {
  const char* central;
  const char* peripheral;
};

// Central and peripheral compartments with elimination and distribution.
int Disposition(LinearModelBuilder& b, const VolumeNames& v) {
  const int cl = b.Parameter("CL", 3.0), vc = b.Parameter(v.central, 20.0);
  const int q = b.Parameter("Q", 5.0), vp = b.Parameter(v.peripheral, 40.0);
  const int central = b.Compartment("CENTRAL", vc), peripheral = b.Compartment("PERIPHERAL", vp);
  b.ClearanceFlow(central, LinearModelBuilder::kOutside, cl);
  b.ClearanceFlow(central, peripheral, q);
  b.ClearanceFlow(peripheral, central, q);
  b.SetCentral(central);
  return central;
}

}  // namespace

std::shared_ptr<const LinearModel> TwoCmtIv() {
  LinearModelBuilder b("2cmt_iv", "two compartments, IV bolus or infusion");
  b.SetDefaultDose(Disposition(b, {"V1", "V2"}));
  b.SetInitialStructure({InitialStructure::Kind::kMammillary, 2, false, {"CL", "V1", "Q", "V2"}, "", ""});
  return b.Build();
}

std::shared_ptr<const LinearModel> TwoCmtOral() {
  LinearModelBuilder b("2cmt_oral", "two compartments, first-order absorption from a depot");
  const int ka = b.Parameter("KA", 1.5);
  const int depot = b.Compartment("DEPOT");
  const int central = Disposition(b, {"V2", "V3"});
  b.RateFlow(depot, central, ka);
  b.SetDefaultDose(depot);
  b.SetInitialStructure({InitialStructure::Kind::kMammillary, 2, true, {"KA", "CL", "V2", "Q", "V3"}, "", ""});
  b.SetFormerNames({"V1"}, "its volumes have NONMEM's ADVAN4 TRANS4 names, V2 the central volume (formerly V1) and "
                           "V3 the peripheral one (formerly V2)");
  return b.Build();
}

}  // namespace models
}  // namespace pk
