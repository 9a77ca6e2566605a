#include "serial_vector_ops.h"

#include <cmath>
#include <vector>

#include <nvector/nvector_serial.h>

namespace pk {
namespace internal {
namespace {

// Kernels over raw arrays; names follow the serial module's.
inline realtype* Data(N_Vector v) { return NV_DATA_S(v); }
inline sunindextype Length(N_Vector v) { return NV_LENGTH_S(v); }

void LinearSum(realtype a, N_Vector xv, realtype b, N_Vector yv, N_Vector zv) {
  const sunindextype n = Length(xv);
  const realtype* x = Data(xv);
  const realtype* y = Data(yv);
  realtype* z = Data(zv);
  // The serial module's cases, in its order: each rounds as it does.
  if (b == 1 && zv == yv) {  // y += a x
    realtype* w = Data(yv);
    if (a == 1) {
      for (sunindextype i = 0; i < n; ++i) w[i] += x[i];
    } else if (a == -1) {
      for (sunindextype i = 0; i < n; ++i) w[i] -= x[i];
    } else {
      for (sunindextype i = 0; i < n; ++i) w[i] += a * x[i];
    }
    return;
  }
  if (a == 1 && zv == xv) {  // x += b y
    realtype* w = Data(xv);
    if (b == 1) {
      for (sunindextype i = 0; i < n; ++i) w[i] += y[i];
    } else if (b == -1) {
      for (sunindextype i = 0; i < n; ++i) w[i] -= y[i];
    } else {
      for (sunindextype i = 0; i < n; ++i) w[i] += b * y[i];
    }
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
  std::vector<N_Vector> column(static_cast<size_t>(nsum));
  for (int j = 0; j < nvec; ++j) {
    for (int i = 0; i < nsum; ++i) column[i] = xv[i][j];
    LinearCombination(nsum, c, column.data(), zv[j]);
  }
  return 0;
}

}  // namespace

void UseFastSerialOps(N_Vector v) {
  N_Vector_Ops ops = v->ops;
  ops->nvlinearsum = LinearSum;
  ops->nvconst = Const;
  ops->nvprod = Prod;
  ops->nvdiv = Div;
  ops->nvscale = Scale;
  ops->nvabs = Abs;
  ops->nvinv = Inv;
  ops->nvaddconst = AddConst;
  ops->nvdotprod = DotProd;
  ops->nvmaxnorm = MaxNorm;
  ops->nvwrmsnorm = WrmsNorm;
  ops->nvwrmsnormmask = WrmsNormMask;
  ops->nvmin = Min;
  ops->nvwl2norm = WL2Norm;
  ops->nvl1norm = L1Norm;
  ops->nvcompare = Compare;
  ops->nvinvtest = InvTest;
  ops->nvlinearcombination = LinearCombination;
  ops->nvscaleaddmulti = ScaleAddMulti;
  ops->nvdotprodmulti = DotProdMulti;
  ops->nvlinearsumvectorarray = LinearSumVectorArray;
  ops->nvscalevectorarray = ScaleVectorArray;
  ops->nvconstvectorarray = ConstVectorArray;
  ops->nvwrmsnormvectorarray = WrmsNormVectorArray;
  ops->nvwrmsnormmaskvectorarray = WrmsNormMaskVectorArray;
  ops->nvscaleaddmultivectorarray = ScaleAddMultiVectorArray;
  ops->nvlinearcombinationvectorarray = LinearCombinationVectorArray;
}

}  // namespace internal
}  // namespace pk
