// The hyper-dual number of pk/hyper_dual.h under its internal name (not installed).
#ifndef PK_SRC_HYPER_DUAL_NUMBER_H_
#define PK_SRC_HYPER_DUAL_NUMBER_H_

#include "pk/hyper_dual.h"

namespace pk {
namespace internal {

using HyperDualNumber = pk::HyperDual;

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_HYPER_DUAL_NUMBER_H_
