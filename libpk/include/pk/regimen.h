// libpk: dosing regimens built in code rather than read from a file.
//
// A Regimen is turned into an ordinary NONMEM-style Dataset, so that it goes
// through exactly the same event semantics as a data file.
#ifndef PK_REGIMEN_H_
#define PK_REGIMEN_H_

#include <vector>

#include "pk/dataset.h"

namespace pk {

/// One dose record.
struct Dose {
  double time = 0;
  double amount = 0;
  int cmt = 0;          ///< 1-based; 0 = the model's default dose compartment
  double rate = 0;      ///< infusion rate (0 = bolus); -1/-2 as in NONMEM's RATE
  double duration = 0;  ///< alternative to `rate`: infusion duration (rate = amount/duration)
  double ii = 0;        ///< interdose interval for `addl` and `ss`
  int addl = 0;         ///< additional doses every `ii`
  int ss = 0;           ///< 0, 1 or 2, as in NONMEM's SS
};

struct Regimen {
  double id = 1;
  std::vector<Dose> doses;
  std::vector<double> times;  ///< output times (EVID 2 records)
};

/// The regimen as a one-subject dataset. Output records at the same time as a
/// dose come after it (they see the post-dose state). Records are numbered as
/// the lines of a file holding them under a header (2, 3, ...). Throws
/// pk::InputError for a dose that no dataset record could hold (CheckRecord,
/// pk/dataset.h).
Dataset RegimenToDataset(const Regimen& regimen);

/// Adds an EVID 2 record at each of `times` to every subject of `data`. An added
/// record sits after the records of the same time and takes its other columns
/// (covariates, time-varying parameters) from the next record, so the value in
/// force over each interval is unchanged. Added records have Record::line = -1.
/// A reset record (EVID 3/4) whose TIME goes back starts a new time axis (a
/// period of a crossover, say): the first axis gets every time, those after
/// its last record placed before the reset; each later axis gets the times at
/// or after its first record again.
Dataset AddOutputTimes(const Dataset& data, const std::vector<double>& times);

/// Subject `subject` of `data` alone, with output records at `times` as AddOutputTimes adds
/// them, keeping of the non-PREDPP columns only those named in `columns` (those present; for a
/// simulation, the model's parameter and modifier names and DVID).
Dataset SubjectWithOutputTimes(const Dataset& data, int subject, const std::vector<double>& times,
                               const std::vector<std::string>& columns);

}  // namespace pk

#endif  // PK_REGIMEN_H_
