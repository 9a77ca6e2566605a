// A goodness-of-fit plot: points, a reference line and their LOWESS smoother (pk/plot.h).
#include <cmath>

#include "pk/plot.h"

namespace pk {

std::string RenderGofSvg(const PlotSeries& points, const PlotSeries& reference, const PlotOptions& o,
                         const std::vector<PlotSeries>& extra) {
  std::vector<double> sx, sy;  // the smoother sees what the axes show
  for (size_t i = 0; i < points.x.size(); ++i) {
    if ((o.log_x && !(points.x[i] > 0)) || (o.log_y && !(points.y[i] > 0))) continue;
    sx.push_back(o.log_x ? std::log(points.x[i]) : points.x[i]);
    sy.push_back(o.log_y ? std::log(points.y[i]) : points.y[i]);
  }
  PlotSeries smooth = Lowess(sx, sy);
  for (double& v : smooth.x) v = o.log_x ? std::exp(v) : v;
  for (double& v : smooth.y) v = o.log_y ? std::exp(v) : v;
  smooth.reference = true;
  smooth.colour = "#d62728";
  std::vector<PlotSeries> series{reference, points};
  series.insert(series.end(), extra.begin(), extra.end());
  if (smooth.y.size() >= 3) series.push_back(smooth);
  return RenderSvg(series, o);
}

}  // namespace pk
