// libpk's kernels for SUNDIALS serial vectors (src/ode/sundials_kernels.h)
// against SUNDIALS's own: every operation CVODES may call, with the special
// coefficients and aliasings the serial module treats apart, must give the
// same numbers to the bit (CVODES's results must not change with them).
#include <cmath>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include <catch2/catch.hpp>
#include <nvector/nvector_serial.h>
#include <sunlinsol/sunlinsol_dense.h>
#include <sunmatrix/sunmatrix_dense.h>

#include "ode/sundials_kernels.h"

namespace {

// A set of k vectors of length n from SUNDIALS, and a copy whose kernels are libpk's.
struct Pair {
  SUNContext ctx = nullptr;
  std::vector<N_Vector> ref, fast;
  Pair(int n, int k, unsigned seed) {
    SUNContext_Create(nullptr, &ctx);
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(-3, 3);
    for (int i = 0; i < k; ++i) {
      ref.push_back(N_VNew_Serial(n, ctx));
      fast.push_back(N_VNew_Serial(n, ctx));
      pk::internal::UseFastSerialOps(fast.back());
      for (int j = 0; j < n; ++j) {
        // Some exact zeros (InvTest) and ones (Compare's threshold).
        const double v = j % 5 == 3 ? 0.0 : j % 7 == 2 ? 1.0 : u(rng);
        NV_Ith_S(ref.back(), j) = v;
        NV_Ith_S(fast.back(), j) = v;
      }
    }
  }
  ~Pair() {
    for (N_Vector v : ref) N_VDestroy(v);
    for (N_Vector v : fast) N_VDestroy(v);
    SUNContext_Free(&ctx);
  }
  // Every vector of the set equal to the bit (0/0 is NaN in both).
  bool Same() const {
    for (size_t i = 0; i < ref.size(); ++i) {
      for (sunindextype j = 0; j < NV_LENGTH_S(ref[i]); ++j) {
        const double a = NV_Ith_S(ref[i], j), b = NV_Ith_S(fast[i], j);
        if (a != b && !(std::isnan(a) && std::isnan(b))) return false;
      }
    }
    return true;
  }
};

}  // namespace

TEST_CASE("libpk's serial vector kernels compute what SUNDIALS's compute, to the bit", "[ode][nvector]") {
  const double c = 0.37, d = -2.6;
  // (a, b) pairs that select each case of N_VLinearSum_Serial.
  const std::vector<std::pair<double, double>> coefficients = {{1, 1},  {1, -1}, {-1, 1}, {1, c},  {c, 1},
                                                               {-1, c}, {c, -1}, {c, c},  {c, -c}, {c, d}};
  for (int n : {1, 3, 17}) {
    CAPTURE(n);
    using Op = std::function<void(const std::vector<N_Vector>&)>;
    const std::vector<std::pair<std::string, Op>> ops = [&] {
      std::vector<std::pair<std::string, Op>> o;
      for (const auto& ab : coefficients) {
        const std::string s = "(" + std::to_string(ab.first) + ", " + std::to_string(ab.second) + ")";
        o.push_back({"LinearSum z " + s, [=](const std::vector<N_Vector>& v) { N_VLinearSum(ab.first, v[0], ab.second, v[1], v[2]); }});
        o.push_back({"LinearSum z=x " + s, [=](const std::vector<N_Vector>& v) { N_VLinearSum(ab.first, v[0], ab.second, v[1], v[0]); }});
        o.push_back({"LinearSum z=y " + s, [=](const std::vector<N_Vector>& v) { N_VLinearSum(ab.first, v[0], ab.second, v[1], v[1]); }});
      }
      for (double k : {1.0, -1.0, c}) {
        o.push_back({"Scale " + std::to_string(k), [=](const std::vector<N_Vector>& v) { N_VScale(k, v[0], v[2]); }});
        o.push_back({"Scale z=x " + std::to_string(k), [=](const std::vector<N_Vector>& v) { N_VScale(k, v[0], v[0]); }});
      }
      o.push_back({"Const", [=](const std::vector<N_Vector>& v) { N_VConst(c, v[2]); }});
      o.push_back({"Prod", [](const std::vector<N_Vector>& v) { N_VProd(v[0], v[1], v[2]); }});
      o.push_back({"Div", [](const std::vector<N_Vector>& v) { N_VDiv(v[0], v[3], v[2]); }});
      o.push_back({"Abs", [](const std::vector<N_Vector>& v) { N_VAbs(v[0], v[2]); }});
      o.push_back({"Inv", [](const std::vector<N_Vector>& v) { N_VInv(v[3], v[2]); }});
      o.push_back({"AddConst", [=](const std::vector<N_Vector>& v) { N_VAddConst(v[0], d, v[2]); }});
      o.push_back({"Compare", [](const std::vector<N_Vector>& v) { N_VCompare(1.0, v[0], v[2]); }});
      o.push_back({"InvTest", [](const std::vector<N_Vector>& v) { NV_Ith_S(v[2], 0) = N_VInvTest(v[0], v[2]); }});
      o.push_back({"norms", [](const std::vector<N_Vector>& v) {
                     double* z = NV_DATA_S(v[2]);
                     z[0] = N_VDotProd(v[0], v[1]);
                     if (NV_LENGTH_S(v[2]) < 3) return;
                     z[1] = N_VMaxNorm(v[0]);
                     z[2] = N_VWrmsNorm(v[0], v[1]);
                     N_VAbs(v[1], v[4]);  // a mask with zeros and positives
                     z[0] += N_VWrmsNormMask(v[0], v[1], v[4]);
                     z[1] += N_VMin(v[0]) + N_VWL2Norm(v[0], v[1]) + N_VL1Norm(v[1]);
                   }});
      const double cs[4] = {c, 1.0, -1.0, d};
      for (int k : {1, 2, 4}) {
        o.push_back({"LinearCombination " + std::to_string(k), [=](const std::vector<N_Vector>& v) {
                       double cc[4] = {cs[0], cs[1], cs[2], cs[3]};
                       N_Vector x[4] = {v[0], v[1], v[3], v[4]};
                       N_VLinearCombination(k, cc, x, v[2]);
                     }});
        o.push_back({"LinearCombination z=x0 " + std::to_string(k), [=](const std::vector<N_Vector>& v) {
                       double cc[4] = {cs[0], cs[1], cs[2], cs[3]};
                       N_Vector x[4] = {v[2], v[1], v[3], v[4]};
                       N_VLinearCombination(k, cc, x, v[2]);
                     }});
      }
      o.push_back({"ScaleAddMulti", [=](const std::vector<N_Vector>& v) {
                     double a[3] = {c, 1.0, -1.0};
                     N_Vector y[3] = {v[1], v[3], v[4]};
                     N_Vector z[3] = {v[2], v[3], v[5]};  // Z₁ = Y₁ (in place)
                     N_VScaleAddMulti(3, a, v[0], y, z);
                   }});
      o.push_back({"DotProdMulti", [](const std::vector<N_Vector>& v) {
                     N_Vector y[2] = {v[1], v[3]};
                     double dots[2];
                     N_VDotProdMulti(2, v[0], y, dots);
                     NV_Ith_S(v[2], 0) = dots[0] + dots[1];
                   }});
      o.push_back({"vector arrays", [=](const std::vector<N_Vector>& v) {
                     N_Vector x[2] = {v[0], v[1]}, y[2] = {v[3], v[4]}, z[2] = {v[2], v[5]};
                     N_VLinearSumVectorArray(2, c, x, d, y, z);
                     double k[2] = {d, c};
                     N_VScaleVectorArray(2, k, z, y);
                     double nrm[2];
                     N_VWrmsNormVectorArray(2, x, y, nrm);
                     N_VConstVectorArray(1, nrm[0] + nrm[1], z);
                     N_VWrmsNormMaskVectorArray(2, x, y, v[1], nrm);
                     NV_Ith_S(v[5], 0) = nrm[0] - nrm[1];
                   }});
      o.push_back({"multi vector arrays", [=](const std::vector<N_Vector>& v) {
                     double a[2] = {c, -1.0};
                     N_Vector x[2] = {v[0], v[1]};
                     N_Vector y0[2] = {v[3], v[4]}, y1[2] = {v[5], v[6]};
                     N_Vector z0[2] = {v[2], v[4]}, z1[2] = {v[7], v[6]};
                     N_Vector* y[2] = {y0, y1};
                     N_Vector* z[2] = {z0, z1};
                     N_VScaleAddMultiVectorArray(2, 2, a, x, y, z);
                     double cc[3] = {d, 1.0, c};
                     N_Vector w0[2] = {v[0], v[1]}, w1[2] = {v[2], v[3]}, w2[2] = {v[4], v[5]};
                     N_Vector* w[3] = {w0, w1, w2};
                     N_Vector out[2] = {v[6], v[7]};
                     N_VLinearCombinationVectorArray(2, 3, cc, w, out);
                   }});
      // More than the 8 columns libpk's kernel keeps on the stack.
      o.push_back({"LinearCombinationVectorArray 10", [=](const std::vector<N_Vector>& v) {
                     double cc[10];
                     N_Vector columns[10][1];
                     N_Vector* w[10];
                     for (int i = 0; i < 10; ++i) {
                       cc[i] = i % 3 == 0 ? 1.0 : c * (i - 4);
                       columns[i][0] = v[static_cast<size_t>(i % 7)];
                       w[i] = columns[i];
                     }
                     N_Vector out[1] = {v[7]};
                     N_VLinearCombinationVectorArray(1, 10, cc, w, out);
                   }});
      return o;
    }();
    for (const auto& op : ops) {
      CAPTURE(op.first);
      Pair p(n, 8, 1234u + static_cast<unsigned>(n));
      op.second(p.ref);
      op.second(p.fast);
      CHECK(p.Same());
    }
  }
}

TEST_CASE("libpk's dense LU and matrix kernels compute what SUNDIALS's compute, to the bit", "[ode][nvector]") {
  SUNContext ctx = nullptr;
  SUNContext_Create(nullptr, &ctx);
  std::mt19937 rng(99);
  std::uniform_real_distribution<double> u(-2, 2);
  for (int n : {1, 2, 5, 12}) {
    for (bool singular : {false, true}) {
      CAPTURE(n, singular);
      // M = I − γJ as CVODES forms it: J copied from a saved copy, scaled, plus I.
      SUNMatrix j_ref = SUNDenseMatrix(n, n, ctx), j_fast = SUNDenseMatrix(n, n, ctx);
      pk::internal::UseFastDenseOps(j_fast);
      for (int c = 0; c < n; ++c) {
        for (int r = 0; r < n; ++r) {
          // Rows that swap under pivoting, a zero entry, and (singular) a zero column.
          const double v = singular && c == n / 2 ? 0.0 : (r + 2 * c) % 4 == 1 ? 0.0 : u(rng);
          SM_ELEMENT_D(j_ref, r, c) = v;
          SM_ELEMENT_D(j_fast, r, c) = v;
        }
      }
      SUNMatrix saved_ref = SUNMatClone(j_ref), saved_fast = SUNMatClone(j_fast);
      CHECK(saved_fast->ops->copy == j_fast->ops->copy);  // clones carry libpk's kernels
      CHECK(saved_ref->ops->copy != j_fast->ops->copy);
      REQUIRE(SUNMatCopy(j_ref, saved_ref) == 0);
      REQUIRE(SUNMatCopy(j_fast, saved_fast) == 0);
      REQUIRE(SUNMatZero(j_ref) == 0);
      REQUIRE(SUNMatZero(j_fast) == 0);
      REQUIRE(SUNMatCopy(saved_ref, j_ref) == 0);
      REQUIRE(SUNMatCopy(saved_fast, j_fast) == 0);
      const double gamma = singular ? 0.0 : -0.73;  // γ = 0 keeps J itself, singular
      if (!singular) {
        REQUIRE(SUNMatScaleAddI(gamma, j_ref) == 0);
        REQUIRE(SUNMatScaleAddI(gamma, j_fast) == 0);
      }
      N_Vector y = N_VNew_Serial(n, ctx);
      SUNLinearSolver ls_ref = SUNLinSol_Dense(y, j_ref, ctx), ls_fast = SUNLinSol_Dense(y, j_fast, ctx);
      pk::internal::UseFastDenseSolver(ls_fast);
      const int flag_ref = SUNLinSolSetup(ls_ref, j_ref), flag_fast = SUNLinSolSetup(ls_fast, j_fast);
      CHECK(flag_ref == flag_fast);
      CHECK(SUNLinSolLastFlag(ls_ref) == SUNLinSolLastFlag(ls_fast));
      bool same = true;
      for (int k = 0; k < n * n; ++k) same = same && SM_DATA_D(j_ref)[k] == SM_DATA_D(j_fast)[k];
      // After a zero pivot in column k (flag k+1) only pivots 0…k are set.
      const long set = SUNLinSolLastFlag(ls_ref) > 0 ? SUNLinSolLastFlag(ls_ref) : n;
      for (int k = 0; k < set; ++k) {
        same = same && static_cast<SUNLinearSolverContent_Dense>(ls_ref->content)->pivots[k] ==
                           static_cast<SUNLinearSolverContent_Dense>(ls_fast->content)->pivots[k];
      }
      CHECK(same);
      if (!singular) {
        CHECK(flag_ref == SUNLS_SUCCESS);
        N_Vector b = N_VNew_Serial(n, ctx), x_ref = N_VNew_Serial(n, ctx), x_fast = N_VNew_Serial(n, ctx);
        for (int k = 0; k < n; ++k) NV_Ith_S(b, k) = u(rng);
        REQUIRE(SUNLinSolSolve(ls_ref, j_ref, x_ref, b, 0.0) == SUNLS_SUCCESS);
        REQUIRE(SUNLinSolSolve(ls_fast, j_fast, x_fast, b, 0.0) == SUNLS_SUCCESS);
        bool equal = true;
        for (int k = 0; k < n; ++k) equal = equal && NV_Ith_S(x_ref, k) == NV_Ith_S(x_fast, k);
        CHECK(equal);
        N_VDestroy(b);
        N_VDestroy(x_ref);
        N_VDestroy(x_fast);
      } else {
        CHECK(flag_ref == SUNLS_LUFACT_FAIL);
      }
      SUNLinSolFree(ls_ref);
      SUNLinSolFree(ls_fast);
      N_VDestroy(y);
      for (SUNMatrix m : {j_ref, j_fast, saved_ref, saved_fast}) SUNMatDestroy(m);
    }
  }
  SUNContext_Free(&ctx);
}

TEST_CASE("vectors with libpk's kernels clone into vectors that share one operation table", "[ode][nvector]") {
  // CVODES's adjoint memories clone two vectors per stored step; a table per vector was most of their size.
  SUNContext ctx = nullptr;
  SUNContext_Create(nullptr, &ctx);
  N_Vector a = N_VNew_Serial(5, ctx), b = N_VNew_Serial(3, ctx);
  pk::internal::UseFastSerialOps(a);
  pk::internal::UseFastSerialOps(b);
  pk::internal::UseFastSerialOps(b);  // twice is harmless
  CHECK(a->ops == b->ops);
  N_VConst(2.5, a);
  N_Vector c = N_VClone(a), e = N_VCloneEmpty(a);
  N_Vector* array = N_VCloneVectorArray(4, b);
  CHECK(c->ops == a->ops);
  CHECK(e->ops == a->ops);
  CHECK(array[3]->ops == a->ops);
  CHECK(N_VGetLength(c) == 5);
  CHECK(N_VGetLength(e) == 5);
  CHECK(N_VGetLength(array[0]) == 3);
  CHECK(N_VGetArrayPointer(c) != nullptr);
  CHECK(N_VGetArrayPointer(c) != N_VGetArrayPointer(a));
  CHECK(N_VGetArrayPointer(e) == nullptr);
  CHECK(N_VGetVectorID(c) == SUNDIALS_NVEC_SERIAL);
  // A clone is a working vector of its own.
  N_VScale(2.0, a, c);
  CHECK(NV_Ith_S(c, 4) == 5.0);
  CHECK(NV_Ith_S(a, 4) == 2.5);
  double outside[5] = {1, 2, 3, 4, 5};
  N_VSetArrayPointer(outside, e);  // not owned: destroying e must leave it alone
  CHECK(N_VMaxNorm(e) == 5.0);
  // Destroyed in any order (AddressSanitizer checks the frees and that nothing leaks).
  N_VDestroy(a);
  N_VDestroy(e);
  N_VDestroyVectorArray(array, 4);
  CHECK(NV_Ith_S(c, 0) == 5.0);
  N_VDestroy(c);
  N_VDestroy(b);
  CHECK(outside[4] == 5.0);
  SUNContext_Free(&ctx);
}
