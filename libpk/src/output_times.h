// Output records added to a subject, through reused storage (not installed).
#ifndef PK_SRC_OUTPUT_TIMES_H_
#define PK_SRC_OUTPUT_TIMES_H_

#include <string>
#include <vector>

#include "pk/dataset.h"

namespace pk {
namespace internal {

/// What pk::SubjectWithOutputTimes builds, kept between calls: a simulation of many subjects on one
/// thread reuses its records and their column vectors, and allocates nothing per row.
struct OutputTimesWorkspace {
  Dataset one;                  ///< the result: the subject alone, with its output records
  std::vector<Record> reduced;  ///< the subject's own records, with the kept columns only
  std::vector<int> kept;
  std::vector<double> sorted, scratch;
};

/// pk::SubjectWithOutputTimes into w->one.
void SubjectWithOutputTimes(const Dataset& data, int subject, const std::vector<double>& times,
                            const std::vector<std::string>& columns, OutputTimesWorkspace* w);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_OUTPUT_TIMES_H_
