// 1cmt_oral_transit (MTT, KA, CL, V) with NTR transit compartments (Savic et
// al. 2007): a dose enters TR1 and passes TR1 → … → TR<NTR> → DEPOT at
// k_tr = (NTR+1)/MTT, so MTT is the mean time to reach the depot; the depot
// absorbs at KA into CENTRAL, cleared at CL/V. NTR is fixed, a model option:
// "1cmt_oral_transit:NTR=5" (default 3). The model is linear, so it runs
// through both the exact and the ODE propagator.
#include "catalogue_models.h"

#include <string>

namespace pk {
namespace models {

std::shared_ptr<const LinearModel> OneCmtOralTransit(int ntr) {
  enum { kMtt, kKa, kCl, kV };
  std::vector<std::string> states;
  for (int i = 1; i <= ntr; ++i) states.push_back("TR" + std::to_string(i));
  states.push_back("DEPOT");
  states.push_back("CENTRAL");
  const int depot = ntr, central = ntr + 1;
  std::vector<LinearTerm> a;
  const double stages = ntr + 1;
  for (int i = 0; i < ntr; ++i) {
    a.push_back({i, i, -stages, -1, kMtt});     // out of TR(i+1) at k_tr
    a.push_back({i + 1, i, stages, -1, kMtt});  // into the next one
  }
  a.push_back({depot, depot, -1.0, kKa, -1});
  a.push_back({central, depot, 1.0, kKa, -1});
  a.push_back({central, central, -1.0, kCl, kV});
  std::vector<std::vector<LinearTerm>> outputs(central + 1);
  for (int c = 0; c < central; ++c) outputs[c] = {{0, c, 1.0, -1, -1}};  // amounts
  outputs[central] = {{0, central, 1.0, -1, kV}};                        // A/V
  Eigen::VectorXd defaults(4);
  defaults << 1.0, 1.5, 3.0, 30.0;
  return LinearModel::FromTerms("1cmt_oral_transit", "one compartment, " + std::to_string(ntr) +
                                                         " transit compartments before first-order absorption",
                                states, {"MTT", "KA", "CL", "V"}, defaults, central + 1, 1, a, outputs);
}

}  // namespace models
}  // namespace pk
