// libpk: exposure metrics of a simulation (Cmax, Tmax, Cmin, trough, AUC).
//
// A dosing interval runs from one dose entering the system to the next (the
// last one to the last output time). AUC is exact (an integral state of the
// simulation). Cmax, Tmax and Cmin are taken over the output times and the
// interval's ends, so a finer output grid resolves them better; the trough is
// the concentration just before the next dose.
#ifndef PK_EXPOSURE_H_
#define PK_EXPOSURE_H_

#include <vector>

#include "pk/simulate.h"

namespace pk {

struct IntervalExposure {
  int index = 0;  ///< 1-based dosing interval
  double start = 0;
  double end = 0;
  double cmax = 0;
  double tmax = 0;
  double cmin = 0;
  double ctrough = 0;  ///< concentration at the end of the interval, before the next dose
  double auc = 0;
};

struct Exposure {
  double id = 0;
  double cmax = 0;
  double tmax = 0;
  double cmin = 0;     ///< over the whole simulation from the first dose
  double auc = 0;      ///< from the first record to the last output time
  std::vector<IntervalExposure> intervals;
};

Exposure ComputeExposure(const SubjectSimulation& simulation);

}  // namespace pk

#endif  // PK_EXPOSURE_H_
