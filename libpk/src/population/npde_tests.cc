// The npde package's tests of N(0, 1) (pk/npde.h): Student's t-test and Wilcoxon's signed-rank test
// of the mean, Fisher's variance test and the Shapiro–Wilk test of normality, each as R computes it,
// and the Bonferroni global test. Boost.Math's distributions are sealed here.
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <vector>

#include <boost/math/distributions/chi_squared.hpp>
#include <boost/math/distributions/normal.hpp>
#include <boost/math/distributions/students_t.hpp>

#include "pk/npde.h"
#include "internal_text.h"

namespace pk {
namespace {

using internal::kNaN;

double NormalCdf(double z, bool upper = false) {
  const boost::math::normal_distribution<double> n;
  return upper ? boost::math::cdf(boost::math::complement(n, z)) : boost::math::cdf(n, z);
}

// Average ranks (R's rank(), ties.method = "average") of v, and whether any were tied.
std::vector<double> AverageRanks(const std::vector<double>& v, std::vector<int>* tie_sizes) {
  std::vector<size_t> order(v.size());
  std::iota(order.begin(), order.end(), size_t{0});
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return v[a] < v[b]; });
  std::vector<double> rank(v.size());
  for (size_t i = 0; i < order.size();) {
    size_t j = i;
    while (j + 1 < order.size() && v[order[j + 1]] == v[order[i]]) ++j;
    for (size_t k = i; k <= j; ++k) rank[order[k]] = (static_cast<double>(i + j) + 2) / 2;
    tie_sizes->push_back(static_cast<int>(j - i + 1));
    i = j + 1;
  }
  return rank;
}

// P(V ≤ q) for the signed-rank statistic V of n values without ties (R's psignrank): the number of
// subsets of {1, …, n} with sum at most q, over 2ⁿ.
double SignedRankCdf(double q, int n) {
  const int top = n * (n + 1) / 2;
  std::vector<double> count(static_cast<size_t>(top) + 1, 0.0);
  count[0] = 1;
  for (int k = 1; k <= n; ++k) {
    for (int s = k * (k + 1) / 2; s >= k; --s) count[static_cast<size_t>(s)] += count[static_cast<size_t>(s - k)];
  }
  double below = 0;
  for (int s = 0; s <= top && s <= q; ++s) below += count[static_cast<size_t>(s)];
  return below / std::ldexp(1.0, n);
}

// R's wilcox.test(x)$p.value (μ = 0, two-sided, continuity correction): exact below 50 values when
// there are neither ties nor zeros, else the normal approximation with the ties' correction. Zeros
// are dropped first.
double SignedRankTest(std::vector<double> x) {
  const size_t all = x.size();
  x.erase(std::remove(x.begin(), x.end(), 0.0), x.end());
  const bool zeros = x.size() != all;
  const int n = static_cast<int>(x.size());
  if (n == 0) return kNaN;
  std::vector<double> magnitude(x.size());
  std::transform(x.begin(), x.end(), magnitude.begin(), [](double v) { return std::fabs(v); });
  std::vector<int> ties;
  const std::vector<double> rank = AverageRanks(magnitude, &ties);
  double v = 0;
  for (size_t i = 0; i < x.size(); ++i) v += x[i] > 0 ? rank[i] : 0.0;
  const bool tied = static_cast<int>(ties.size()) != n;
  const double dn = n;
  if (n < 50 && !tied && !zeros) {
    // 1 − P(V ≤ v − 1) is exact here: the counts over 2ⁿ (n < 50) are represented exactly.
    const double p = v > dn * (dn + 1) / 4 ? 1 - SignedRankCdf(v - 1, n) : SignedRankCdf(v, n);
    return std::min(2 * p, 1.0);
  }
  double tie_sum = 0;
  for (int t : ties) tie_sum += static_cast<double>(t) * t * t - t;
  const double z0 = v - dn * (dn + 1) / 4;
  const double sigma = std::sqrt(dn * (dn + 1) * (2 * dn + 1) / 24 - tie_sum / 48);
  const double z = (z0 - (z0 > 0 ? 0.5 : z0 < 0 ? -0.5 : 0.0)) / sigma;
  return 2 * std::min(NormalCdf(z), NormalCdf(z, true));
}

// Σ(x − x̄)², and x̄ in *mean.
double SumOfSquares(const std::vector<double>& x, double* mean) {
  *mean = std::accumulate(x.begin(), x.end(), 0.0) / static_cast<double>(x.size());
  double ss = 0;
  for (double v : x) ss += (v - *mean) * (v - *mean);
  return ss;
}

// R's t.test(x)$p.value (μ = 0, two-sided): the npde package's test of the mean since its version 2.
double TTest(const std::vector<double>& x) {
  const double n = static_cast<double>(x.size());
  if (n < 2) return kNaN;
  double mean = 0;
  const double ss = SumOfSquares(x, &mean);
  if (!(ss > 0)) return kNaN;  // R: "data are essentially constant"
  const double t = mean / std::sqrt(ss / (n - 1) / n);
  return 2 * boost::math::cdf(boost::math::complement(boost::math::students_t_distribution<double>(n - 1), std::fabs(t)));
}

// The npde package's variance test: (n − 1)s² against χ²(n − 1), two-sided.
double VarianceTest(const std::vector<double>& x) {
  const double n = static_cast<double>(x.size());
  if (n < 2) return kNaN;
  double mean = 0;
  const double ss = SumOfSquares(x, &mean);
  const boost::math::chi_squared_distribution<double> chi(n - 1);
  return 2 * std::min(boost::math::cdf(chi, ss), boost::math::cdf(boost::math::complement(chi, ss)));
}

double Polynomial(const double* c, int terms, double x) {  // c₀ + c₁x + … (Horner)
  double p = 0;
  for (int k = terms - 1; k >= 0; --k) p = p * x + c[k];
  return p;
}

// Royston's coefficients a_1…a_{n/2} of the Shapiro–Wilk statistic (Applied Statistics algorithm
// AS R94, 1995, as R's swilk.c), for the largest values; the smallest take −a.
std::vector<double> ShapiroWilkCoefficients(int n) {
  const int half = n / 2;
  std::vector<double> a(static_cast<size_t>(half));
  if (n == 3) {
    a[0] = std::sqrt(0.5);
    return a;
  }
  static const double c1[6] = {0, 0.221157, -0.147981, -2.07119, 4.434685, -2.706056};
  static const double c2[6] = {0, 0.042981, -0.293762, -1.752461, 5.682633, -3.582633};
  const double dn = n;
  std::vector<double> m(static_cast<size_t>(half));
  double sum2 = 0;
  for (int i = 0; i < half; ++i) {
    m[static_cast<size_t>(i)] = NormalQuantile((i + 1 - 0.375) / (dn + 0.25));  // negative: the lower half
    sum2 += m[static_cast<size_t>(i)] * m[static_cast<size_t>(i)];
  }
  sum2 *= 2;
  const double root = std::sqrt(sum2), u = 1 / std::sqrt(dn);
  const double a1 = Polynomial(c1, 6, u) - m[0] / root;
  int first = 1;
  double scale = 0;
  if (n > 5) {
    const double a2 = -m[1] / root + Polynomial(c2, 6, u);
    scale = std::sqrt((sum2 - 2 * m[0] * m[0] - 2 * m[1] * m[1]) / (1 - 2 * a1 * a1 - 2 * a2 * a2));
    a[1] = a2;
    first = 2;
  } else {
    scale = std::sqrt((sum2 - 2 * m[0] * m[0]) / (1 - 2 * a1 * a1));
  }
  a[0] = a1;
  for (int i = first; i < half; ++i) a[static_cast<size_t>(i)] = -m[static_cast<size_t>(i)] / scale;
  return a;
}

// R's shapiro.test(x): W and its p-value (Royston 1995), for 3 ≤ n ≤ 5000 values not all equal;
// false otherwise.
bool ShapiroWilk(std::vector<double> x, double* w, double* p) {
  const int n = static_cast<int>(x.size());
  std::sort(x.begin(), x.end());
  if (n < 3 || n > 5000 || !(x.back() - x.front() >= 1e-10)) return false;
  const std::vector<double> a = ShapiroWilkCoefficients(n);
  // W is the squared correlation of the sorted values with the coefficients (−a mirrored below,
  // 0 at an odd middle), formed as 1 − W to keep its digits near 1.
  std::vector<double> c(static_cast<size_t>(n), 0.0);
  for (int i = 0; i < n / 2; ++i) {
    c[static_cast<size_t>(i)] = -a[static_cast<size_t>(i)];
    c[static_cast<size_t>(n - 1 - i)] = a[static_cast<size_t>(i)];
  }
  const double dn = n, range = x.back() - x.front();
  double cm = 0, xm = 0;
  for (int i = 0; i < n; ++i) cm += c[static_cast<size_t>(i)], xm += x[static_cast<size_t>(i)] / range;
  cm /= dn, xm /= dn;
  double scc = 0, sxx = 0, scx = 0;
  for (int i = 0; i < n; ++i) {
    const double dc = c[static_cast<size_t>(i)] - cm, dx = x[static_cast<size_t>(i)] / range - xm;
    scc += dc * dc, sxx += dx * dx, scx += dc * dx;
  }
  const double root = std::sqrt(scc * sxx);
  const double w1 = (root - scx) * (root + scx) / (scc * sxx);
  *w = 1 - w1;
  if (n == 3) {  // exact: (6/π)(asin √W − π/3)
    *p = std::max(0.0, 6 / M_PI * (std::asin(std::sqrt(*w)) - M_PI / 3));
    return true;
  }
  static const double g[2] = {-2.273, 0.459};
  static const double c3[4] = {0.544, -0.39978, 0.025054, -6.714e-4}, c4[4] = {1.3822, -0.77857, 0.062767, -0.0020322};
  static const double c5[4] = {-1.5861, -0.31082, -0.083751, 0.0038915}, c6[3] = {-0.4803, -0.082676, 0.0030302};
  double y = std::log(w1), mean = 0, sd = 0;
  if (n <= 11) {
    const double gamma = Polynomial(g, 2, dn);
    if (y >= gamma) {  // as swilk.c; not reached by a valid W (n = 4 would need W ≤ 0.354)
      *p = 1e-99;
      return true;
    }
    y = -std::log(gamma - y);
    mean = Polynomial(c3, 4, dn);
    sd = std::exp(Polynomial(c4, 4, dn));
  } else {
    mean = Polynomial(c5, 4, std::log(dn));
    sd = std::exp(Polynomial(c6, 3, std::log(dn)));
  }
  *p = NormalCdf((y - mean) / sd, true);
  return true;
}

}  // namespace

NpdeTests TestNpde(const std::vector<double>& values) {
  std::vector<double> x;
  for (double v : values) {
    if (std::isfinite(v)) x.push_back(v);
  }
  NpdeTests t;
  t.mean_p = TTest(x);
  t.mean_wilcoxon_p = SignedRankTest(x);
  t.variance_p = VarianceTest(x);
  ShapiroWilk(x, &t.normality_w, &t.normality_p);
  // Bonferroni over the tests there are (Shapiro–Wilk's needs 3 to 5000 values).
  double least = INFINITY;
  int tests = 0;
  for (double p : {t.mean_p, t.variance_p, t.normality_p}) {
    if (std::isfinite(p)) least = std::min(least, p), ++tests;
  }
  t.global_p = tests == 0 ? kNaN : std::min(1.0, tests * least);
  return t;
}

}  // namespace pk
