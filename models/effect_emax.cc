// 1cmt_iv_emax (CL, V, KE0, E0, EMAX, EC50, HILL): a one-compartment PK model
// driving an effect compartment, dCe/dt = KE0 (C − Ce), and a sigmoid Emax
// response E = E0 + EMAX·Ce^HILL / (EC50^HILL + Ce^HILL).
// States: CENTRAL (amount), EFFECT (Ce, a concentration). Outputs: DVID 1 is
// C = A/V, DVID 2 is the effect E.
#include "catalogue_models.h"

namespace pk {
namespace models {
namespace {

struct EffectEmax {
  template <typename T>
  void Rhs(const T* x, const T* p, T* dxdt) const {
    const T c = x[0] / p[1];
    dxdt[0] = -p[0] * c;
    dxdt[1] = p[2] * (c - x[1]);
  }
  template <typename T>
  T Output(int output, const T* x, const T* p) const {
    using std::pow;
    if (output != 2) return x[0] / p[1];
    // Integration error can leave Ce a hair below zero; Ce^HILL needs Ce ≥ 0.
    const T ce = x[1] > T(0.0) ? x[1] : T(0.0);
    const T ceh = pow(ce, p[6]);
    return p[3] + p[4] * ceh / (pow(p[5], p[6]) + ceh);
  }
};

}  // namespace

std::shared_ptr<const OdeModel> OneCmtIvEmax() {
  OdeModelSpec s;
  s.name = "1cmt_iv_emax";
  s.description = "one compartment with an effect compartment and a sigmoid Emax response (DVID 1: C, 2: E)";
  s.compartments = {"CENTRAL", "EFFECT"};
  s.parameters = {{"CL", 3.0}, {"V", 30.0}, {"KE0", 0.5}, {"E0", 10.0}, {"EMAX", 50.0}, {"EC50", 1.0}, {"HILL", 1.5}};
  s.signed_parameters = {"E0", "EMAX"};  // a baseline and an inhibitory or stimulatory maximum
  s.outputs = {"CP", "EFFECT"};
  return MakeOdeModel(s, EffectEmax());
}

}  // namespace models
}  // namespace pk
