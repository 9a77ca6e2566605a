#include "sundials_kernels.h"

#include <cmath>
#include <cstdlib>
#include <utility>
#include <vector>

#include <nvector/nvector_serial.h>
#include <sunlinsol/sunlinsol_dense.h>
#include <sunmatrix/sunmatrix_dense.h>

namespace pk {
namespace internal {
namespace {

// Kernels over raw arrays; names follow the serial module's.
inline realtype* Data(N_Vector v) { return NV_DATA_S(v); }
inline sunindextype Length(N_Vector v) { return NV_LENGTH_S(v); }

// w += c v, with the serial module's cases c = ±1.
void Axpy(sunindextype n, realtype c, const realtype* v, realtype* w) {
  if (c == 1) {
    for (sunindextype i = 0; i < n; ++i) w[i] += v[i];
  } else if (c == -1) {
    for (sunindextype i = 0; i < n; ++i) w[i] -= v[i];
  } else {
    for (sunindextype i = 0; i < n; ++i) w[i] += c * v[i];
  }
}

void LinearSum(realtype a, N_Vector xv, realtype b, N_Vector yv, N_Vector zv) {
  const sunindextype n = Length(xv);
  const realtype* x = Data(xv);
  const realtype* y = Data(yv);
  realtype* z = Data(zv);
  // The serial module's cases, in its order: each rounds as it does.
  if (b == 1 && zv == yv) {  // y += a x
    Axpy(n, a, x, Data(yv));
    return;
  }
  if (a == 1 && zv == xv) {  // x += b y
    Axpy(n, b, y, Data(xv));
    return;
  }
  if (a == 1 && b == 1) {
    for (sunindextype i = 0; i < n; ++i) z[i] = x[i] + y[i];
    return;
  }
  if ((a == 1 && b == -1) || (a == -1 && b == 1)) {
    const bool plus_x = a == 1;
    const realtype* v1 = plus_x ? y : x;
    const realtype* v2 = plus_x ? x : y;
    for (sunindextype i = 0; i < n; ++i) z[i] = v2[i] - v1[i];
    return;
  }
  if (a == 1 || b == 1) {  // z = c v1 + v2
    const bool unit_a = a == 1;
    const realtype c = unit_a ? b : a;
    const realtype* v1 = unit_a ? y : x;
    const realtype* v2 = unit_a ? x : y;
    for (sunindextype i = 0; i < n; ++i) z[i] = c * v1[i] + v2[i];
    return;
  }
  if (a == -1 || b == -1) {  // z = c v1 − v2
    const bool minus_a = a == -1;
    const realtype c = minus_a ? b : a;
    const realtype* v1 = minus_a ? y : x;
    const realtype* v2 = minus_a ? x : y;
    for (sunindextype i = 0; i < n; ++i) z[i] = c * v1[i] - v2[i];
    return;
  }
  if (a == b) {
    for (sunindextype i = 0; i < n; ++i) z[i] = a * (x[i] + y[i]);
    return;
  }
  if (a == -b) {
    for (sunindextype i = 0; i < n; ++i) z[i] = a * (x[i] - y[i]);
    return;
  }
  for (sunindextype i = 0; i < n; ++i) z[i] = a * x[i] + b * y[i];
}

void Const(realtype c, N_Vector zv) {
  const sunindextype n = Length(zv);
  realtype* z = Data(zv);
  for (sunindextype i = 0; i < n; ++i) z[i] = c;
}

void Prod(N_Vector xv, N_Vector yv, N_Vector zv) {
  const sunindextype n = Length(xv);
  const realtype *x = Data(xv), *y = Data(yv);
  realtype* z = Data(zv);
  for (sunindextype i = 0; i < n; ++i) z[i] = x[i] * y[i];
}

void Div(N_Vector xv, N_Vector yv, N_Vector zv) {
  const sunindextype n = Length(xv);
  const realtype *x = Data(xv), *y = Data(yv);
  realtype* z = Data(zv);
  for (sunindextype i = 0; i < n; ++i) z[i] = x[i] / y[i];
}

void Scale(realtype c, N_Vector xv, N_Vector zv) {
  const sunindextype n = Length(xv);
  const realtype* x = Data(xv);
  realtype* z = Data(zv);
  if (zv == xv) {
    for (sunindextype i = 0; i < n; ++i) z[i] *= c;
  } else if (c == 1) {
    for (sunindextype i = 0; i < n; ++i) z[i] = x[i];
  } else if (c == -1) {
    for (sunindextype i = 0; i < n; ++i) z[i] = -x[i];
  } else {
    for (sunindextype i = 0; i < n; ++i) z[i] = c * x[i];
  }
}

void Abs(N_Vector xv, N_Vector zv) {
  const sunindextype n = Length(xv);
  const realtype* x = Data(xv);
  realtype* z = Data(zv);
  for (sunindextype i = 0; i < n; ++i) z[i] = std::fabs(x[i]);
}

void Inv(N_Vector xv, N_Vector zv) {
  const sunindextype n = Length(xv);
  const realtype* x = Data(xv);
  realtype* z = Data(zv);
  for (sunindextype i = 0; i < n; ++i) z[i] = 1.0 / x[i];
}

void AddConst(N_Vector xv, realtype b, N_Vector zv) {
  const sunindextype n = Length(xv);
  const realtype* x = Data(xv);
  realtype* z = Data(zv);
  for (sunindextype i = 0; i < n; ++i) z[i] = x[i] + b;
}

realtype DotProd(N_Vector xv, N_Vector yv) {
  const sunindextype n = Length(xv);
  const realtype *x = Data(xv), *y = Data(yv);
  realtype sum = 0;
  for (sunindextype i = 0; i < n; ++i) sum += x[i] * y[i];
  return sum;
}

realtype MaxNorm(N_Vector xv) {
  const sunindextype n = Length(xv);
  const realtype* x = Data(xv);
  realtype m = 0;
  for (sunindextype i = 0; i < n; ++i) {
    if (std::fabs(x[i]) > m) m = std::fabs(x[i]);
  }
  return m;
}

realtype WSqrSum(N_Vector xv, N_Vector wv) {
  const sunindextype n = Length(xv);
  const realtype *x = Data(xv), *w = Data(wv);
  realtype sum = 0;
  for (sunindextype i = 0; i < n; ++i) {
    const realtype p = x[i] * w[i];
    sum += p * p;
  }
  return sum;
}

realtype Sqrt(realtype s) { return s <= 0 ? 0.0 : std::sqrt(s); }  // SUNRsqrt

realtype WrmsNorm(N_Vector xv, N_Vector wv) { return Sqrt(WSqrSum(xv, wv) / Length(xv)); }

realtype WrmsNormMask(N_Vector xv, N_Vector wv, N_Vector idv) {
  const sunindextype n = Length(xv);
  const realtype *x = Data(xv), *w = Data(wv), *id = Data(idv);
  realtype sum = 0;
  for (sunindextype i = 0; i < n; ++i) {
    if (id[i] > 0) {
      const realtype p = x[i] * w[i];
      sum += p * p;
    }
  }
  return Sqrt(sum / n);
}

realtype Min(N_Vector xv) {
  const sunindextype n = Length(xv);
  const realtype* x = Data(xv);
  realtype m = x[0];
  for (sunindextype i = 1; i < n; ++i) {
    if (x[i] < m) m = x[i];
  }
  return m;
}

realtype WL2Norm(N_Vector xv, N_Vector wv) { return Sqrt(WSqrSum(xv, wv)); }

realtype L1Norm(N_Vector xv) {
  const sunindextype n = Length(xv);
  const realtype* x = Data(xv);
  realtype sum = 0;
  for (sunindextype i = 0; i < n; ++i) sum += std::fabs(x[i]);
  return sum;
}

void Compare(realtype c, N_Vector xv, N_Vector zv) {
  const sunindextype n = Length(xv);
  const realtype* x = Data(xv);
  realtype* z = Data(zv);
  for (sunindextype i = 0; i < n; ++i) z[i] = std::fabs(x[i]) >= c ? 1.0 : 0.0;
}

booleantype InvTest(N_Vector xv, N_Vector zv) {
  const sunindextype n = Length(xv);
  const realtype* x = Data(xv);
  realtype* z = Data(zv);
  booleantype no_zero = SUNTRUE;
  for (sunindextype i = 0; i < n; ++i) {
    if (x[i] == 0) {
      no_zero = SUNFALSE;
    } else {
      z[i] = 1.0 / x[i];
    }
  }
  return no_zero;
}

// Fused and array operations. SUNDIALS's fallbacks chain N_VScale and
// N_VLinearSum (z = c₀x₀, then z = z + cᵢxᵢ); each element here is summed in
// the same order, so the results are the same to the bit.
int LinearCombination(int nvec, realtype* c, N_Vector* xv, N_Vector zv) {
  if (nvec == 1) {
    Scale(c[0], xv[0], zv);
    return 0;
  }
  const sunindextype n = Length(zv);
  realtype* z = Data(zv);
  for (sunindextype j = 0; j < n; ++j) {
    realtype s = c[0] * Data(xv[0])[j];
    for (int i = 1; i < nvec; ++i) s += c[i] * Data(xv[i])[j];
    z[j] = s;
  }
  return 0;
}

int ScaleAddMulti(int nvec, realtype* a, N_Vector xv, N_Vector* yv, N_Vector* zv) {
  for (int i = 0; i < nvec; ++i) LinearSum(a[i], xv, 1.0, yv[i], zv[i]);
  return 0;
}

int DotProdMulti(int nvec, N_Vector xv, N_Vector* yv, realtype* d) {
  for (int i = 0; i < nvec; ++i) d[i] = DotProd(xv, yv[i]);
  return 0;
}

int LinearSumVectorArray(int nvec, realtype a, N_Vector* xv, realtype b, N_Vector* yv, N_Vector* zv) {
  for (int i = 0; i < nvec; ++i) LinearSum(a, xv[i], b, yv[i], zv[i]);
  return 0;
}

int ScaleVectorArray(int nvec, realtype* c, N_Vector* xv, N_Vector* zv) {
  for (int i = 0; i < nvec; ++i) Scale(c[i], xv[i], zv[i]);
  return 0;
}

int ConstVectorArray(int nvec, realtype c, N_Vector* zv) {
  for (int i = 0; i < nvec; ++i) Const(c, zv[i]);
  return 0;
}

int WrmsNormVectorArray(int nvec, N_Vector* xv, N_Vector* wv, realtype* nrm) {
  for (int i = 0; i < nvec; ++i) nrm[i] = WrmsNorm(xv[i], wv[i]);
  return 0;
}

int WrmsNormMaskVectorArray(int nvec, N_Vector* xv, N_Vector* wv, N_Vector id, realtype* nrm) {
  for (int i = 0; i < nvec; ++i) nrm[i] = WrmsNormMask(xv[i], wv[i], id);
  return 0;
}

int ScaleAddMultiVectorArray(int nvec, int nsum, realtype* a, N_Vector* xv, N_Vector** yv, N_Vector** zv) {
  for (int j = 0; j < nvec; ++j) {
    for (int i = 0; i < nsum; ++i) LinearSum(a[i], xv[j], 1.0, yv[i][j], zv[i][j]);
  }
  return 0;
}

int LinearCombinationVectorArray(int nvec, int nsum, realtype* c, N_Vector** xv, N_Vector* zv) {
  // CVODES sums at most q + 1 ≤ 6 Nordsieck columns: no allocation then.
  N_Vector small[8];
  std::vector<N_Vector> large(nsum > 8 ? static_cast<size_t>(nsum) : 0);
  N_Vector* column = nsum > 8 ? large.data() : small;
  for (int j = 0; j < nvec; ++j) {
    for (int i = 0; i < nsum; ++i) column[i] = xv[i][j];
    LinearCombination(nsum, c, column, zv[j]);
  }
  return 0;
}

// Dense matrices (column-major, cols[j] points at column j).
int MatZero(SUNMatrix a) {
  realtype* d = SM_DATA_D(a);
  for (sunindextype i = 0; i < SM_LDATA_D(a); ++i) d[i] = 0;
  return SUNMAT_SUCCESS;
}

int MatCopy(SUNMatrix a, SUNMatrix b) {
  if (SM_ROWS_D(a) != SM_ROWS_D(b) || SM_COLUMNS_D(a) != SM_COLUMNS_D(b)) return SUNMAT_ILL_INPUT;
  const realtype* s = SM_DATA_D(a);
  realtype* d = SM_DATA_D(b);
  for (sunindextype i = 0; i < SM_LDATA_D(a); ++i) d[i] = s[i];
  return SUNMAT_SUCCESS;
}

int MatScaleAddI(realtype c, SUNMatrix a) {  // A ← cA + I
  for (sunindextype j = 0; j < SM_COLUMNS_D(a); ++j) {
    realtype* col = SM_COLUMN_D(a, j);
    for (sunindextype i = 0; i < SM_ROWS_D(a); ++i) col[i] *= c;
    if (j < SM_ROWS_D(a)) col[j] += 1;
  }
  return SUNMAT_SUCCESS;
}

SUNMatrix MatClone(SUNMatrix a) {
  SUNMatrix b = SUNDenseMatrix(SM_ROWS_D(a), SM_COLUMNS_D(a), a->sunctx);
  if (b) UseFastDenseOps(b);
  return b;
}

// SUNDlsMat_denseGETRF: LU with partial pivoting, in place, one column at a
// time; returns k+1 for a zero pivot in column k, else 0.
sunindextype Getrf(realtype** a, sunindextype m, sunindextype n, sunindextype* p) {
  for (sunindextype k = 0; k < n; ++k) {
    realtype* col_k = a[k];
    sunindextype l = k;
    for (sunindextype i = k + 1; i < m; ++i) {
      if (std::fabs(col_k[i]) > std::fabs(col_k[l])) l = i;
    }
    p[k] = l;
    if (col_k[l] == 0) return k + 1;
    if (l != k) {
      for (sunindextype j = 0; j < n; ++j) std::swap(a[j][l], a[j][k]);
    }
    const realtype mult = 1.0 / col_k[k];
    for (sunindextype i = k + 1; i < m; ++i) col_k[i] *= mult;
    for (sunindextype j = k + 1; j < n; ++j) {
      realtype* col_j = a[j];
      const realtype a_kj = col_j[k];
      if (a_kj != 0) {
        for (sunindextype i = k + 1; i < m; ++i) col_j[i] -= a_kj * col_k[i];
      }
    }
  }
  return 0;
}

// SUNDlsMat_denseGETRS: b ← A⁻¹b from Getrf's factors.
void Getrs(realtype** a, sunindextype n, const sunindextype* p, realtype* b) {
  for (sunindextype k = 0; k < n; ++k) {
    if (p[k] != k) std::swap(b[k], b[p[k]]);
  }
  for (sunindextype k = 0; k < n - 1; ++k) {
    const realtype* col_k = a[k];
    for (sunindextype i = k + 1; i < n; ++i) b[i] -= col_k[i] * b[k];
  }
  for (sunindextype k = n - 1; k > 0; --k) {
    const realtype* col_k = a[k];
    b[k] /= col_k[k];
    for (sunindextype i = 0; i < k; ++i) b[i] -= col_k[i] * b[k];
  }
  b[0] /= a[0][0];
}

SUNLinearSolverContent_Dense DenseContent(SUNLinearSolver s) {
  return static_cast<SUNLinearSolverContent_Dense>(s->content);
}

int DenseSetup(SUNLinearSolver s, SUNMatrix a) {
  if (a == nullptr || SUNMatGetID(a) != SUNMATRIX_DENSE) return SUNLS_ILL_INPUT;
  SUNLinearSolverContent_Dense c = DenseContent(s);
  c->last_flag = Getrf(SM_COLS_D(a), SM_ROWS_D(a), SM_COLUMNS_D(a), c->pivots);
  return c->last_flag > 0 ? SUNLS_LUFACT_FAIL : SUNLS_SUCCESS;
}

int DenseSolve(SUNLinearSolver s, SUNMatrix a, N_Vector x, N_Vector b, realtype) {
  if (a == nullptr || x == nullptr || b == nullptr) return SUNLS_MEM_NULL;
  Scale(1.0, b, x);
  SUNLinearSolverContent_Dense c = DenseContent(s);
  Getrs(SM_COLS_D(a), SM_ROWS_D(a), c->pivots, NV_DATA_S(x));
  c->last_flag = SUNLS_SUCCESS;
  return SUNLS_SUCCESS;
}

// Clones share their source's operation table (SUNDIALS gives every vector a
// copy of its own, about 0.4 kB; CVODES's adjoint memories hold two vectors per
// stored step). The table is libpk's, made once, and is never freed.
void Destroy(N_Vector v) {
  if (v == nullptr) return;
  if (v->content != nullptr) {
    N_VectorContent_Serial c = NV_CONTENT_S(v);
    if (c->own_data && c->data != nullptr) std::free(c->data);
    std::free(c);
  }
  std::free(v);
}

N_Vector CloneEmpty(N_Vector w) {
  if (w == nullptr) return nullptr;
  N_Vector v = static_cast<N_Vector>(std::malloc(sizeof(*v)));
  N_VectorContent_Serial c = static_cast<N_VectorContent_Serial>(std::malloc(sizeof(*c)));
  if (v == nullptr || c == nullptr) {
    std::free(v);
    std::free(c);
    return nullptr;
  }
  c->length = NV_LENGTH_S(w);
  c->own_data = SUNFALSE;
  c->data = nullptr;
  v->content = c;
  v->ops = w->ops;
  v->sunctx = w->sunctx;
  return v;
}

N_Vector Clone(N_Vector w) {
  N_Vector v = CloneEmpty(w);
  if (v == nullptr || NV_LENGTH_S(w) <= 0) return v;
  realtype* data = static_cast<realtype*>(std::malloc(static_cast<size_t>(NV_LENGTH_S(w)) * sizeof(realtype)));
  if (data == nullptr) {
    Destroy(v);
    return nullptr;
  }
  NV_DATA_S(v) = data;
  NV_OWN_DATA_S(v) = SUNTRUE;
  return v;
}

// libpk's table: SUNDIALS's serial operations with the kernels above.
N_Vector_Ops SharedTable(N_Vector_Ops serial) {
  static _generic_N_Vector_Ops table = [serial] {
    _generic_N_Vector_Ops t = *serial;
    t.nvclone = Clone;
    t.nvcloneempty = CloneEmpty;
    t.nvdestroy = Destroy;
    t.nvlinearsum = LinearSum;
    t.nvconst = Const;
    t.nvprod = Prod;
    t.nvdiv = Div;
    t.nvscale = Scale;
    t.nvabs = Abs;
    t.nvinv = Inv;
    t.nvaddconst = AddConst;
    t.nvdotprod = DotProd;
    t.nvmaxnorm = MaxNorm;
    t.nvwrmsnorm = WrmsNorm;
    t.nvwrmsnormmask = WrmsNormMask;
    t.nvmin = Min;
    t.nvwl2norm = WL2Norm;
    t.nvl1norm = L1Norm;
    t.nvcompare = Compare;
    t.nvinvtest = InvTest;
    t.nvlinearcombination = LinearCombination;
    t.nvscaleaddmulti = ScaleAddMulti;
    t.nvdotprodmulti = DotProdMulti;
    t.nvlinearsumvectorarray = LinearSumVectorArray;
    t.nvscalevectorarray = ScaleVectorArray;
    t.nvconstvectorarray = ConstVectorArray;
    t.nvwrmsnormvectorarray = WrmsNormVectorArray;
    t.nvwrmsnormmaskvectorarray = WrmsNormMaskVectorArray;
    t.nvscaleaddmultivectorarray = ScaleAddMultiVectorArray;
    t.nvlinearcombinationvectorarray = LinearCombinationVectorArray;
    return t;
  }();
  return &table;
}

}  // namespace

void UseFastDenseOps(SUNMatrix a) {
  a->ops->zero = MatZero;
  a->ops->copy = MatCopy;
  a->ops->scaleaddi = MatScaleAddI;
  a->ops->clone = MatClone;
}

void UseFastDenseSolver(SUNLinearSolver ls) {
  ls->ops->setup = DenseSetup;
  ls->ops->solve = DenseSolve;
}

void UseFastSerialOps(N_Vector v) {
  N_Vector_Ops own = v->ops;
  if (own == SharedTable(own)) return;
  v->ops = SharedTable(own);
  std::free(own);  // N_VNewEmpty's copy, malloc'ed
}

}  // namespace internal
}  // namespace pk
