// SUNDIALS's serial-vector and dense-matrix kernels, compiled with libpk
// (not installed).
//
// Debian 12's SUNDIALS 6.4 is built without optimisation: its serial vector
// kernels (N_VLinearSum_Serial, N_VWrmsNorm_Serial, …) and its dense LU
// (SUNDlsMat_denseGETRF/GETRS) run as -O0 code, and they are most of every
// CVODES integration's instructions. libpk keeps SUNDIALS's objects (the same
// content, so N_VGetArrayPointer, SUNDenseMatrix_Data and the NV_*/SM_*
// macros still apply) but points their operation tables at kernels compiled
// with libpk. Each kernel computes exactly what SUNDIALS's computes, with the
// same special cases and order of operations, so results do not change in the
// last bit. CVODES clones its work vectors and matrices from the ones it is
// given: libpk's vector clone gives the clone the same table (one table for
// all, where SUNDIALS copies it into every vector), and the matrix clone is
// replaced so that its clones are patched too.
#ifndef PK_SRC_ODE_SUNDIALS_KERNELS_H_
#define PK_SRC_ODE_SUNDIALS_KERNELS_H_

#include <sundials/sundials_linearsolver.h>
#include <sundials/sundials_matrix.h>
#include <sundials/sundials_nvector.h>

namespace pk {
namespace internal {

/// Points serial vector `v` (from N_VNew_Serial) at libpk's table of kernels,
/// shared by all its clones; `v`'s own copy of SUNDIALS's table is freed.
void UseFastSerialOps(N_Vector v);
/// Replaces the kernels of dense matrix `a` (from SUNDenseMatrix) and of its clones.
void UseFastDenseOps(SUNMatrix a);
/// Replaces the LU factorisation and solve of `ls` (from SUNLinSol_Dense).
void UseFastDenseSolver(SUNLinearSolver ls);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_ODE_SUNDIALS_KERNELS_H_
