// libpk: plain SVG plots of concentration against time.
#ifndef PK_PLOT_H_
#define PK_PLOT_H_

#include <string>
#include <vector>

namespace pk {

struct PlotSeries {
  std::string label;
  std::vector<double> x;
  std::vector<double> y;
  bool markers = false;  ///< draw points (observations) instead of a line
  bool hollow = false;   ///< with markers: open circles (e.g. censored samples, drawn at their limit)
};

struct PlotOptions {
  std::string title;
  std::string x_label = "time";
  std::string y_label = "concentration";
  bool log_y = false;  ///< logarithmic y axis; non-positive values are left out
  int width = 820;
  int height = 520;
};

/// An SVG document with one line or point series per entry.
std::string RenderSvg(const std::vector<PlotSeries>& series, const PlotOptions& options);

}  // namespace pk

#endif  // PK_PLOT_H_
