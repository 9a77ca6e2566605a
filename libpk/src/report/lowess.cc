// Cleveland's LOWESS (J. Am. Stat. Assoc. 74:829, 1979), as R's lowess() computes it: local linear
// fits with tricube weights over the nearest f·n points, at x values at least δ = range/100 apart
// (the points between are interpolated), then robustness passes with bisquare weights on the
// residuals scaled by six times their median absolute value.
#include <algorithm>
#include <cmath>

#include "pk/plot.h"

namespace pk {
namespace {

// The weighted local linear fit at xs[i] over the window [lo, lo + ns) of the sorted points, as R's
// lowest(): tricube weights of the distance over the window's half-width h, 1 within 0.001·h, 0
// beyond 0.999·h; the slope only when the weighted spread of x exceeds 0.001 of its range.
double LocalFit(const std::vector<double>& xs, const std::vector<double>& ys, const std::vector<double>& robust,
                size_t i, size_t lo, size_t ns) {
  const double x = xs[i];
  const double h = std::max(x - xs[lo], xs[lo + ns - 1] - x);
  double sw = 0, sx = 0, sy = 0, sxx = 0, sxy = 0;
  for (size_t j = lo; j < lo + ns; ++j) {
    const double r = std::fabs(xs[j] - x);
    double w = 1;
    if (r > 0.999 * h) continue;
    if (r > 0.001 * h) {
      const double t = 1 - (r / h) * (r / h) * (r / h);
      w = t * t * t;
    }
    w *= robust[j];
    sw += w;
    sx += w * xs[j];
    sy += w * ys[j];
    sxx += w * xs[j] * xs[j];
    sxy += w * xs[j] * ys[j];
  }
  if (!(sw > 0)) return ys[i];
  const double mx = sx / sw, my = sy / sw, var = sxx / sw - mx * mx;
  const double range = xs.back() - xs.front();
  if (!(h > 0) || !(std::sqrt(std::max(var, 0.0)) > 0.001 * range)) return my;
  return my + (sxy / sw - mx * my) / var * (x - mx);
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
  for (size_t i = 0;;) {
    while (lo + ns < n && xs[i] - xs[lo] > xs[lo + ns] - xs[i]) ++lo;
    fit[i] = LocalFit(xs, ys, robust, i, lo, ns);
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
  for (const auto& p : points) out.x.push_back(p.first);
  if (n < 3 || out.x.front() == out.x.back()) return out;  // no smoother through fewer points
  std::vector<double> ys(n);
  for (size_t i = 0; i < n; ++i) ys[i] = points[i].second;
  const size_t ns = std::min(n, std::max<size_t>(2, static_cast<size_t>(std::lround(f * static_cast<double>(n)))));
  std::vector<double> robust(n, 1.0), fit;
  for (int pass = 0; pass <= iterations; ++pass) {
    fit = Pass(out.x, ys, robust, ns);
    if (pass == iterations || !RobustnessWeights(ys, fit, &robust)) break;
  }
  out.y = fit;
  return out;
}

}  // namespace pk
