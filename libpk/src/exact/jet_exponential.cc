// JetExponential: scaling and squaring of a jet (jet_exponential.h).
#include "jet_exponential.h"

#include <algorithm>
#include <cmath>

#include "../numerical_failure.h"

namespace pk {
namespace internal {
namespace {

constexpr int kDegree = 10;            // Taylor degree after scaling
constexpr double kScaledNorm = 1.0 / 16;  // Σ_S ‖X_S‖₁ after scaling

// r += a·b for w×w column-major blocks, written out: Eigen's dynamic-size product costs several
// times the arithmetic at the sizes here (w = 1–20).
void AddProduct(const double* a, const double* b, Eigen::Index w, double* r) {
  for (Eigen::Index j = 0; j < w; ++j) {
    for (Eigen::Index k = 0; k < w; ++k) {
      const double bkj = b[j * w + k];
      if (bkj == 0) continue;
      for (Eigen::Index i = 0; i < w; ++i) r[j * w + i] += a[k * w + i] * bkj;
    }
  }
}

// *out = x·y by the algebra's table (out must not alias x or y; its parts keep their size). Parts of
// x that are zero (`zero`) are skipped: a direction that A does not depend on twice, say.
void Multiply(const Jet& x, const std::vector<char>& zero, const Jet& y, const JetProducts& algebra, Jet* out) {
  const Eigen::Index w = x.front().rows();
  for (Eigen::MatrixXd& r : *out) r.setZero();
  for (const auto& [t, a, b] : algebra.entries) {
    if (!zero[static_cast<size_t>(a)]) {
      AddProduct(x[static_cast<size_t>(a)].data(), y[static_cast<size_t>(b)].data(), w, (*out)[static_cast<size_t>(t)].data());
    }
  }
}

void ZeroParts(const Jet& x, std::vector<char>* zero) {
  zero->resize(x.size());
  for (size_t s = 0; s < x.size(); ++s) (*zero)[s] = x[s].isZero(0.0) ? 1 : 0;
}

// Scratch kept per thread: a fit takes thousands of these exponentials of a few small parts each,
// where allocating the parts would cost more than the arithmetic.
struct Scratch {
  Jet x, product;
  std::vector<char> zero;
};

}  // namespace

void JetExponential(const JetProducts& algebra, Jet* e) {
  thread_local Scratch scratch;
  Jet& x = scratch.x;
  std::swap(x, *e);  // x holds X; *e, the scratch's old parts, becomes exp(X)
  const auto w = x.front().rows();
  double norm = 0;
  for (const Eigen::MatrixXd& part : x) norm += part.cwiseAbs().colwise().sum().maxCoeff();
  if (!std::isfinite(norm)) throw NumericalFailure("a step's matrix is not finite");
  const int squarings = norm > kScaledNorm ? static_cast<int>(std::ceil(std::log2(norm / kScaledNorm))) : 0;
  const double scale = std::ldexp(1.0, -squarings);
  for (Eigen::MatrixXd& part : x) part *= scale;
  Jet& product = scratch.product;
  product.resize(x.size());
  e->resize(x.size());
  for (size_t s = 0; s < x.size(); ++s) {
    product[s].resize(w, w);
    (*e)[s].setZero(w, w);
  }
  // Horner: E = I + X(I + X/2(I + … (I + X/k)…)).
  (*e)[0].setIdentity();
  ZeroParts(x, &scratch.zero);
  for (int k = kDegree; k >= 1; --k) {
    Multiply(x, scratch.zero, *e, algebra, &product);
    for (size_t s = 0; s < e->size(); ++s) (*e)[s] = product[s] / k;
    (*e)[0].diagonal().array() += 1;
  }
  for (int i = 0; i < squarings; ++i) {
    ZeroParts(*e, &scratch.zero);
    Multiply(*e, scratch.zero, *e, algebra, &product);
    std::swap(*e, product);
  }
}

}  // namespace internal
}  // namespace pk
