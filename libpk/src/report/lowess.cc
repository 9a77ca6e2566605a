// Cleveland's LOWESS (J. Am. Stat. Assoc. 74:829, 1979), as R's lowess() computes it: local linear
// fits with tricube weights over the nearest f·n points, at x values at least δ = range/100 apart
// (the points between are interpolated), then robustness passes with bisquare weights on the
// residuals scaled by six times their median absolute value.
#include <algorithm>
#include <cmath>

#include "pk/plot.h"

namespace pk {
namespace {

// The weighted local linear fit at xs[i] over the window from `lo` of the sorted points, as R's
// lowest(): tricube weights of the distance over the window's half-width h (from its ns points), 1
// within 0.001·h, 0 beyond 0.999·h; points right of the window still within 0.999·h (ties of its last
// point when h = 0) count too. The slope only when the weighted spread of x, taken about its mean,
// exceeds 0.001 of the range of x.
double LocalFit(const std::vector<double>& xs, const std::vector<double>& ys, const std::vector<double>& robust,
                size_t i, size_t lo, size_t ns, std::vector<double>* w) {
  const double x = xs[i];
  const double h = std::max(x - xs[lo], xs[lo + ns - 1] - x);
  w->clear();
  double sw = 0;
  size_t end = lo;
  for (; end < xs.size(); ++end) {
    const double r = std::fabs(xs[end] - x);
    if (r > 0.999 * h) {
      if (xs[end] > x) break;
      w->push_back(0);
      continue;
    }
    double wj = 1;
    if (r > 0.001 * h) {
      const double t = 1 - (r / h) * (r / h) * (r / h);
      wj = t * t * t;
    }
    w->push_back(wj * robust[end]);
    sw += w->back();
  }
  if (!(sw > 0)) return ys[i];
  double a = 0;
  for (size_t j = lo; j < end; ++j) a += (*w)[j - lo] / sw * xs[j];
  const double range = xs.back() - xs.front();
  double c = 0;
  for (size_t j = lo; j < end; ++j) c += (*w)[j - lo] / sw * (xs[j] - a) * (xs[j] - a);
  const bool slope = h > 0 && std::sqrt(c) > 0.001 * range;
  double fit = 0;
  for (size_t j = lo; j < end; ++j) {
    const double wj = (*w)[j - lo] / sw;
    fit += (slope ? wj * ((x - a) * (xs[j] - a) / c + 1) : wj) * ys[j];
  }
  return fit;
}

// One pass: fitted values at every point. As R does, after a fit at x_last the next fit is at the
// last point within δ of it (at least the next point), and the points between are interpolated.
std::vector<double> Pass(const std::vector<double>& xs, const std::vector<double>& ys,
                         const std::vector<double>& robust, size_t ns) {
  const size_t n = xs.size();
  const double delta = 0.01 * (xs.back() - xs.front());
  std::vector<double> fit(n);
  size_t lo = 0, last = 0;
  bool first = true;
  std::vector<double> weights;
  for (size_t i = 0;;) {
    while (lo + ns < n && xs[i] - xs[lo] > xs[lo + ns] - xs[i]) ++lo;
    fit[i] = LocalFit(xs, ys, robust, i, lo, ns, &weights);
    if (!first && i > last + 1) {  // the points skipped since the last fit, interpolated
      for (size_t j = last + 1; j < i; ++j) {
        const double a = (xs[j] - xs[last]) / (xs[i] - xs[last]);
        fit[j] = a * fit[i] + (1 - a) * fit[last];
      }
    }
    first = false;
    last = i;
    const double cut = xs[last] + delta;
    size_t k = last + 1;
    for (; k < n && xs[k] <= cut; ++k) {
      if (xs[k] == xs[last]) {  // ties share the fit
        fit[k] = fit[last];
        last = k;
      }
    }
    if (last + 1 >= n) break;
    i = std::max(last + 1, k - 1);
  }
  return fit;
}

// R's robustness weights: bisquare of the residuals over six times their median absolute value
// (the mean of the two middle ones for even n); false when the fit is (nearly) exact.
bool RobustnessWeights(const std::vector<double>& ys, const std::vector<double>& fit, std::vector<double>* robust) {
  const size_t n = ys.size();
  std::vector<double> residual(n);
  double mean_abs = 0;
  for (size_t i = 0; i < n; ++i) {
    residual[i] = std::fabs(ys[i] - fit[i]);
    mean_abs += residual[i] / static_cast<double>(n);
  }
  std::vector<double> sorted = residual;
  std::sort(sorted.begin(), sorted.end());
  const double median = n % 2 ? sorted[n / 2] : 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]);
  const double cmad = 6 * median;
  if (cmad < 1e-7 * mean_abs) return false;
  for (size_t i = 0; i < n; ++i) {
    const double u = residual[i] / cmad;
    (*robust)[i] = residual[i] <= 0.001 * cmad ? 1 : residual[i] <= 0.999 * cmad ? (1 - u * u) * (1 - u * u) : 0;
  }
  return true;
}

}  // namespace

PlotSeries Lowess(const std::vector<double>& x, const std::vector<double>& y, double f, int iterations) {
  std::vector<std::pair<double, double>> points;
  for (size_t i = 0; i < std::min(x.size(), y.size()); ++i) {
    if (std::isfinite(x[i]) && std::isfinite(y[i])) points.emplace_back(x[i], y[i]);
  }
  std::stable_sort(points.begin(), points.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  PlotSeries out;
  out.label = "LOWESS";
  const size_t n = points.size();
  if (n < 3 || points.front().first == points.back().first) return out;  // no smoother: both empty
  for (const auto& p : points) out.x.push_back(p.first);
  std::vector<double> ys(n);
  for (size_t i = 0; i < n; ++i) ys[i] = points[i].second;
  // The neighbourhood: f·n points, truncated as R does.
  const size_t ns = std::min(n, std::max<size_t>(2, static_cast<size_t>(f * static_cast<double>(n) + 1e-7)));
  std::vector<double> robust(n, 1.0), fit;
  for (int pass = 0; pass <= iterations; ++pass) {
    fit = Pass(out.x, ys, robust, ns);
    if (pass == iterations || !RobustnessWeights(ys, fit, &robust)) break;
  }
  out.y = fit;
  return out;
}

}  // namespace pk
