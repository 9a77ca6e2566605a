// A numerical failure of one evaluation (not installed): reported through a
// result or summary, never a crash.
#ifndef PK_SRC_NUMERICAL_FAILURE_H_
#define PK_SRC_NUMERICAL_FAILURE_H_

#include <stdexcept>

namespace pk {
namespace internal {

class NumericalFailure : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_NUMERICAL_FAILURE_H_
