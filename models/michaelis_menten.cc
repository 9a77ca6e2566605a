// Saturable (Michaelis–Menten) elimination: the rate out of the central
// compartment is VMAX·C/(KM + C), C = A_central/V, VMAX in amount per time and
// KM in concentration.
//   1cmt_iv_mm   (VMAX, KM, V)
//   1cmt_oral_mm (KA, VMAX, KM, V)          depot 1, central 2
//   2cmt_iv_mm   (VMAX, KM, V1, Q, V2)      central 1, peripheral 2
#include "catalogue_models.h"

namespace pk {
namespace models {
namespace {

template <typename T>
T Saturable(const T& vmax, const T& km, const T& c) {
  return vmax * c / (km + c);
}

struct OneCmtIvMmRhs {
  template <typename T>
  void Rhs(const T* x, const T* p, T* dxdt) const {
    dxdt[0] = -Saturable(p[0], p[1], x[0] / p[2]);
  }
  template <typename T>
  T Output(int /*output*/, const T* x, const T* p) const { return x[0] / p[2]; }
};

struct OneCmtOralMmRhs {
  template <typename T>
  void Rhs(const T* x, const T* p, T* dxdt) const {
    const T absorption = p[0] * x[0];
    dxdt[0] = -absorption;
    dxdt[1] = absorption - Saturable(p[1], p[2], x[1] / p[3]);
  }
  template <typename T>
  T Output(int /*output*/, const T* x, const T* p) const { return x[1] / p[3]; }
};

struct TwoCmtIvMmRhs {
  template <typename T>
  void Rhs(const T* x, const T* p, T* dxdt) const {
    const T c1 = x[0] / p[2], c2 = x[1] / p[4];
    const T distribution = p[3] * (c1 - c2);
    dxdt[0] = -Saturable(p[0], p[1], c1) - distribution;
    dxdt[1] = distribution;
  }
  template <typename T>
  T Output(int /*output*/, const T* x, const T* p) const { return x[0] / p[2]; }
};

}  // namespace

std::shared_ptr<const OdeModel> OneCmtIvMm() {
  OdeModelSpec s;
  s.name = "1cmt_iv_mm";
  s.description = "one compartment, Michaelis-Menten elimination";
  s.compartments = {"CENTRAL"};
  s.parameters = {{"VMAX", 20.0}, {"KM", 2.0}, {"V", 30.0}};
  s.initial_structure = {InitialStructure::Kind::kMammillary, 1, false, {"CL", "V"}, "VMAX", "KM"};
  return MakeOdeModel(s, OneCmtIvMmRhs());
}

std::shared_ptr<const OdeModel> OneCmtOralMm() {
  OdeModelSpec s;
  s.name = "1cmt_oral_mm";
  s.description = "one compartment, first-order absorption, Michaelis-Menten elimination";
  s.compartments = {"DEPOT", "CENTRAL"};
  s.parameters = {{"KA", 1.5}, {"VMAX", 20.0}, {"KM", 2.0}, {"V", 30.0}};
  s.central = 2;
  s.default_dose = 1;
  s.initial_structure = {InitialStructure::Kind::kMammillary, 1, true, {"KA", "CL", "V"}, "VMAX", "KM"};
  return MakeOdeModel(s, OneCmtOralMmRhs());
}

std::shared_ptr<const OdeModel> TwoCmtIvMm() {
  OdeModelSpec s;
  s.name = "2cmt_iv_mm";
  s.description = "two compartments, Michaelis-Menten elimination from the central one";
  s.compartments = {"CENTRAL", "PERIPHERAL"};
  s.parameters = {{"VMAX", 20.0}, {"KM", 2.0}, {"V1", 20.0}, {"Q", 5.0}, {"V2", 40.0}};
  s.initial_structure = {InitialStructure::Kind::kMammillary, 2, false, {"CL", "V1", "Q", "V2"}, "VMAX", "KM"};
  return MakeOdeModel(s, TwoCmtIvMmRhs());
}

}  // namespace models
}  // namespace pk
