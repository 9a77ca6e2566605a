// Optimised operations for SUNDIALS serial vectors (not installed).
//
// Debian 12's SUNDIALS 6.4 is built without optimisation: its serial vector
// kernels (N_VLinearSum_Serial, N_VWrmsNorm_Serial, …) run as -O0 code, and
// they are about half of every CVODES integration's instructions. libpk keeps
// SUNDIALS's serial vectors (the same content, so N_VGetArrayPointer and the
// NV_* macros still apply) but points their operation table at kernels compiled
// with libpk. Each kernel computes exactly what the serial one computes, with
// the same special cases and order of operations, so results do not change in
// the last bit. CVODES clones its work vectors from the vectors it is given,
// and clones copy the table, so patching the vectors libpk creates suffices.
#ifndef PK_SRC_ODE_SERIAL_VECTOR_OPS_H_
#define PK_SRC_ODE_SERIAL_VECTOR_OPS_H_

#include <sundials/sundials_nvector.h>

namespace pk {
namespace internal {

/// Replaces the kernels of serial vector `v` (from N_VNew_Serial) with libpk's.
void UseFastSerialOps(N_Vector v);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_ODE_SERIAL_VECTOR_OPS_H_
